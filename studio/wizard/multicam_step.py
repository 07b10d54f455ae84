"""Step 7: multi-camera rig - synchronised sets, one joint solve of every camera, its checks, accept, export.

A *set* is one moment seen by several cameras (:mod:`backend.calib.multicam.capture`):
captured here from every chosen camera's device at once, refused when the frame times
spread over more than the tolerance, or imported from a recorded bag, whose frames are
matched by timestamp (frames no other camera matches are reported, not stored). *Solve*
runs the joint calibration (:func:`backend.calib.multicam.service.solve_session`) as a job:
the reference camera keeps its place in the rig and every other camera is solved
relative to it; cameras without intrinsics get them estimated from the sets.

Each result answers "how good is this": the result card (:class:`~studio.result_card.ResultCard`)
shows every camera's ``T_ref_cam`` with its 1-sigma, the verdict and the warnings, and accepts
it (each camera an edge of the rig graph, after the rig preview; an older result reverts);
beside it per camera its verdict, RMS and estimated intrinsics, the observation graph (which
cameras saw the board together, how often), per-frame residual bars, per pair the baseline
and the epipolar error, with the stereo check of any set
(:func:`backend.calib.multicam.service.stereo_check`), and in 3D the solved frusta and board poses
beside the rig, in the step's layer group. The rig is then exported as the rig transforms YAML
(with ROS static transforms) or a Kalibr camchain.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from backend.calib.multicam import capture as capture_service
from backend.calib.multicam import service as multicam_service
from backend.calib.multicam.service import LINE_COLOUR_BGR, Rectification
from backend.core.boards import BoardSpec
from backend.core.camera import DIST_NAMES, CameraIntrinsics
from backend.core.errors import InputError
from backend.plots.multicam import covisibility_graph, frame_residual_bars
from backend.plots.render import to_rgb
from backend.services.demo import move_simulated_board, simulated_board_motion
from studio.context import StudioContext
from studio.job_panel import JobPanel
from studio.marks import WARNING
from studio.result_card import ResultCard
from studio.result_history import ResultHistory

STEP = "multicam"
"""The step's layer group in the 3D view (:mod:`studio.layers`)."""
NONE = "(none)"
HELP = ("Hold the board still where **two or more cameras** see it and capture a set; move it so that every camera "
        "shares sets with the others (the observation graph must link them all) and the board reaches the corners "
        "of each image. Or import sets from a recorded bag. **Solve rig** calibrates all cameras at once: the "
        "reference stays where the rig has it and the others are placed relative to it; a camera without "
        "intrinsics has them estimated from the sets.")
HELP_FILE = Path(__file__).resolve().parents[2] / "frontend_assets" / "help" / "heating_the_board.md"
MAX_SET_ROWS = 5
"""Newest sets listed one by one (all are counted)."""
MAX_UNMATCHED_LISTED = 12
PREVIEW_WIDTH_PX = 960
LINE_SPACING_PX = 64
"""Rows (px of the full images) between the rectified preview's lines."""
PLACEHOLDER = np.full((90, 320, 3), 235, np.uint8)
DEFAULT_LIMIT = 200


def _help_text() -> str:
    """The thermal help page, its title dropped (the folder carries it)."""
    try:
        lines = HELP_FILE.read_text(encoding="utf-8").splitlines()
    except OSError:
        return ("Warm or cool the board evenly (sunlight, a heat gun from behind, a heated plate) until its pattern "
                "shows.")
    return "\n".join(lines[1:] if lines and lines[0].startswith("# ") else lines).strip()


class MulticamStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self._boxes: dict = {}
        """Camera -> its checkbox ("use in the rig")."""
        self._topics: dict = {}
        """Camera -> the text box of its bag topic."""
        self._record: dict | None = None
        """The result on show."""
        self._filling = False
        """True while the step itself sets a dropdown (setting one fires its callback)."""
        gui = ctx.server.gui
        with gui.add_folder("7 · Multi-camera", expand_by_default=False):
            gui.add_markdown(HELP)
            self.camera_folder = gui.add_folder("Cameras")
            self.reference = gui.add_dropdown("Reference camera", options=[NONE],
                                              hint="keeps its place in the rig; the others are solved relative to it")
            self.sets_text = gui.add_markdown("")
            self.lens_text = gui.add_markdown("")
            self.scene_button = gui.add_button("Carry the board about the yard (simulation)", visible=False,
                                               hint="the simulated person waves the board for a lens calibration: "
                                                    "have them carry it about the yard again, seen by every camera")
            self.tolerance_ms = gui.add_number("Time tolerance (ms)", initial_value=1e3 * capture_service.
                                               DEFAULT_TOLERANCE_S, min=0.0, max=5000.0, step=1.0,
                                               hint="largest spread of the frame times within one set")
            self.need_board = gui.add_checkbox("Board in view of two", initial_value=True,
                                               hint="refuse a set unless at least two cameras see the board")
            self.capture_button = gui.add_button("Capture set", color="green",
                                                 hint="one frame of every chosen camera, read at the same moment")
            self.capture_jobs = JobPanel(ctx, [self.capture_button])
            with gui.add_folder("Import from a bag", expand_by_default=False):
                self.bag_path = gui.add_text("Bag path", "", hint="a ROS 2 bag folder (or its .db3 / .mcap file)")
                self.topic_folder = gui.add_folder("Image topic per camera")
                self.match_ms = gui.add_number("Match tolerance (ms)", initial_value=1e3 * capture_service.
                                               DEFAULT_TOLERANCE_S, min=0.0, max=5000.0, step=1.0,
                                               hint="frames are matched by header stamp: the largest spread within "
                                                    "one set (well under half the frame period)")
                self.every = gui.add_number("Every n-th set", initial_value=1, min=1, max=1000, step=1)
                self.limit = gui.add_number("At most (sets)", initial_value=DEFAULT_LIMIT, min=1, max=10_000, step=1)
                self.import_button = gui.add_button("Import sets")
                self.import_jobs = JobPanel(ctx, [self.import_button])
                self.import_text = gui.add_markdown("")
            self.refine = gui.add_checkbox("Refine intrinsics", initial_value=False,
                                           hint="refine every camera's intrinsics with the rig (a camera without "
                                                "intrinsics is always estimated)")
            self.solve_button = gui.add_button("Solve rig", color="blue")
            self.jobs = JobPanel(ctx, [self.capture_button, self.solve_button])
            self.capture_jobs.also_disable(self.solve_button)
            self.history = ResultHistory(gui, lambda result_id: self._show_result(result_id, draw=True),
                                         label="Rig result",
                                         hint="every solve of these cameras; pick one to inspect, accept or revert to")
            self.card = ResultCard(ctx, on_accepted=lambda result_id: self._show_result(result_id, draw=True),
                                   empty_text="No multi-camera result for these cameras yet.")
            self.rig_text = gui.add_markdown("")
            self.show_3d = gui.add_checkbox("Show the solved rig in 3D", initial_value=True,
                                            hint="orange frusta and the board poses, placed from the reference")
            self.graph_image = gui.add_image(to_rgb(covisibility_graph([], {}, [])), label="Observation graph")
            self.residual_image = gui.add_image(to_rgb(frame_residual_bars([], [])), label="Per-frame RMS")
            with gui.add_folder("Stereo check", expand_by_default=False):
                self.stereo_pair = gui.add_dropdown("Stereo pair", options=[NONE])
                self.stereo_set = gui.add_dropdown("Stereo set", options=[NONE])
                self.stereo_text = gui.add_markdown("")
                self.stereo_image = gui.add_image(PLACEHOLDER, label="Rectified (rows should match)", format="png")
            with gui.add_folder("Export", expand_by_default=False):
                gui.add_markdown("The rig as accepted: every transform with its sigmas and the "
                                 "`static_transform_publisher` lines, or Kalibr's camchain (`T_cn_cnm1`).")
                self.export_rig = gui.add_button("Download rig YAML (ROS transforms)")
                self.export_kalibr = gui.add_button("Download Kalibr camchain")
            with gui.add_folder("Thermal cameras: heating the board", expand_by_default=False):
                gui.add_markdown(_help_text())
        self.reference.on_update(lambda _: None if self._filling else self._select())
        self.capture_button.on_click(lambda _: self._capture())
        self.import_button.on_click(lambda _: self._import())
        self.solve_button.on_click(lambda _: self._solve())
        self.scene_button.on_click(lambda _: self._carry_board())
        ctx.on_rig_changed(lambda _: self._lens_guidance())
        self.show_3d.on_update(lambda _: self._draw_3d())
        self.stereo_pair.on_update(lambda _: None if self._filling else self._pair_sets())
        self.stereo_set.on_update(lambda _: None if self._filling else self._show_stereo())
        self.export_rig.on_click(lambda event: self.ctx.download(event, "rig"))
        self.export_kalibr.on_click(lambda event: self.ctx.download(event, "kalibr"))
        ctx.on_session_closing(self.ctx.scene.clear_solved_cameras)
        ctx.on_session_changed(self._on_session)

    # -- session and cameras -------------------------------------------------------------------
    def _on_session(self, session) -> None:
        for handle in [*self._boxes.values(), *self._topics.values()]:
            handle.remove()
        self.import_text.content = ""
        names = [f.name for f in session.rig.sensors("camera")]
        in_sets = {c for s in capture_service.stored_sets(session) for c in s.cameras} if len(names) >= 2 else set()
        ticked = [n for n in names if n in in_sets] if len(in_sets) >= 2 else names
        gui = self.ctx.server.gui
        with self.camera_folder:
            self._boxes = {name: gui.add_checkbox(name, initial_value=name in ticked) for name in names}
        recorded = {name: session.rig.get(name).device for name in names
                    if session.rig.get(name).device.get("driver") == "rosbag"}
        with self.topic_folder:
            self._topics = {name: gui.add_text(name, str(recorded.get(name, {}).get("topic", ""))) for name in names}
        if recorded and not self.bag_path.value:  # cameras replaying a bag: offer it
            self.bag_path.value = str(next(iter(recorded.values())).get("path", ""))
        for box in self._boxes.values():
            box.on_update(lambda _: self._on_ticked())
        self._on_ticked(draw=False)

    @property
    def ticked(self) -> list[str]:
        return [name for name, box in self._boxes.items() if box.value]

    @property
    def cameras(self) -> list[str]:
        """The chosen cameras, the reference first (the order the solve takes them in)."""
        ticked, reference = self.ticked, self.reference.value
        if reference not in ticked:
            return ticked
        return [reference] + [name for name in ticked if name != reference]

    def _offer(self, dropdown, options: list[str]) -> None:
        """Set a dropdown's options, keeping its value if still offered (else the first), without its callback."""
        self._filling = True
        try:
            dropdown.options = options or [NONE]
            if dropdown.value not in dropdown.options:
                dropdown.value = dropdown.options[0]
        finally:
            self._filling = False

    def _on_ticked(self, draw: bool = True) -> None:
        """Offer the ticked cameras as the reference (keeping the current one if still ticked) and list again."""
        self._offer(self.reference, self.ticked)
        self._select(draw)

    def _select(self, draw: bool = True) -> None:
        """List the chosen cameras' sets and results; show the accepted result, or the newest."""
        self._list_sets()
        cameras = self.cameras
        accepted = self.ctx.session.accepted(multicam_service.slot(cameras)) if len(cameras) >= 2 else None
        self._show_result(self.history.fill(self._results(), accepted), draw)

    def _lens_guidance(self) -> None:
        """Which chosen cameras have no lens calibration (their intrinsics would only be estimated inside the rig,
        unchecked): calibrate them in step 3 first, then come back; in a simulation, the board is put back in the
        yard for the rig."""
        session, cameras = self.ctx.session, self.cameras
        if session is None:
            return
        missing = [name for name in cameras if session.rig.get(name).intrinsics is None]
        self.lens_text.content = "" if not missing else (
            f"{WARNING} {', '.join(missing)} {'has' if len(missing) == 1 else 'have'} no lens calibration yet: "
            f"the rig solve would only estimate it, unchecked. Calibrate it first in step 3, *Camera intrinsics* "
            f"(pick {missing[0]}; in the simulation press *Wave the board in front of it* there), accept it, then "
            f"come back here and solve the rig.")
        self.scene_button.visible = any(simulated_board_motion(session, name) in ("wave", "carried")
                                        for name in cameras)

    def _carry_board(self) -> None:
        """Simulation only: every chosen simulated camera sees the board carried about the yard again."""
        session = self.ctx.session
        try:
            for name in self.cameras:
                if simulated_board_motion(session, name) in ("wave", "carried"):
                    move_simulated_board(session, name, "scene")
        except InputError as exc:
            self.ctx.notify("Cannot move the simulated board", exc.message, error=True)
            return
        self.ctx.rig_changed()

    def _list_sets(self) -> None:
        self._lens_guidance()
        session, cameras = self.ctx.session, self.cameras
        if session is None or len(cameras) < 2:
            self.sets_text.content = "Tick at least two cameras."
            return
        sets = capture_service.stored_sets(session, cameras)
        self.sets_text.content = sets_markdown(sets, cameras)

    # -- capture and import (jobs) -----------------------------------------------------------------
    def _capture(self) -> None:
        session, cameras = self.ctx.session, self.cameras
        if len(cameras) < 2:
            self.ctx.notify("Tick two cameras", "A set needs at least two cameras.", error=True)
            return
        tolerance_s, need_board = float(self.tolerance_ms.value) / 1e3, bool(self.need_board.value)
        self.capture_jobs.run(f"set of {', '.join(cameras)}", lambda progress: capture_service.capture_set_from_devices(
            session, cameras, tolerance_s=tolerance_s, require_board=need_board, progress=progress),
            self._on_captured, done_message="Set captured in {seconds:.1f} s.")

    def _on_captured(self, found: capture_service.MulticamSet) -> None:
        session = self.ctx.session
        for camera, capture in found.captures.items():
            self.ctx.scene.show_camera_image(camera, session.capture_image(camera, capture.id))
        seen = ", ".join(found.cameras_with_board) or "no camera"
        self.capture_jobs.text.content += f" **{found.name}**: the board was seen by {seen}."
        self._list_sets()

    def _import(self) -> None:
        session, cameras, path = self.ctx.session, self.cameras, self.bag_path.value.strip()
        topics = {name: self._topics[name].value.strip() for name in cameras if self._topics[name].value.strip()}
        if not path or len(topics) < 2:
            self.ctx.notify("Bag and topics", "Give the bag's path and the image topic of at least two ticked "
                            "cameras.", error=True)
            return
        tolerance_s, every, limit = float(self.match_ms.value) / 1e3, int(self.every.value), int(self.limit.value)
        self.import_jobs.run(f"sets from {Path(path).name}", lambda progress: capture_service.import_bag_sets(
            session, path, topics, tolerance_s=tolerance_s, every=every, limit=limit, progress=progress).to_dict(),
            self._on_imported, done_message="Imported in {seconds:.1f} s.")

    def _on_imported(self, report: dict) -> None:
        self.import_text.content = bag_report_markdown(report)
        self._list_sets()

    # -- solve and results --------------------------------------------------------------------------
    def _solve(self) -> None:
        session, cameras, refine = self.ctx.session, self.cameras, bool(self.refine.value)
        if len(cameras) < 2:
            self.ctx.notify("Tick two cameras", "A rig needs at least two cameras.", error=True)
            return
        self.jobs.run(f"rig of {', '.join(cameras)}", lambda progress: multicam_service.solve_session(
            session, cameras, refine_intrinsics=refine, progress=progress)[0], self._on_solved,
            done_message="Solved in {seconds:.1f} s.")

    def _on_solved(self, result_id: str) -> None:
        self._show_result(self.history.fill(self._results(), result_id), draw=True)

    def _results(self) -> list[str]:
        """Ids of the multicam results of exactly the chosen cameras (any reference), newest first."""
        chosen = sorted(self.cameras)
        if self.ctx.session is None or len(chosen) < 2:
            return []
        results = self.ctx.session.results(None, multicam_service.KIND)
        return [r["id"] for r in reversed(results) if sorted(r.get("camera_order", [])) == chosen]

    def _show_result(self, result_id: str | None, draw: bool) -> None:
        session = self.ctx.session
        self._record = None if session is None or result_id is None else session.result(result_id)
        record = self._record
        accepted = None if record is None else session.accepted(multicam_service.slot(record["camera_order"]))
        for handle in (self.export_rig, self.export_kalibr):
            handle.disabled = accepted is None
        self.card.show(record, accepted)
        if record is None:
            self.rig_text.content = ""
            self.graph_image.image = to_rgb(covisibility_graph([], {}, []))
            self.residual_image.image = to_rgb(frame_residual_bars([], []))
            self.ctx.scene.clear_solved_cameras()
            self._fill_pairs()
            return
        self.rig_text.content = rig_markdown(record)
        graph = record["graph"]
        self.graph_image.image = to_rgb(covisibility_graph(graph["cameras"], graph["frames_seen"], graph["edges"],
                                                           record["reference"]))
        self.residual_image.image = to_rgb(frame_residual_bars(record["camera_order"], record["frames"]))
        self._fill_pairs()
        if draw:
            self._draw_3d()

    def _draw_3d(self) -> None:
        """The solved frusta and board poses of the result on show, if asked for."""
        session, record = self.ctx.session, self._record
        if record is None or not self.show_3d.value:
            self.ctx.scene.clear_solved_cameras()
            return
        self.ctx.show_step(STEP)
        self.ctx.scene.show_solved_cameras(
            STEP, session.rig, record["reference"], multicam_service.record_T_ref_cam(record),
            {n: CameraIntrinsics.from_dict(c) for n, c in record["cameras"].items()}, BoardSpec.parse(record["board"]),
            {n: np.array(T) for n, T in record["T_ref_board"].items()}, tag=record["id"])

    # -- stereo check ----------------------------------------------------------------------------------
    def _fill_pairs(self) -> None:
        record = self._record
        self._offer(self.stereo_pair, [f"{p['a']} + {p['b']}" for p in record["pairs"]] if record else [])
        self._pair_sets()

    @property
    def pair(self) -> tuple[str, str] | None:
        if self._record is None or self.stereo_pair.value == NONE:
            return None
        a, b = self.stereo_pair.value.split(" + ")
        return a, b

    def _pair_sets(self) -> None:
        pair, record = self.pair, self._record
        sets = [] if pair is None else list(multicam_service.stereo_sets(self.ctx.session, record, *pair))
        self._offer(self.stereo_set, sets)
        self._show_stereo()

    def _show_stereo(self) -> None:
        pair, record = self.pair, self._record
        if pair is None or self.stereo_set.value == NONE:
            self.stereo_text.content = "Solve a rig whose cameras saw the board together."
            self.stereo_image.image = PLACEHOLDER
            return
        check = multicam_service.stereo_check(self.ctx.session, record["id"], *pair, self.stereo_set.value,
                                              LINE_SPACING_PX)
        self.stereo_text.content = stereo_markdown(check)
        rect = check.rectification
        self.stereo_image.image = PLACEHOLDER if rect is None else _panel_preview(rect, check.preview_bgr)[..., ::-1]


def _panel_preview(rect: Rectification, preview: np.ndarray) -> np.ndarray:
    """The rectified preview (BGR) scaled to the panel, its lines drawn again one pixel wide so that they stay
    crisp (averaged into the image they would fade)."""
    scale = PREVIEW_WIDTH_PX / preview.shape[1]
    small = cv2.resize(preview, (PREVIEW_WIDTH_PX, int(round(preview.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    across = 1 if rect.vertical else 0
    lines = np.arange(0, preview.shape[across], LINE_SPACING_PX)
    lines = np.minimum(np.round(lines * scale).astype(int), small.shape[across] - 1)
    if rect.vertical:
        small[:, lines] = LINE_COLOUR_BGR
    else:
        small[lines] = LINE_COLOUR_BGR
    return small


def stereo_markdown(check: multicam_service.StereoCheck) -> str:
    """One pair's stereo check on one set: corners, epipolar error, rectified offset and baseline."""
    line = (f"**{check.set_name}**, {check.left} left, {check.right} right: {check.corners} corners seen by both · "
            f"epipolar error RMS {check.epipolar_rms_px:.2f} px, max {check.epipolar_max_px:.2f} px")
    rect = check.rectification
    if rect is None:
        return f"{line}\n\n{WARNING} no rectified preview: {check.no_preview}"
    across = "column" if rect.vertical else "row"
    return (f"{line} · rectified {across} offset RMS {check.row_offset_rms_px:.2f} px · baseline "
            f"{1e3 * rect.baseline_m:.1f} mm")


def _estimated(record: dict, camera: str) -> str:
    """An estimated camera's intrinsics with their 1-sigma and its worst projection sigma across the image."""
    intrinsics, std = CameraIntrinsics.from_dict(record["cameras"][camera]), record["intrinsics_std"][camera]
    values = {"fx": intrinsics.K[0, 0], "fy": intrinsics.K[1, 1], "cx": intrinsics.K[0, 2], "cy": intrinsics.K[1, 2],
              **dict(zip(DIST_NAMES[intrinsics.model], intrinsics.dist, strict=False))}
    terms = " ".join(f"{name} {values[name]:.4g}±{'n/a' if sigma is None else f'{sigma:.2g}'}"
                     for name, sigma in std.items())
    projection = record.get("intrinsics_projection_sigma_px", {}).get(camera)
    return f"yes: {terms}; projection σ ≤ {'n/a' if projection is None else f'{projection:.2f}'} px"


def sets_markdown(sets: list[capture_service.MulticamSet], cameras: list[str]) -> str:
    """How many sets hold at least two of ``cameras``, which cameras saw the board in each (newest first)."""
    if not sets:
        return (f"**No sets** of {', '.join(cameras)} yet: capture one with the board in view of at least two of "
                "them, or import a bag.")
    useful = sum(len(s.cameras_with_board) >= capture_service.MIN_BOARD_VIEWS for s in sets)
    rows = "\n".join(f"| {s.name} | {', '.join(s.cameras_with_board) or 'none'} |"
                     for s in sets[::-1][:MAX_SET_ROWS])
    more = f"\n\n… and {len(sets) - MAX_SET_ROWS} older" if len(sets) > MAX_SET_ROWS else ""
    return (f"**{len(sets)} sets** of {', '.join(cameras)} · {useful} with the board in view of two or more\n\n"
            f"| set | board seen by |\n|---|---|\n{rows}{more}")


def bag_report_markdown(report: dict) -> str:
    """A bag import's counts per camera, and the frames no other camera matched."""
    rows, unmatched = [], []
    for camera, c in report["cameras"].items():
        rows.append(f"| {camera} | `{c['topic']}` | {c['read']} | {c['matched']} | {c['unmatched']} | {c['stored']} |")
        if c["unmatched_frames"]:
            listed = ", ".join(f"#{i}" for i in c["unmatched_frames"][:MAX_UNMATCHED_LISTED])
            extra = " …" if len(c["unmatched_frames"]) > MAX_UNMATCHED_LISTED else ""
            unmatched.append(f"- {camera}: {listed}{extra}")
        if c["skipped"]:
            unmatched.append(f"- {camera}: {len(c['skipped'])} messages skipped ({c['skipped'][0]['message']})")
    no_board = f" · {report['no_board']} without the board in two views" if report["no_board"] else ""
    return (f"**{len(report['sets'])} sets stored** of {report['matched_sets']} matched{no_board} · {report['ended']}"
            "\n\n| camera | topic | read | matched | unmatched | stored |\n|---|---|---|---|---|---|\n"
            + "\n".join(rows)
            + ("\n\n**Frames in no set** (no other camera within the tolerance):\n" + "\n".join(unmatched)
               if unmatched else "\n\nEvery frame was matched."))


def rig_markdown(record: dict) -> str:
    """What the result card does not show of a multicam result: the sets and views used, per camera its verdict,
    RMS and the intrinsics estimated with the rig, and the pair checks."""
    estimated = set(record["settings"]["estimate_intrinsics"])
    verdicts = record.get("verdict", {})
    flagged = sum(f["flagged"] for f in record["frames"])
    rows = [f"| {name} | {verdicts.get(name, {}).get('level', 'none')} | {record['rms_px'][name]:.3f} | "
            f"{_estimated(record, name) if name in estimated else 'no'} |" for name in record["camera_order"]]
    pairs = "\n".join(f"| {p['a']} + {p['b']} | {p['frames']} | {1e3 * p['baseline_m']:.1f} | "
                      f"{p['epipolar_rms_px']:.3f} |" for p in record.get("pairs", []))
    return (f"**{len(record['T_ref_board'])} sets** · {len(record['frames']) - flagged} views used, {flagged} flagged "
            f"· reference {record['reference']}\n\n"
            "| camera | verdict | RMS (px) | intrinsics estimated |\n|---|---|---|---|\n" + "\n".join(rows)
            + ("\n\n| pair | shared sets | baseline (mm) | epipolar RMS (px) |\n|---|---|---|---|\n" + pairs
               if pairs else ""))
