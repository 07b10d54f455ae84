"""Step 11, *Clocks*: the time offset between two sensors' clocks, and each sensor's clock offset in the rig.

The user picks the reference (a camera) and the sensor (a 3D LiDAR, a 2D scanner or another camera), records both
while a board is carried through both views (or, for two 3D LiDARs, while the rig turns in a static scene): *Record
both*, a job storing every frame of each (:mod:`backend.services.motion_recording`); in the simulation the person
carries the board without stopping once asked to. *Measure* then lines up the chosen recording (or every capture,
for imported ones) as a job with progress and Cancel (:mod:`backend.calib.time_offset.service`). The result shows
the offset with its sigma, both signals on the reference's clock (where the offset is right they lie on each other)
and the score over the offsets searched; it is kept in the session's history, and accepting it on the shared result
card sets the sensor's clock offset, which the table of clocks shows and the matching of pairs and sets applies.
"""

from __future__ import annotations

from backend.calib.time_offset import service as time_offset_service
from backend.core.errors import InputError
from backend.core.rig import Rig
from backend.plots.render import to_rgb
from backend.plots.time_offset import aligned_signals
from backend.services import motion_recording
from backend.services.demo import simulated_board_motion
from backend.store.session import Session
from studio.context import StudioContext
from studio.job_panel import JobPanel
from studio.result_card import ResultCard
from studio.result_history import ResultHistory
from studio.wizard.simulated_board import move_board

NONE = "(none)"
DEFAULT_RECORD_S = 15.0
"""Seconds *Record both* records by default: about 7 of the simulated board's carries, 200 frames at 15 Hz."""
ALL_CAPTURES = "(every capture)"
HELP = ("**Record both** while the board is carried through both sensors' views, tilting and turning it, without "
        "stopping (or import both recordings in their steps, then measure *every capture*); for a 2D scanner, turn "
        "the board about a vertical axis as it crosses the scan plane; for two 3D LiDARs, turn the rig about every "
        "axis in a static scene. Then measure. The offset follows Kalibr: `t_sensor = "
        "t_reference + offset`. Accepting it sets the sensor's clock offset; pairs and multi-camera sets are then "
        "matched on the rig's clock.")


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
            self.carry_button = gui.add_button("Carry the board without stopping (simulation)", visible=False,
                                               hint="the simulated person holds the board still at each place in "
                                                    "the yard, which shows no motion to line up")
            self.hold_button = gui.add_button("Hold the board still at each place (simulation)", visible=False,
                                              hint="back to still poses, for the LiDAR-camera pairs and the "
                                                   "multi-camera sets")
            self.duration = gui.add_slider("Record for (s)", min=5.0, max=motion_recording.MAX_DURATION_S, step=1.0,
                                           initial_value=DEFAULT_RECORD_S)
            self.record_button = gui.add_button("Record both", color="green",
                                                hint="every frame of both sensors, stored as one recording")
            self.recording = gui.add_dropdown("Recording", options=[ALL_CAPTURES],
                                              hint="the recording to line up; every capture for imported ones")
            self.measure_button = gui.add_button("Measure the time offset", color="blue")
            self.jobs = JobPanel(ctx, [self.record_button, self.measure_button])
            self.history = ResultHistory(gui, lambda _: self._show_result(), label="Time-offset result")
            self.offset_text = gui.add_markdown("")
            self.plot = gui.add_image(to_rgb(aligned_signals(None)), label="Both signals on the reference's clock")
            self.card = ResultCard(ctx, on_accepted=lambda _: self._show_clocks(),
                                   empty_text="No time-offset result yet.")
            self.clocks_text = gui.add_markdown("")
        self.measure_button.on_click(lambda _: self._measure())
        self.record_button.on_click(lambda _: self._record())
        self.carry_button.on_click(lambda _: move_board(ctx, self.reference.value, "carried"))
        self.hold_button.on_click(lambda _: move_board(ctx, self.reference.value, "scene"))
        self.reference.on_update(lambda _: self._pair_changed())
        self.sensor.on_update(lambda _: self._pair_changed())
        ctx.on_session_changed(self._session_changed)
        ctx.on_rig_changed(lambda _: self._list_sensors())

    def _session_changed(self, session: Session) -> None:
        self._list_sensors()

    def _list_sensors(self) -> None:
        rig = self.ctx.session.rig
        for dropdown, kinds in ((self.reference, ("camera", "lidar3d")), (self.sensor, ("lidar3d", "lidar2d",
                                                                                          "camera"))):
            names = [frame.name for kind in kinds for frame in rig.sensors(kind)] or [NONE]
            dropdown.options = names
            if dropdown.value not in names:
                dropdown.value = names[0]
        self._pair_changed()
        self._show_clocks()

    def _pair_changed(self) -> None:
        self._list_recordings()
        self._show_board_buttons()
        self._fill_history(None)

    def _list_recordings(self, newest: str | None = None) -> None:
        """The recordings holding captures of both sensors, newest first (the newest chosen)."""
        session, pair = self.ctx.session, (self.reference.value, self.sensor.value)
        names = [] if session is None or NONE in pair else [
            name for name in motion_recording.recordings(session, pair[0])
            if name in motion_recording.recordings(session, pair[1])]
        self.recording.options = [*names, ALL_CAPTURES]
        self.recording.value = newest if newest in names else self.recording.options[0]

    def _show_board_buttons(self) -> None:
        """Simulation only: offer to carry the yard's board without stopping, or to hold it still again."""
        session, reference = self.ctx.session, self.reference.value
        motion = None if session is None or reference == NONE else simulated_board_motion(session, reference)
        self.carry_button.visible = motion in ("wave", "scene")
        self.hold_button.visible = motion == "carried"

    def _record(self) -> None:
        session, pair = self.ctx.session, [self.reference.value, self.sensor.value]
        if NONE in pair:
            self.ctx.notify("Nothing to record", "Pick the reference and the sensor to line up first.", error=True)
            return
        seconds = float(self.duration.value)
        self.jobs.run(f"recording {' and '.join(pair)} for {seconds:g} s", lambda progress: motion_recording.
                      record_motion(session, pair, seconds, progress), self._recorded)

    def _recorded(self, recording: motion_recording.Recording) -> None:
        self._list_recordings(recording.name)
        missed = "".join(f"; {camera}: {n} frame(s) without the board" for camera, n in recording.missed.items() if n)
        slow = recording.slow()
        advice = (f" Slow: {', '.join(f'{sensor} {recording.rates_hz[sensor]:.1f}/s' for sensor in slow)}, under "
                  f"{motion_recording.MIN_RATE_HZ:g}/s (a busy machine or a slow device): the offset's σ will show "
                  "what that costs; record again with less running." if slow else "")
        self.ctx.notify("Recorded", f"{recording.name}: " + ", ".join(
            f"{sensor} {n} capture(s)" for sensor, n in recording.stored.items()) + missed + ". Measure it now."
            + advice, error=bool(slow))

    def _show_clocks(self) -> None:
        self.clocks_text.content = clocks_markdown(self.ctx.session.rig)

    def _measure(self) -> None:
        session, reference, sensor = self.ctx.session, self.reference.value, self.sensor.value
        recording = None if self.recording.value == ALL_CAPTURES else self.recording.value
        try:
            time_offset_service.check_pair(session, reference, sensor, recording)
        except InputError as exc:
            self.ctx.notify("Cannot measure the time offset", exc.message, error=True)
            return
        self.jobs.run(f"time offset of {sensor} from {reference}", lambda progress: time_offset_service.solve_session(
            session, reference, sensor, recording=recording, progress=progress), self._fill_history)

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
