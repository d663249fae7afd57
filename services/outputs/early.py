"""timeseries.png drawn while the run goes on: its minute (`services.sim.kept.SeriesWindow`) is whole
long before the run ends, and the picture's process has a core to spare once SUMO's has driven.

`EarlyTimeseries` is a track sink of a streamed run (`services.sim.streamed.run_streamed`): it is given
each accounted stretch's rows, as the track files are, keeps the same window of them as the run does,
and hands the picture to the plot worker as soon as the window is whole, to be drawn in memory once
the worker's imports are done (`services.outputs.plot_worker`). `services.outputs.write.write_outputs`
then writes the PNG's bytes instead of drawing it after the run (the same bytes: the same window of
the same rows, drawn by the same function).
"""

from __future__ import annotations

from vrsim.services.sim.kept import SERIES_KEYS, SeriesWindow


class EarlyTimeseries:
    """timeseries.png of a run, handed to `plotter` once its minute is known.

    Call `world_built` with the run's world before the first rows (`run_streamed`'s ``on_world``),
    then call it with each stretch's rows; ``submitted`` says whether the picture went to the worker
    (then its reply is the PNG's bytes, next in the worker's order).
    """

    def __init__(self, plotter):
        self.plotter = plotter
        self.window = SeriesWindow()
        self.world = None
        self.submitted = False

    def world_built(self, world) -> None:
        """The run's world (`services.sim.world.World`): its grid gives the rates' unit, its scenario
        the title."""
        self.world = world

    def __call__(self, rows: dict) -> None:
        """The next stretch's track rows (`services.sim.bounded.BoundedAccount`'s)."""
        if self.submitted:
            return
        self.window.add({k: rows[k] for k in SERIES_KEYS}, rows["implement_on"])
        if self.window.complete:
            from vrsim.services.outputs.plots import window_picture

            self.plotter.submit("draw_timeseries", window_picture(self.window.series, self.world), None)
            self.submitted = True
