"""Section control: which sections of the implement apply product, tick by tick.

``[implement] section_control`` picks the switching (``"coverage"``, ``"boundary"`` or ``"off"``).
`SectionSwitch` steps it over a track's ticks, in batches of any size with the same result, and
returns `SectionStates`: per tick and section whether the gate is open (``actual``: product metered
in the tick passes it and lands ``delivery_delay_s`` later) and what the terminal commanded.

Modules: `switching` (the modes and the states), `passes` (runs of work, numbered), `gates`
(commands and their latencies, in ticks), `coverage` (the terminal's coverage map), `strips`
(where a section's strip lies, m) and `motion` (the look-ahead: where the implement and each section
will be, from the sensed speed, acceleration and yaw rate). The sections-on mask of the outputs
(``"0x3f"``) is `common.section_masks`.
"""

from vrsim.services.sim.sections.gates import command, gate
from vrsim.services.sim.sections.passes import pass_index, runs_of
from vrsim.services.sim.sections.strips import Poses, fill_outlines
from vrsim.services.sim.sections.switching import (
    STEPS_KEY,
    SWITCHING,
    SectionStates,
    SectionSwitch,
    run_section_states,
    switch_sections,
)

__all__ = [
    "STEPS_KEY",
    "SWITCHING",
    "SectionStates",
    "SectionSwitch",
    "switch_sections",
    "run_section_states",
    "pass_index",
    "runs_of",
    "command",
    "gate",
    "Poses",
    "fill_outlines",
]
