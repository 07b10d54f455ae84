"""Step 11, *Clocks*: the time offset between two sensors' clocks, and each sensor's clock offset in the rig.

The user picks the reference (a camera) and the sensor (a 3D LiDAR or another camera) whose captures watched a
board carried through both views (or two 3D LiDARs whose captures were taken while the rig turned in a static
scene), and clicks *Measure*; the alignment runs as a job with progress and Cancel
(:mod:`backend.calib.time_offset.service`). The result shows the offset with its sigma, both signals on the
reference's clock (where the offset is right they lie on each other) and the score over the offsets searched; it is
kept in the session's history, and accepting it on the shared result card sets the sensor's clock offset, which the
table of clocks shows and the matching of pairs and sets applies.
"""

from __future__ import annotations

from backend.calib.time_offset import service as time_offset_service
from backend.core.errors import InputError
from backend.core.rig import Rig
from backend.plots.render import to_rgb
from backend.plots.time_offset import aligned_signals
from backend.store.session import Session
from studio.context import StudioContext
from studio.job_panel import JobPanel
from studio.result_card import ResultCard
from studio.result_history import ResultHistory

NONE = "(none)"
HELP = ("Carry the board through both sensors' views, tilting and turning it, while both capture continuously (or "
        "import both recordings); for two 3D LiDARs, turn the rig about every axis in a static scene. Then measure. "
        "The offset follows Kalibr: `t_sensor = t_reference + offset`. Accepting it sets the sensor's clock offset; "
        "pairs and multi-camera sets are then matched on the rig's clock.")


def clocks_markdown(rig: Rig) -> str:
    """Every sensor's clock offset (ms) with its sigma, as a table."""
    rows = ["| sensor | kind | clock offset (ms) | σ (ms) |", "|---|---|---|---|"]
    for frame in rig.frames.values():
        if frame.kind == "frame":
            continue
        std = "not measured" if frame.clock_offset_std_s is None else f"{1e3 * frame.clock_offset_std_s:.2f}"
        rows.append(f"| {frame.name} | {frame.kind} | {1e3 * frame.clock_offset_s:.2f} | {std} |")
    return "\n".join(rows)


class TimeOffsetStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        gui = ctx.server.gui
        with gui.add_folder("11 · Clocks", expand_by_default=False):
            gui.add_markdown(HELP)
            self.reference = gui.add_dropdown("Reference", options=[NONE], hint="a camera, or a 3D LiDAR against "
                                              "another 3D LiDAR")
            self.sensor = gui.add_dropdown("Sensor to line up", options=[NONE])
            self.measure_button = gui.add_button("Measure the time offset", color="blue")
            self.jobs = JobPanel(ctx, [self.measure_button])
            self.history = ResultHistory(gui, lambda _: self._show_result(), label="Time-offset result")
            self.offset_text = gui.add_markdown("")
            self.plot = gui.add_image(to_rgb(aligned_signals(None)), label="Both signals on the reference's clock")
            self.card = ResultCard(ctx, on_accepted=lambda _: self._show_clocks(),
                                   empty_text="No time-offset result yet.")
            self.clocks_text = gui.add_markdown("")
        self.measure_button.on_click(lambda _: self._measure())
        self.sensor.on_update(lambda _: self._fill_history(None))
        ctx.on_session_changed(self._session_changed)
        ctx.on_rig_changed(lambda _: self._list_sensors())

    def _session_changed(self, session: Session) -> None:
        self._list_sensors()

    def _list_sensors(self) -> None:
        rig = self.ctx.session.rig
        for dropdown, kinds in ((self.reference, ("camera", "lidar3d")), (self.sensor, ("lidar3d", "camera"))):
            names = [frame.name for kind in kinds for frame in rig.sensors(kind)] or [NONE]
            dropdown.options = names
            if dropdown.value not in names:
                dropdown.value = names[0]
        self._fill_history(None)
        self._show_clocks()

    def _show_clocks(self) -> None:
        self.clocks_text.content = clocks_markdown(self.ctx.session.rig)

    def _measure(self) -> None:
        session, reference, sensor = self.ctx.session, self.reference.value, self.sensor.value
        try:
            time_offset_service.check_pair(session, reference, sensor)
        except InputError as exc:
            self.ctx.notify("Cannot measure the time offset", exc.message, error=True)
            return
        self.jobs.run(f"time offset of {sensor} from {reference}", lambda progress: time_offset_service.solve_session(
            session, reference, sensor, progress=progress), self._fill_history)

    def _fill_history(self, result_id: str | None) -> None:
        session, sensor = self.ctx.session, self.sensor.value
        records = [] if session is None or sensor == NONE else session.results(sensor, time_offset_service.KIND)
        self.history.fill([r["id"] for r in reversed(records)], result_id)
        self._show_result()

    def _show_result(self) -> None:
        result_id = self.history.selected
        record = None if result_id is None else self.ctx.session.result(result_id)
        slot_holder = None if record is None else self.ctx.session.accepted(time_offset_service.slot(record["sensor"]))
        self.card.show(record, slot_holder)
        self.offset_text.content = "" if record is None else (
            f"Time offset **{1e3 * record['time_offset_s']:.2f} ms** ± {1e3 * record['std']['time_s']:.2f} "
            f"(t_{record['sensor_b']} = t_{record['sensor_a']} + offset) · {record['samples']} samples lined up")
        self.plot.image = to_rgb(aligned_signals(record))
