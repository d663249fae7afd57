"""ISO 11783-11 data dictionary entries (DDIs) that vrsim reads and writes, with their units.

Numbers, names and resolutions as the ISOBUS data dictionary defines them (checked against the
open-source AgIsoStack++ and isoxml-dotnet tables): a process data value is an int32 in the DDI's
unit, e.g. DDI 6 and 7 in mg/m^2 (resolution 1), DDI 67 in mm.
"""

from __future__ import annotations

SETPOINT_VOLUME_PER_AREA = 0x0001  # resolution 0.01 mm^3/m^2
ACTUAL_VOLUME_PER_AREA = 0x0002
SETPOINT_MASS_PER_AREA = 0x0006  # mg/m^2
ACTUAL_MASS_PER_AREA = 0x0007
SETPOINT_COUNT_PER_AREA = 0x000B  # resolution 0.001 /m^2
ACTUAL_COUNT_PER_AREA = 0x000C
SETPOINT_SPACING = 0x0010
ACTUAL_WORKING_WIDTH = 0x0043  # mm
DEVICE_ELEMENT_OFFSET_X = 0x0086  # mm, forward positive
DEVICE_ELEMENT_OFFSET_Y = 0x0087  # mm, right positive (section 1 is the leftmost)
ACTUAL_WORK_STATE = 0x008D  # 0 off, 1 on, 2 error, 3 not available
ACTUAL_CONDENSED_WORK_STATE_1_16 = 0x00A1  # 2 bits per section, section 1 in the lowest bits; A2.. B0
SECTIONS_PER_CONDENSED = 16
MAX_CONDENSED_DDIS = 16  # 0x00A1 .. 0x00B0: sections 1 to 256

KG_HA_PER_MG_M2 = 0.01  # 1 mg/m^2 = 1e-6 kg / 1e-4 ha
# DDI 1 and 2 count 0.01 mm^3/m^2, and 1 mm^3/m^2 = 1e-6 L / 1e-4 ha = 0.01 L/ha.
L_HA_PER_VOLUME_COUNT = 0.01 * 0.01
SEEDS_HA_PER_COUNT = 0.001 * 1e4  # DDI 11 and 12 count 0.001 /m^2 = 10 /ha

# Names of common DDIs, so messages say what a file holds.
NAMES = {
    SETPOINT_VOLUME_PER_AREA: "setpoint volume per area (0.01 mm^3/m^2)",
    ACTUAL_VOLUME_PER_AREA: "actual volume per area (0.01 mm^3/m^2)",
    SETPOINT_MASS_PER_AREA: "setpoint mass per area (mg/m^2)",
    ACTUAL_MASS_PER_AREA: "actual mass per area (mg/m^2)",
    SETPOINT_COUNT_PER_AREA: "setpoint count per area (0.001 /m^2)",
    ACTUAL_COUNT_PER_AREA: "actual count per area (0.001 /m^2)",
    SETPOINT_SPACING: "setpoint spacing (mm)",
    ACTUAL_WORKING_WIDTH: "actual working width (mm)",
    ACTUAL_WORK_STATE: "actual work state",
    ACTUAL_CONDENSED_WORK_STATE_1_16: "actual condensed work state 1-16",
}

# Actual rate DDI -> (its setpoint DDI, unit vrsim reports, factor from the DDI's unit to it).
RATES = {
    ACTUAL_MASS_PER_AREA: (SETPOINT_MASS_PER_AREA, "kg/ha", KG_HA_PER_MG_M2),
    ACTUAL_VOLUME_PER_AREA: (SETPOINT_VOLUME_PER_AREA, "L/ha", L_HA_PER_VOLUME_COUNT),
    ACTUAL_COUNT_PER_AREA: (SETPOINT_COUNT_PER_AREA, "seeds/ha", SEEDS_HA_PER_COUNT),
}


def ddi_list(ddis) -> str:
    """``"0006 (setpoint mass per area (mg/m^2)), 0094"``: DDIs as files write them, named when known."""
    return ", ".join(f"{d:04X}" + (f" ({NAMES[d]})" if d in NAMES else "") for d in ddis)
