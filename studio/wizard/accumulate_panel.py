"""The LiDAR step's accumulation panel: a static LiDAR's frames added up over an integration time into one capture.

For a non-repetitive scanner (a Livox Horizon or Avia) one frame covers a fraction of the field of view; held still
for half a second it covers nearly all of it. The user picks the LiDAR and the integration time and clicks
*Accumulate*; the device is read as a background job (:func:`backend.services.accumulated_capture.
capture_accumulated`), the cloud kept as one capture, and its coverage of the field of view drawn (cells never hit
in red), so the user sees whether the time was long enough. Live view holds the device, so it must be stopped first.
"""

from __future__ import annotations

from collections.abc import Callable

from backend.core.accumulation import MAX_INTEGRATION_S
from backend.core.errors import InputError
from backend.plots.accumulation import coverage_image
from backend.plots.render import to_rgb
from backend.services import accumulated_capture
from studio.context import StudioContext
from studio.job_panel import JobPanel

NONE = "(no LiDAR)"


class AccumulatePanel:
    """Accumulation for one chosen LiDAR; ``on_captured()`` runs after the capture was added; ``is_live()`` says
    whether the step streams live now (then the device is busy)."""

    def __init__(self, ctx: StudioContext, on_captured: Callable[[], None], is_live: Callable[[], bool]):
        self.ctx = ctx
        self.on_captured = on_captured
        self.is_live = is_live
        gui = ctx.server.gui
        with gui.add_folder("Accumulate a static LiDAR", expand_by_default=False):
            gui.add_markdown("For a Livox (non-repetitive scan): hold the rig still and add its frames up into one "
                             "dense cloud. The coverage shows where the field of view is still empty.")
            self.sensor = gui.add_dropdown("LiDAR to accumulate", options=[NONE])
            self.integration = gui.add_number("Integration time (s)", initial_value=0.5, min=0.05,
                                              max=MAX_INTEGRATION_S, step=0.05)
            self.accumulate_button = gui.add_button("Accumulate")
            self.jobs = JobPanel(ctx, [self.accumulate_button])
            self.coverage = gui.add_image(to_rgb(coverage_image(None)), label="Coverage of the field of view")
        self.accumulate_button.on_click(lambda _: self._accumulate())

    def set_lidars(self, lidars: list[str]) -> None:
        self.sensor.options = lidars or [NONE]
        if self.sensor.value not in self.sensor.options:
            self.sensor.value = self.sensor.options[0]

    def _accumulate(self) -> None:
        session, sensor, seconds = self.ctx.session, self.sensor.value, float(self.integration.value)
        if self.is_live():
            self.ctx.notify("Stop live first", "Live view holds the LiDARs' devices; stop it, then accumulate.",
                            error=True)
            return
        try:
            accumulated_capture.check_device(session, sensor)
        except InputError as exc:
            self.ctx.notify("Cannot accumulate", exc.message, error=True)
            return

        def done(captured: accumulated_capture.AccumulatedCapture) -> None:
            self.coverage.image = to_rgb(coverage_image(captured.coverage, f"{sensor}, {seconds:g} s"))
            self.ctx.notify("Cloud accumulated", f"capture {captured.record.id} of {sensor}: "
                            f"{captured.record.n_points:,} points from {captured.record.meta['frames']} frames, "
                            f"{100 * captured.coverage.share:.1f} % of the field of view")
            self.on_captured()

        self.jobs.run(f"accumulate {sensor}", lambda progress: accumulated_capture.capture_accumulated(
            session, sensor, seconds, progress), done)
