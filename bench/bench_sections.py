"""Section control's cost on the default scenario's track (SUMO drives it once, untimed).

Figures
-------
sections_coverage_default_s    switch_sections, coverage mode (6 sections, 1.0 s on / 0.6 s off),
                               over the default scenario's 177,000 ticks (best of 3), s
sections_boundary_default_s    the same in boundary mode (the rule the run used before), s
sections_landing_default_s     per-section landing: section_strips, AsApplied.add_strips with
                               passes, the worked-area raster and overlap_metrics (best of 3), s
"""

from __future__ import annotations

import dataclasses

import numpy as np

from bench.bench_maps import _best  # best of 3 wall times


def run() -> dict:
    from vrsim.maps import AsApplied
    from vrsim.services.sim.metrics import overlap_metrics
    from vrsim.services.sim.run import cells_in_field, measure
    from vrsim.services.sim.scenario import load
    from vrsim.services.sim.section_landing import section_strips, worked_fraction
    from vrsim.services.sim.sections import switch_sections
    from vrsim.services.sim.world import build_world, driving

    scenario = load("default")
    world = build_world(scenario)
    period_s = scenario.timing.control_period_s
    with driving(world.scenario, world.path) as driver:
        track = driver.run_all()
    measured = measure(scenario, track)
    imp, grid, polygon = scenario.implement, world.grid, world.field.polygon
    cell_m = min(grid.cell_size)
    figures = {}
    for mode in ("coverage", "boundary"):
        implement = dataclasses.replace(imp, section_control=mode)
        figures[f"sections_{mode}_default_s"] = _best(
            lambda implement=implement: switch_sections(track, implement, polygon, world.path, cell_m,
                                                        measured, period_s))
    states = switch_sections(track, imp, polygon, world.path, cell_m, measured, period_s)
    rate = grid.lookup(track["x_m"], track["y_m"]).rate_kg_ha
    metered = np.nan_to_num(rate) * track["speed_m_s"] * states.width_on_m * period_s / 1e4
    in_field = cells_in_field(grid, polygon)

    def per_section():
        applied = AsApplied(grid)
        section_strips(track, metered, states, imp.delivery_delay_s, period_s, cell_m).add_to(applied)
        overlap_metrics(applied.coverage_fraction, applied.overlap_fraction, applied.overlap_kg,
                        worked_fraction(track, imp.width_m, grid), in_field, grid.rates_kg_ha)

    figures["sections_landing_default_s"] = _best(per_section)
    return figures


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key:<36} {value:.3f}")
