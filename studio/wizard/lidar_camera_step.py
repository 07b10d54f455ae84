"""Step 6: LiDAR to camera - the LiDAR's points drawn onto the camera's images, solved and nudged.

The editor holds ``T_camera_lidar`` (it maps LiDAR points into the camera's optical frame): six
sliders move it along and about the camera's or the LiDAR's axes, with nudges, keys, undo and
redo, and its x, y, z, yaw, pitch, roll are shown read-only
(:class:`~studio.transform_sliders.TransformSliders`). Every change redraws the overlay
(:func:`backend.core.overlay.render_overlays`): the chosen scene - one stored image + cloud
pair, all pairs tiled so that every scene is judged at once, or the latest captures -
projected with the camera's intrinsics, coloured over one scale with its legend beneath.
Redraws run on one worker thread that always draws the newest pose, so dragging never queues
work. The first scene's overlay also fills the camera's frustum in 3D, and its cloud can be
painted with the image's colours (under the step's layer group, ``/steps/lidar_camera/...``).
*Open the full-size overlay* opens the API's overlay page (zoom and pan at the image's
resolution) on the same scene, transform and style.

Solving runs as a job from the sliders' transform (solve, then nudge; or nudge, then
solve): target-based on the pairs with a board, or targetless on edges or intensities. Each
solve is kept in the result history with its before/after overlays (shown beside the card)
and its verdict; *Keep the sliders' transform* keeps the sliders' own as a result set by
hand. The result card (:class:`~studio.result_card.ResultCard`) shows the picked result and
accepts it into the rig graph after showing what moves (a ``check`` verdict only with
*Confirm the check* ticked). A board result's poses are drawn under *Board poses*, each one's board against the
plate with its fit and how far the solve without it moves the result; one can be dropped and the rest solved again.
"""

from __future__ import annotations

import html
import threading
from urllib.parse import quote, urlencode

import numpy as np

from backend.calib._session import lidar_names
from backend.calib.lidar_camera import capture as pairs_service
from backend.calib.lidar_camera import service as lidar_camera_service
from backend.calib.lidar_camera.service import PairData
from backend.core.errors import InputError
from backend.core.overlay import COLOUR_MODES, OverlayStyle, mosaic, with_legend
from backend.core.projection import colourise_cloud
from backend.core.result import StoredResult
from backend.core.rig import edge_slot
from backend.core.transforms import to_xyz_ypr, transform_points
from backend.devices.image_io import read_image
from backend.plots.lidar_camera import FLAG_SIGMAS as DROP_HINT_SIGMAS
from backend.plots.lidar_camera import pose_evidence_figure
from backend.plots.render import to_rgb
from backend.services.demo import simulated_board_motion
from studio.context import StudioContext
from studio.job_panel import JobPanel
from studio.marks import WARNING
from studio.result_card import ResultCard
from studio.result_history import ResultHistory
from studio.transform_sliders import TransformSliders
from studio.wizard.simulated_board import move_board

STEP = "lidar_camera"
"""The step's name: its scene nodes live under its layer group (:meth:`studio.scene.RigScene.group`)."""
NONE = "(none)"
ALL_PAIRS = "all pairs"
LATEST = "latest captures"
MAX_TILES = 6
"""Most pairs tiled in the "all pairs" view."""
OVERLAY_WIDTH_PX = 960
"""Width of the overlay shown in the panel (the projection itself runs at the image's full size; the full-size page
shows it so)."""
LEGEND_DIGITS = 2
"""Decimals of the colour scale's ends in the status line."""
MAX_SLIDER_TRANSLATION_M = 0.5
"""The translation sliders reach this far either way from where they were centred."""
COLOURISED_POINT_SIZE_M = 0.02
PLACEHOLDER = np.full((90, 160, 3), 235, np.uint8)
METHODS = {"target (board)": "target", "V-target (two plates)": "vtarget", "targetless (edges)": "edges",
           "targetless (intensity)": "intensity"}
HELP = ("Capture image + cloud pairs with the board held still in view of both (or, for the targetless method, of a "
        "scene with plenty of straight edges). For the board, take 20 or more, near and far, low and high, the board "
        "tilted 15-45 deg from facing the camera every way (turned, leaning, rolled). Move the sliders (increments "
        "along and about the camera's or the LiDAR's axes; keys: W/S A/D R/F move, I/K J/L U/O turn, Shift for fine, "
        "Z/Y undo/redo) until edges, poles and the board line up, then solve from there and nudge what is left. "
        "For V-targets (the session's V-target, step 1), untick Board in view and place the target at nine "
        "positions, two heights each, both faces towards the sensors, leaning some and laying some on their side: "
        "upright targets alone leave the LiDAR's height along the ridges undetermined.")
FULL_SIZE_LINK = ('<a href="{url}" target="calib_studio_overlay" rel="opener" style="display:block;padding:6px 10px;'
                  'border-radius:4px;background:#228be6;color:#fff;text-align:center;text-decoration:none;'
                  'font-size:0.85em">Open the full-size overlay ↗</a>')
"""A link styled as a button: one named tab, which opening the link again redraws with the sliders' newest pose."""


NO_POSES = "A board (target) result shows its poses here: each one's board against the plate, its fit, and how " \
    "far the solve without it moves the result."
POSES_WIDTH_PX = 960
"""Width of the poses' drawing in the panel (px)."""


def poses_table(poses: list[dict], skipped: list[str]) -> str:
    """A markdown table of a target result's poses (its ``diagnostics["poses"]``): points, fits and how far the solve
    without each moves the result; then the poses skipped and why."""
    rows = ["| pose | points | plane mm | ends mm | without it |", "|---|---|---|---|---|"]
    for pose in poses:
        moved = ("—" if pose.get("without_m") is None else
                 f"{1000 * pose['without_m']:.1f} mm, {pose['without_deg']:.2f}° ({pose['without_sigmas']:.1f} σ)")
        flag = f" {WARNING}" if (pose.get("without_sigmas") or 0.0) > DROP_HINT_SIGMAS else ""
        rows.append(f"| {pose['name']}{flag} | {pose['plane_points']} + {pose['edge_points']} | "
                    f"{1000 * pose['plane_rms_m']:.1f} | {1000 * pose['edge_rms_m']:.1f} | {moved} |")
    rows += [f"\nSkipped: {reason}" for reason in skipped]
    return "\n".join(rows)


def _clocks(pairs: list[pairs_service.CapturePair]) -> str:
    """`` · clock offsets assumed: cam 0.00 ms, lidar 37.12 ms`` for pairs stored with a non-zero clock offset (the
    rig's accepted time offsets when they were captured), else nothing."""
    assumed = {name: offset for pair in pairs for name, offset in pair.clock_offsets_s.items() if offset}
    return "" if not assumed else " · clock offsets assumed: " + ", ".join(
        f"{name} {1e3 * offset:.2f} ms" for name, offset in sorted(assumed.items()))


class LidarCameraStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self._scenes: list[PairData] = []
        self._inputs: list[str] = []
        """The captures on screen, as ``sensor:capture`` (what an accepted transform was judged on)."""
        self._page_scene: dict[str, str] = {}
        """The scene on screen in the full-size page's terms: ``scene`` (an image id, or ``all``) and ``cloud_id``."""
        self._wake = threading.Event()
        self._draw_lock = threading.Lock()
        """Held by each redraw, so that leaving a session waits for the one in flight."""
        self._colourised = None
        self._poses_shown = 0
        """Counts the results whose poses were asked for, so that a slow drawing of an older one is not shown."""
        self.result_id: str | None = None
        self.redraws = 0
        """Overlays drawn so far (tests and the status line read it)."""
        gui = ctx.server.gui
        with gui.add_folder("6 · LiDAR to camera", expand_by_default=False):
            gui.add_markdown(HELP)
            self.camera = gui.add_dropdown("Onto camera", options=[NONE])
            self.lidar = gui.add_dropdown("From LiDAR", options=[NONE])
            self.scene_choice = gui.add_dropdown("Scene", options=[LATEST],
                                                 hint="one pair, all pairs tiled, or the latest captures")
            self.data_text = gui.add_markdown("")
            self.capture_button = gui.add_button("Capture pair", hint="an image and a cloud of the same still moment")
            self.capture_jobs = JobPanel(ctx, [self.capture_button])
            self.hold_button = gui.add_button("Hold the board still at each place (simulation)", visible=False,
                                              hint="the simulated person carries the board without stopping (step "
                                                   "11's clocks): a pair needs it held still")
            self.need_board = gui.add_checkbox("Board in view", initial_value=True,
                                               hint="refuse a pair without the board, and wait for it to hold still")
            self.integration = gui.add_number("LiDAR integration (s)", initial_value=0.0, min=0.0, max=60.0, step=0.1,
                                              hint="0: one scan; more: the LiDAR's frames over that time added up "
                                                   "(a Livox fills its field of view in about 0.5 s), the board still")
            self.editor = TransformSliders(gui, lambda _: self._wake.set(), max_translation_m=MAX_SLIDER_TRANSLATION_M)
            self.editor.bind_keys(gui, "LiDAR to camera")
            self.reset_button = gui.add_button("Reset to rig")
            self.method = gui.add_dropdown("Method", options=list(METHODS))
            self.translation_prior = gui.add_number(
                "Translation prior σ (m)", initial_value=0.0, min=0.0, max=1.0, step=0.005,
                hint="targetless: hold the sliders' translation as measured to this 1-sigma; 0: held at the sliders "
                     "+- 5 cm only when the scene cannot determine it (edges all far away fix the rotation but hardly "
                     "the translation)")
            self.solve_button = gui.add_button("Solve from the sliders", color="blue")
            self.jobs = JobPanel(ctx, [self.solve_button, self.capture_button])
            self.capture_jobs.also_disable(self.solve_button)
            self.keep_button = gui.add_button("Keep the sliders' transform",
                                              hint="keep the sliders' transform as a result set by hand (no "
                                                   "uncertainty), to accept it like a solve")
            self.history = ResultHistory(gui, lambda result_id: self._show_result(result_id, move_sliders=True),
                                         hint="every solve and hand-set transform of this pair; pick one to "
                                              "inspect or accept")
            self.card = ResultCard(ctx, on_accepted=self._on_accepted, empty_text="No LiDAR-to-camera result yet.")
            with gui.add_folder("Before / after", expand_by_default=False):
                self.before_image = gui.add_image(PLACEHOLDER, label="Before", format="jpeg")
                self.after_image = gui.add_image(PLACEHOLDER, label="After", format="jpeg")
            with gui.add_folder("Board poses", expand_by_default=False):
                self.poses_text = gui.add_markdown(NO_POSES)
                self.poses_image = gui.add_image(PLACEHOLDER, label="Poses", format="png")
                self.drop_pose = gui.add_dropdown("Pose to drop", options=[NONE],
                                                  hint="a pose whose board points are not the board's (a hand, an "
                                                       "arm, the person behind it), or that moves the result alone")
                self.drop_button = gui.add_button("Drop it and re-solve",
                                                  hint="solve again from this result's pairs without that pose")
            self.jobs.also_disable(self.drop_button)
            self.colour_by = gui.add_dropdown("Colour by", options=list(COLOUR_MODES))
            self.window = gui.add_multi_slider("Range window (m)", min=0.0, max=100.0, step=0.5,
                                               initial_value=(0.5, 40.0))
            self.occlusion = gui.add_checkbox("Hide occluded points", initial_value=True)
            self.radius = gui.add_slider("Point radius (px)", min=0, max=4, step=1, initial_value=1)
            self.paint_cloud = gui.add_checkbox("Paint the cloud with the image (3D)", initial_value=False)
            self.full_size = gui.add_html("")
            self.overlay = gui.add_image(np.full((270, 480, 3), 235, np.uint8), label="Overlay", format="jpeg")
            self.status = gui.add_markdown("")
        self.camera.on_update(lambda _: self._select())
        self.lidar.on_update(lambda _: self._select())
        self.scene_choice.on_update(lambda _: self._load_scenes())
        for handle in (self.colour_by, self.window, self.occlusion, self.radius, self.paint_cloud):
            handle.on_update(lambda _: self._wake.set())
        self.reset_button.on_click(lambda _: self.editor.set(self._rig_T(), undoable=False))  # start afresh there
        self.capture_button.on_click(lambda _: self._capture())
        self.hold_button.on_click(lambda _: move_board(ctx, self.camera.value, "scene"))
        self.solve_button.on_click(lambda _: self._solve())
        self.keep_button.on_click(lambda _: self._keep())
        self.drop_button.on_click(lambda _: self._drop_and_solve())
        self.paint_cloud.on_update(lambda _: self.ctx.show_step(STEP) if self.paint_cloud.value else None)
        threading.Thread(target=self._redraw_loop, name="overlay", daemon=True).start()
        ctx.on_session_closing(self._close)
        ctx.on_session_changed(self._on_session)
        ctx.on_rig_changed(lambda _: self._rig_changed())

    # -- session, sensors and data ------------------------------------------------------------
    def _close(self) -> None:
        """Leave the open session: nothing of its scenes stays on screen or in the 3D view."""
        with self._draw_lock:  # after a redraw in flight, before the next
            self._scenes, self._inputs, self._page_scene = [], [], {}
            self._remove_colourised()

    def _rig_changed(self) -> None:
        self._show_hold_button()
        self._show_result(self.result_id, move_sliders=False)

    def _show_hold_button(self) -> None:
        pair = self.pair
        self.hold_button.visible = pair is not None and simulated_board_motion(self.ctx.session, pair[0]) == "carried"

    def _on_session(self, session) -> None:
        cameras = [f.name for f in session.rig.sensors("camera")]
        lidars = lidar_names(session.rig)
        self.camera.options, self.lidar.options = cameras or [NONE], lidars or [NONE]
        self.camera.value, self.lidar.value = self.camera.options[0], self.lidar.options[0]
        self._select()

    @property
    def pair(self) -> tuple[str, str] | None:
        session, camera, lidar = self.ctx.session, self.camera.value, self.lidar.value
        if session is None or camera not in session.rig.frames or lidar not in session.rig.frames:
            return None  # also while a session fills the lists
        return camera, lidar

    def _rig_T(self) -> np.ndarray:
        pair = self.pair
        return np.eye(4) if pair is None else self.ctx.session.rig.T_a_b(*pair)

    def _select(self) -> None:
        """List the pair's scenes and results, put the rig's transform on the sliders, redraw."""
        pair = self.pair
        self._show_hold_button()
        self.editor.frames = pair
        self.editor.set(self._rig_T(), undoable=False)
        if pair is None:  # not the previous pair's static_transform_publisher line
            self.editor.text.content = "Pick a camera and a LiDAR."
        self._list_scenes()
        accepted = None if pair is None else self.ctx.session.accepted(edge_slot(*pair))
        self._show_result(self.history.fill(self._pair_results(), accepted), move_sliders=False)

    def _stored_pairs(self) -> list[pairs_service.CapturePair]:
        pair = self.pair
        return [] if pair is None else pairs_service.stored_pairs(self.ctx.session, *pair)

    def _list_scenes(self, select: str | None = None) -> None:
        names = [p.name for p in self._stored_pairs()]
        options = ([ALL_PAIRS] if names else []) + names[::-1] + [LATEST]
        wanted = select or self.scene_choice.value
        if wanted not in options or (wanted == LATEST and ALL_PAIRS not in self.scene_choice.options):
            wanted = options[0]  # the latest captures were the only choice so far: open on all pairs if any
        unchanged = wanted == self.scene_choice.value
        self.scene_choice.options = options
        self.scene_choice.value = wanted
        if unchanged:
            self._load_scenes()  # setting the same value again fires no update

    def _load_scenes(self) -> None:
        """Read the chosen scene(s) from the session and redraw."""
        session, pair, choice = self.ctx.session, self.pair, self.scene_choice.value
        self._scenes, self._inputs, self._page_scene = [], [], {}
        if pair is None:
            self.data_text.content = "Pick a camera and a LiDAR (step 2, *Sensors*, adds them)."
        else:
            camera, lidar = pair
            if choice == LATEST:
                self._load_latest(camera, lidar)
            else:
                stored = self._stored_pairs()
                chosen = stored[-MAX_TILES:] if choice == ALL_PAIRS else [p for p in stored if p.name == choice]
                if chosen:
                    self._scenes = lidar_camera_service.load_pairs(session, camera, lidar, [p.image.id for p in chosen])
                self._inputs = [name for p in chosen for name in (f"{camera}:{p.image.id}", f"{lidar}:{p.cloud.id}")]
                if chosen:
                    self._page_scene = {"scene": "all" if choice == ALL_PAIRS else chosen[0].image.id}
                self.data_text.content = f"{len(stored)} pair(s) stored · showing {len(chosen)}" + _clocks(chosen)
            if session.rig.get(camera).intrinsics is None:
                self.data_text.content += f" · {WARNING} this camera has no intrinsics yet: calibrate it in step 3"
        self._wake.set()

    def _load_latest(self, camera: str, lidar: str) -> None:
        session = self.ctx.session
        images = [c for c in session.captures(camera) if not c.n_points]
        clouds = [c for c in session.captures(lidar) if c.n_points]
        if images and clouds:
            name = f"{camera}:{images[-1].id}+{lidar}:{clouds[-1].id}"
            self._scenes = [PairData(name, name, session.capture_image(camera, images[-1].id),
                                     *session.capture_cloud(lidar, clouds[-1].id))]
            self._inputs = [f"{camera}:{images[-1].id}", f"{lidar}:{clouds[-1].id}"]
            self._page_scene = {"scene": images[-1].id, "cloud_id": clouds[-1].id}
        self.data_text.content = (
            f"Image: {images[-1].id if images else '**none captured yet** (step 3)'} · "
            f"cloud: {clouds[-1].id + f' ({clouds[-1].n_points:,} pts)' if clouds else '**none yet** (step 4)'}")

    # -- capture and solve (jobs) ----------------------------------------------------------------
    def _capture(self) -> None:
        session, pair, need_board = self.ctx.session, self.pair, bool(self.need_board.value)
        integration_s = float(self.integration.value) or None
        if pair is None:
            self.ctx.notify("Pick a camera and a LiDAR", "Both are needed for a pair.", error=True)
            return
        self.ctx.show_step(STEP)
        self.capture_jobs.run(f"pair {pair[0]}+{pair[1]}", lambda progress: pairs_service.capture_pair_from_devices(
            session, *pair, require_board=need_board, integration_s=integration_s, progress=progress).name,
            lambda name: self._list_scenes(select=name), done_message="Pair captured in {seconds:.1f} s.")

    def _solve(self) -> None:
        session, pair, T_init, method = self.ctx.session, self.pair, self.editor.T, METHODS[self.method.value]
        targetless = method in ("edges", "intensity")
        prior_m = float(self.translation_prior.value) if targetless and self.translation_prior.value else None
        if pair is None:
            self.ctx.notify("Pick a camera and a LiDAR", "Both are needed to solve.", error=True)
            return
        self.ctx.show_step(STEP)
        self.jobs.run(f"{pair[1]} to {pair[0]} ({method})", lambda progress: lidar_camera_service.solve_session(
            session, *pair, method=method, T_init=T_init, translation_prior_m=prior_m, progress=progress)[0],
            self._on_solved)

    def _on_solved(self, result_id: str) -> None:
        self._show_result(self.history.fill(self._pair_results(), result_id), move_sliders=True)

    # -- results ----------------------------------------------------------------------------------
    def _pair_results(self) -> list[str]:
        """Ids of the pair's LiDAR-to-camera results, newest first."""
        pair = self.pair
        if pair is None:
            return []
        results = self.ctx.session.results(pair[1], lidar_camera_service.KIND)
        return [r["id"] for r in reversed(results) if StoredResult(r).edges[0].parent == pair[0]]

    def _show_result(self, result_id: str | None, move_sliders: bool) -> None:
        session, pair = self.ctx.session, self.pair
        self.result_id = result_id
        if session is None or pair is None or result_id is None:
            self.card.show(None, None)
            self.before_image.image = self.after_image.image = PLACEHOLDER
            self._show_poses(None)
            return
        record = session.result(result_id)
        if move_sliders:
            self.editor.set(StoredResult(record).edges[0].T_parent_child)
        self.card.show(record, session.accepted(edge_slot(*pair)))
        for name, handle in (("overlay_before.jpg", self.before_image), ("overlay_after.jpg", self.after_image)):
            stored = name in record.get("files", [])  # a transform set by hand has none
            handle.image = read_image(session.result_file(result_id, name))[..., ::-1] if stored else PLACEHOLDER
        self._show_poses(record)

    def _show_poses(self, record: dict | None) -> None:
        """The board poses of a target result: each one's board drawn against the plate (on a worker thread: the
        pairs are read back), the table of their fits and leave-one-out moves, and the poses to drop."""
        self._poses_shown += 1
        poses = [] if record is None else record.get("diagnostics", {}).get("poses", [])
        if record is None or record.get("method") != "target" or not poses:
            self.poses_text.content, self.poses_image.image, self.drop_pose.options = NO_POSES, PLACEHOLDER, [NONE]
            return
        self.poses_text.content = poses_table(poses, record.get("diagnostics", {}).get("skipped", []))
        self.drop_pose.options = [pose["name"] for pose in poses]
        self.drop_pose.value = max(poses, key=lambda pose: pose.get("without_sigmas") or 0.0)["name"]
        shown, session, lidar, result_id = self._poses_shown, self.ctx.session, record["sensor"], record["id"]

        def draw() -> None:
            try:
                evidence = lidar_camera_service.session_pose_evidence(session, lidar, result_id)
                image = to_rgb(pose_evidence_figure(evidence, f"{result_id}: each pose's board at the result"),
                               POSES_WIDTH_PX)
            except Exception as exc:  # noqa: BLE001 - an exception would end the thread unseen, the old figure shown
                image = PLACEHOLDER
                why = f"{exc.input}: {exc.message}" if isinstance(exc, InputError) else f"{type(exc).__name__}: {exc}"
                self.poses_text.content += f"\n\n{WARNING} the poses cannot be drawn: {why}"
            if shown == self._poses_shown:
                self.poses_image.image = image

        threading.Thread(target=draw, name="poses", daemon=True).start()

    def _drop_and_solve(self) -> None:
        """Solve again, by the board method from the shown result's transform, from its pairs less the chosen pose."""
        session, pair, result_id, dropped = self.ctx.session, self.pair, self.result_id, self.drop_pose.value
        if pair is None or result_id is None or dropped == NONE:
            self.ctx.notify("Nothing to drop", "Show a board (target) result with its poses first.", error=True)
            return
        record = session.result(result_id)
        kept = [p.image.id for p in self._stored_pairs() if p.name in record.get("inputs", []) and p.name != dropped]
        T_init = StoredResult(record).edges[0].T_parent_child
        self.ctx.show_step(STEP)
        self.jobs.run(f"{pair[1]} to {pair[0]} (target) without {dropped}",
                      lambda progress: lidar_camera_service.solve_session(
                          session, *pair, method="target", T_init=T_init, image_ids=kept, progress=progress)[0],
                      self._on_solved)

    def _keep(self) -> None:
        """Keep the sliders' transform as a result set by hand, judged on the captures on screen, and show it."""
        session, pair = self.ctx.session, self.pair
        if pair is None:
            self.ctx.notify("Nothing to keep", "Pick a camera and a LiDAR first.", error=True)
            return
        try:
            result_id = lidar_camera_service.store_manual(session, *pair, self.editor.T, inputs=self._inputs)
        except InputError as exc:
            self.ctx.notify("Cannot keep the transform", exc.message, error=True)
            return
        self._show_result(self.history.fill(self._pair_results(), result_id), move_sliders=False)
        self.ctx.notify("Kept", f"{result_id}: T_{pair[0]}_{pair[1]} as set on the sliders; accept it below.")

    def _on_accepted(self, result_id: str) -> None:
        """The card accepted ``result_id``: list it as accepted, and redraw the overlay with the re-fitted rig."""
        self.history.fill(self._pair_results(), result_id)
        self._wake.set()

    # -- drawing (worker thread) ------------------------------------------------------------------
    def _redraw_loop(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()  # changes from now on wake the next pass; this one draws the newest state
            try:
                with self._draw_lock:
                    self._redraw()
            except Exception as exc:  # noqa: BLE001 - the worker must survive one bad input and say why
                self.status.content = f"{WARNING} overlay failed: {exc}"

    @property
    def style(self) -> OverlayStyle:
        return OverlayStyle(colour_by=self.colour_by.value, range_m=tuple(self.window.value),
                            occlusion_px=OverlayStyle.occlusion_px if self.occlusion.value else 0,
                            radius_px=int(self.radius.value))

    def _redraw(self) -> None:
        session, pair, scenes = self.ctx.session, self.pair, self._scenes
        intrinsics = None if pair is None else session.rig.get(pair[0]).intrinsics
        if pair is None or not scenes or intrinsics is None:
            self.status.content = "Nothing to draw yet."
            self.full_size.content = ""
            self.overlay.image = PLACEHOLDER
            return
        camera, lidar = pair
        T_camera_lidar, style = self.editor.T, self.style
        try:
            drawn, projections, scale = lidar_camera_service.render_scenes(session, camera, lidar, scenes,
                                                                           T_camera_lidar, style)
        except InputError as exc:
            self.status.content = f"{WARNING} {exc.input}: {exc.message}"
            return
        kept = sum(len(p) for p in projections)
        self.overlay.image = with_legend(mosaic(drawn, OVERLAY_WIDTH_PX), scale)[..., ::-1]
        self.full_size.content = FULL_SIZE_LINK.format(url=html.escape(self._page_url(T_camera_lidar, style)))
        self.ctx.scene.show_camera_image(camera, drawn[0])
        self._paint_cloud(scenes[0], T_camera_lidar, intrinsics, lidar)
        self.redraws += 1
        total = sum(len(s.points) for s in scenes)
        self.status.content = (f"{kept:,} of {total:,} points drawn"
                               + (f" over {len(scenes)} pairs" if len(scenes) > 1 else "")
                               + f" · colours: {scale.label} {scale.lo:.{LEGEND_DIGITS}f}–{scale.hi:.{LEGEND_DIGITS}f}")
        if kept == 0:
            self.status.content += (f" · {WARNING} no point lands in the image: the cloud and the camera do not "
                                    "overlap with this transform (check the range window and the sliders)")

    def _page_url(self, T_camera_lidar: np.ndarray, style: OverlayStyle) -> str:
        """The full-size overlay page of the API on the scene on screen, drawn with ``T_camera_lidar`` and ``style``."""
        camera, lidar = self.pair
        xyz, ypr = to_xyz_ypr(T_camera_lidar)
        query = {"camera": camera, "lidar": lidar, **self._page_scene,
                 "xyz_m": ",".join(f"{v:.9g}" for v in xyz), "ypr_deg": ",".join(f"{v:.9g}" for v in np.degrees(ypr)),
                 "colour_by": style.colour_by, "range_m": ",".join(f"{v:g}" for v in style.range_m),
                 "occlusion_px": style.occlusion_px, "radius_px": style.radius_px}
        return (f"{self.ctx.api_url}/api/sessions/{quote(self.ctx.session.name)}/lidar-camera/view?"
                f"{urlencode(query)}")

    def _remove_colourised(self) -> None:
        if self._colourised is not None:
            self._colourised.remove()
            self._colourised = None

    def _paint_cloud(self, scene: PairData, T_camera_lidar: np.ndarray, intrinsics, lidar: str) -> None:
        """The reverse view: the cloud in 3D in the image's colours (points the camera does not see left out)."""
        self._remove_colourised()
        if not self.paint_cloud.value:
            return
        colours, seen = colourise_cloud(scene.points, T_camera_lidar, intrinsics, scene.image,
                                        occlusion_px=OverlayStyle.occlusion_px)
        points_root = transform_points(self.ctx.session.rig.T_root_frame(lidar), scene.points[seen])
        self._colourised = self.ctx.server.scene.add_point_cloud(
            f"{self.ctx.scene.group(STEP)}/{lidar}/colourised", points_root.astype(np.float32), colours[seen],
            point_size=COLOURISED_POINT_SIZE_M, precision="float32")

