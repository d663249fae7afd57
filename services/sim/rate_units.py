"""The unit of a run's rate figures and how their keys read in the map's own unit.

A run's rate figures are in kg/ha (`RATE_UNIT`; their keys end in ``_kg_ha``); each is also given in
the map's own unit under its key without the suffix (`rate_key`: the summary's ``in_rate_unit``,
`services.sim.metrics.in_rate_unit`, and the machine check's, `MachineCheck.in_rate_unit`). Below the
figures and the machines: both name them.
"""

__all__ = ["RATE_UNIT", "rate_key"]

RATE_UNIT = "kg/ha"  # the unit the run's rate figures are in (their keys end in _kg_ha)


def rate_key(key: str) -> str:
    """The key of a figure in `RATE_UNIT` in ``in_rate_unit``: ``"mae_kg_ha"`` -> ``"mae"``."""
    return key.removesuffix("_kg_ha")
