"""Step 4: LiDARs - live clouds, capture, and LiDAR-to-LiDAR extrinsics (guess, refine, inspect, accept).

Live: one :class:`~backend.services.live_clouds.LiveClouds` thread per ticked LiDAR
draws its cloud under ``/steps/lidar/<sensor>/live`` (the step's layer group; each sensor's
node there is posed where the rig has the sensor, and follows it when an accept or a revert moves
it; starting live or a job puts the step in view), range-windowed,
coloured by sensor, intensity, height or range, at most *Points drawn per LiDAR*
(default :data:`MAX_DISPLAY_POINTS`; an even stride; the full scan is what gets captured).
Each live cloud is one scene node whose buffers are replaced in place, float16 on the wire.

LiDAR to LiDAR: the six sliders *are* ``T_target_source`` (m, ROS yaw/pitch/roll in
degrees). The target's latest captured cloud is drawn under ``/steps/lidar/<target>/l2l`` and
the source's as a child node posed by the sliders, so moving a slider only re-poses
that node (no points re-sent). "Global guess" and "Refine (GICP)" run as jobs and
write their transform back into the sliders; refine starts from the sliders and solves
one transform over the ticked capture pairs (*Scenes*: pairs taken in different places
cross-check each other). Half a second after the last nudge the source cloud is
recoloured by its distance to the target at the new pose (colours only). The guess and
the fit at the sliders' pose are :mod:`backend.calib.lidar_lidar.service`'s; this step only draws.
The :class:`~studio.result_card.ResultCard` shows the result (pose, sigma, residuals, verdict)
and accepts it into the rig's tree with its preview; beside it, every scene's own solve and the
cloud-to-cloud histogram.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import viser
from scipy.spatial import cKDTree

from backend.calib._session import lidar_names, store_cloud
from backend.calib.lidar_lidar import service as lidar_service
from backend.calib.lidar_lidar.service import LidarLidarSettings
from backend.calib.rig import service as rig_service
from backend.calib.sweep import service as sweep_service
from backend.core.colour_maps import distance_colours
from backend.core.errors import InputError
from backend.plots.lidar_lidar import c2c_histogram
from backend.plots.render import to_rgb
from backend.services.demo import ROBOT_PLACE_NAMES, move_simulated_robot, simulated_place
from backend.services.live_clouds import CloudCallbacks, LiveClouds
from studio import cloud_colours as cc
from studio.context import StudioContext
from studio.frame_pacer import FramePacer
from studio.job_panel import JobPanel
from studio.live_toggle import LiveToggle
from studio.marks import WARNING, mark
from studio.result_card import ResultCard, rotation_vector_deg
from studio.result_history import ResultHistory
from studio.scene import viser_pose
from studio.transform_sliders import TransformSliders
from studio.wizard.accumulate_panel import AccumulatePanel
from studio.wizard.cloud_import_panel import CloudImportPanel

NONE = "(no LiDAR)"
STEP = "lidar"
"""This step's layer group (``/steps/lidar``: live and captured clouds, one posed node per sensor under it)."""
MAX_DISPLAY_POINTS = 100_000
"""Per sensor, by default. 100k float16 points are 0.6 MB a frame (+0.3 MB when coloured per point)."""
LIVE_PRECISION = "float16"
"""Live clouds travel as float16 (half the bytes; steps of 1 mm within 2 m, 1.6 cm at 16-32 m, 3 cm at 32-64 m),
finer than a live point's size; captured clouds and the LiDAR-to-LiDAR view are drawn in float32."""
LIVE_BUCKET_POINTS = 4096
"""Live clouds are padded to a multiple of this many points, so the page reuses their GPU buffers."""
RATES_PERIOD_S = 0.5
"""How often the live line (rates, points, device status) is refreshed (s)."""
LIVE_HZ = 12.0
"""Upper bound of each live thread's draw rate (Hz)."""
CAPTURE_WAIT_S = 10.0
"""How long *Capture clouds* waits for each live LiDAR's next scan (s): a guard, since scans come every 0.1 s."""
POINT_SIZE_M = 0.02
TARGET_COLOUR = (150, 150, 150)
RECOLOUR_DELAY_S = 0.5
SCENES_HELP = ("Tick the capture pairs to solve from (source ↔ target). Captures pair by their time stamps (taken "
               "together), never by number; uploaded clouds, which have none, pair in upload order. Pairs from "
               "different places are scenes: one transform is solved for all of them, and each scene's own solve "
               "cross-checks the others.")
LIVE_HELP = ("Tick the LiDARs to show, then **Start live**. **Capture clouds** keeps the next scan of each live "
             "LiDAR for the LiDAR-to-LiDAR solve (capture a few with the rig still).")


def wire_faults(meta: dict) -> str:
    """What a driver skipped on the wire so far (YDLiDAR checksums and stray bytes, Velodyne malformed datagrams)."""
    bad = int(meta.get("bad_checksums", 0)) + int(meta.get("malformed", 0))
    stray = int(meta.get("skipped_bytes", 0))
    faults = [f"{bad:,} bad packets" if bad else "", f"{stray:,} stray bytes" if stray else ""]
    return f" ({' and '.join(f for f in faults if f)} skipped)" if bad or stray else ""


def _live_by_default(session, sensor: str) -> bool:
    """3D LiDARs start ticked; a swept scanner does not (each of its frames is a sweep of several seconds)."""
    return session.rig.get(sensor).kind == "lidar3d" and not sweep_service.is_swept(session, sensor)


class LidarStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self.live: dict[str, LiveClouds] = {}
        self.show: dict[str, viser.GuiCheckboxHandle] = {}
        self._drawn: dict[str, int] = {}
        """Points drawn in each sensor's latest live frame."""
        self._pacer: FramePacer[tuple[np.ndarray, np.ndarray]] = FramePacer(ctx.server, self._draw_paced,
                                                                            "live clouds")
        self._live_nodes_lock = threading.Lock()
        """Held while a live cloud is drawn and while Stop removes them, so no frame redraws one after Stop."""
        self._errors: dict[str, str] = {}
        """The latest error each live sensor reported (a corrupt file, a lost device)."""
        self._source_node: viser.PointCloudHandle | None = None
        self._source_points: np.ndarray | None = None
        self._target_tree: cKDTree | None = None
        self._recolour_timer: threading.Timer | None = None
        self._l2l_nodes: list[viser.SceneNodeHandle] = []
        self.pair_boxes: dict[tuple[str, str], viser.GuiCheckboxHandle] = {}
        """One checkbox per (source capture id, target capture id) pair of the chosen LiDARs."""
        self._live_nodes: dict[str, viser.PointCloudHandle] = {}
        self._sensor_nodes: dict[str, viser.FrameHandle] = {}
        """``/steps/lidar/<sensor>``, posed where the rig has the sensor: its clouds hang under it."""
        self._lock = threading.Lock()
        self._nodes_lock = threading.Lock()
        self.max_correspondence_m = LidarLidarSettings().max_correspondence_m
        gui = ctx.server.gui
        with gui.add_folder("4 · LiDARs", expand_by_default=False):
            gui.add_markdown(LIVE_HELP)
            # Untitled, so viser draws it without a collapsible frame: a titled folder filled while this step is
            # closed can stay at height 0, its frame covering the boxes.
            self.sensor_folder = gui.add_folder(None)
            self.start_button = gui.add_button("Start live", color="green")
            self.stop_button = gui.add_button("Stop live", color="red", visible=False)
            self.toggle = LiveToggle(self.start_button, self.stop_button)
            self.colour_by = gui.add_dropdown("Colour by", options=cc.COLOUR_MODES, initial_value="sensor")
            self.accumulate = gui.add_number("Accumulate frames", initial_value=1, min=1, max=50, step=1,
                                             hint="merge the last N scans into a 3 cm voxel map")
            self.window = gui.add_multi_slider("Range window (m)", min=0.0, max=100.0, step=0.5,
                                               initial_value=(0.0, 100.0))
            self.point_size = gui.add_slider("Point size (m)", min=0.005, max=0.1, step=0.005,
                                             initial_value=POINT_SIZE_M)
            self.max_points = gui.add_slider("Points drawn per LiDAR", min=10_000, max=200_000, step=10_000,
                                             initial_value=MAX_DISPLAY_POINTS,
                                             hint="fewer keep a slow page fluid; a capture keeps the whole scan")
            self.live_text = gui.add_markdown("Not live.")
            self.place = gui.add_dropdown("Robot stands at", options=ROBOT_PLACE_NAMES, visible=False,
                                          hint="the simulator only: drive the robot to another place of the yard, "
                                               "so the clouds captured there are a scene of their own")
            self.capture_button = gui.add_button("Capture clouds")
            self.captures_text = gui.add_markdown("")
            self.imports = CloudImportPanel(ctx, on_imported=self._on_captures)
            self.accumulation = AccumulatePanel(ctx, on_captured=self._on_captures, is_live=lambda: self.toggle.live)
            with gui.add_folder("LiDAR to LiDAR"):
                self.source = gui.add_dropdown("Source LiDAR", options=[NONE])
                self.target = gui.add_dropdown("Target LiDAR", options=[NONE])
                gui.add_markdown("T_target_source: where the source sits in the target's frame (ROS yaw, pitch, "
                                 "roll). Nudge, then refine from here.")
                self.editor = TransformSliders(gui, self._on_slider)
                self.reset_button = gui.add_button("Reset to rig")
                self.scenes_folder = gui.add_folder("Scenes (capture pairs)")
                with self.scenes_folder:
                    gui.add_markdown(SCENES_HELP)
                    self.unpaired_text = gui.add_markdown("")
                self.global_button = gui.add_button("Global guess")
                self.refine_button = gui.add_button("Refine (GICP)", color="blue")
                self.jobs = JobPanel(ctx, [self.refine_button, self.global_button])
                self.history = ResultHistory(gui, self._show_result,
                                             hint="every solve of this pair; pick one to inspect or accept")
                self.card = ResultCard(ctx, empty_text="No LiDAR-to-LiDAR result yet.")
                self.scenes_text = gui.add_markdown("")
                self.histogram = gui.add_image(to_rgb(c2c_histogram(np.zeros(0), self.max_correspondence_m)),
                                               label="Cloud-to-cloud distances")

        self.start_button.on_click(ctx.after_switch(self.start_live))
        self.stop_button.on_click(lambda _: self.stop_live())
        self.accumulate.on_update(lambda _: self._set_accumulate())
        self.capture_button.on_click(lambda _: self._capture())
        self.place.on_update(lambda _: self._drive())
        self.source.on_update(lambda _: self._select_pair())
        self.target.on_update(lambda _: self._select_pair())
        self.reset_button.on_click(lambda _: self.editor.set(self._rig_T()))
        self.global_button.on_click(lambda _: self._global_guess())
        self.refine_button.on_click(lambda _: self._refine())
        ctx.on_session_closing(self._close)
        ctx.on_session_changed(self._on_session)
        ctx.on_rig_changed(lambda _: self._rig_changed())

    # -- session ------------------------------------------------------------------------------
    def _lidars(self) -> list[str]:
        session = self.ctx.session
        if session is None:
            return []
        return lidar_names(session.rig)

    def _rig_changed(self) -> None:
        """An accept or revert (in any step) moved frames, or a change elsewhere drove the simulated robot."""
        self._place_sensors()
        self._show_place()

    def _close(self) -> None:
        """Leave the open session: stop its live clouds and let go of its LiDAR-to-LiDAR clouds and sensor nodes."""
        self.stop_live()
        self._drop_pair_clouds()
        with self._nodes_lock:
            nodes, self._sensor_nodes = self._sensor_nodes, {}
        for node in nodes.values():
            node.remove()
        self.live_text.content = "Not live."
        self.histogram.image = to_rgb(c2c_histogram(np.zeros(0), self.max_correspondence_m))

    def _on_session(self, session) -> None:
        lidars = self._lidars()
        old, self.show = self.show, {}
        # Boxes of LiDARs still there are kept (their rows do not flicker); new ones go in before the gone ones go.
        with self.sensor_folder:
            for name in lidars:
                ticked = _live_by_default(session, name)
                if name in old:
                    self.show[name] = old.pop(name)
                    self.show[name].value = ticked
                else:
                    self.show[name] = self.ctx.server.gui.add_checkbox(name, initial_value=ticked)
        for box in old.values():
            box.remove()
        self.imports.set_lidars(lidars)
        self.accumulation.set_lidars([name for name in lidars if session.rig.get(name).kind == "lidar3d"])
        options = lidars or [NONE]
        self.source.options, self.target.options = options, options
        if self.target.value not in options:
            self.target.value = options[0]
        if self.source.value not in options or self.source.value == self.target.value:
            self.source.value = next((o for o in options if o != self.target.value), options[0])
        self._show_place()
        self._show_captures()
        self._select_pair()

    def _show_place(self) -> None:
        """*Robot stands at* shows where the simulated robot stands (hidden without a simulated sensor)."""
        place = None if self.ctx.session is None else simulated_place(self.ctx.session)
        self.place.visible = place is not None
        if place is not None:
            self.place.value = ROBOT_PLACE_NAMES[place]  # the same place: _drive does nothing

    def _drive(self) -> None:
        """*Robot stands at*: drive the simulated robot there; live LiDARs are reopened to see the yard from there."""
        session = self.ctx.session
        place = ROBOT_PLACE_NAMES.index(self.place.value)
        if session is None or simulated_place(session) in (None, place):
            return
        was_live = bool(self.live)
        self.stop_live()
        try:
            move_simulated_robot(session, place)
        except InputError as exc:
            self.ctx.notify("The robot did not move", exc.message, error=True)
            return
        self.ctx.notify("The robot moved", f"It stands at {self.place.value} in the yard. Capture clouds here: the "
                        "pairs taken at each place are a scene of their own, and scenes check each other.")
        if was_live:
            self.start_live()

    # -- live -----------------------------------------------------------------------------------
    def start_live(self) -> None:
        session = self.ctx.session
        chosen = [name for name, box in self.show.items() if box.value]
        if session is None or not chosen:
            self.ctx.notify("No LiDAR", "Tick at least one LiDAR to show live.", error=True)
            return
        self.ctx.show_step(STEP)
        self.stop_live()
        self._drawn, self._errors = {}, {}
        live = {name: LiveClouds(session, name, CloudCallbacks(frame=self._on_frame, status=self._on_status),
                                 accumulate=int(self.accumulate.value), max_hz=LIVE_HZ) for name in chosen}
        self.live = live
        self._pacer.start()
        for thread in live.values():
            thread.start()
        self.toggle.started(list(live.values()))
        threading.Thread(target=self._show_rates, args=(live,), name="live-rates", daemon=True).start()

    def _show_rates(self, live: dict[str, LiveClouds]) -> None:
        """Refresh the live line while these streams are the live ones, also while a device reconnects (no frames)."""
        while self.live is live and any(thread.running for thread in live.values()):
            self.live_text.content = "Live · " + self._rates(live)
            time.sleep(RATES_PERIOD_S)

    def stop_live(self) -> None:
        live, self.live = self.live, {}
        self.toggle.stopped()
        self._pacer.stop()
        with self._live_nodes_lock:
            for node in self._live_nodes.values():  # leave the view to the captured clouds
                node.remove()
            self._live_nodes = {}
        if live:
            self.live_text.content = "Not live. " + self._rates(live)
        for thread in live.values():  # last: the page has its answer while the devices close
            thread.stop()

    def _set_accumulate(self) -> None:
        for thread in self.live.values():
            thread.accumulate = int(self.accumulate.value)

    def _on_frame(self, sensor: str, points: np.ndarray, intensity: np.ndarray | None) -> None:
        session = self.ctx.session
        if session is None or sensor not in self.live:
            return
        lo, hi = self.window.value
        points, intensity = cc.range_window(points, intensity, lo, hi)
        points, intensity = cc.display_subset(points, intensity, int(self.max_points.value))
        self._drawn[sensor] = len(points)
        points, intensity = cc.padded_to_bucket(points, intensity, LIVE_BUCKET_POINTS)
        lidars = self._lidars()
        colours = cc.colour_points(self.colour_by.value, points, intensity, session.rig.T_root_frame(sensor),
                                   lidars.index(sensor) if sensor in lidars else 0)
        self._pacer.offer(sensor, (points, colours))

    def _draw_paced(self, sensor: str, frame: tuple[np.ndarray, np.ndarray]) -> None:
        """Draw a frame the pacer lets through, unless live view of ``sensor`` was stopped meanwhile."""
        with self._live_nodes_lock:
            if sensor in self.live:
                self._draw_live(sensor, *frame)

    def _draw_live(self, sensor: str, points: np.ndarray, colours: np.ndarray) -> None:
        """Update the sensor's live cloud in place (one message of new buffers), or create it.

        Updating the handle's props, rather than adding a new node per frame, spares the page a
        node's creation and removal each frame, and lets viser's message buffer replace a frame
        still waiting to be sent by the next one (same redundancy key). Only what changed is sent:
        viser's client rebuilds a cloud's material whenever its colours arrive, and reuses its GPU
        buffers in place while the length stays the same (hence :func:`cc.padded_to_bucket`).
        """
        node = self._live_nodes.get(sensor)
        size = float(self.point_size.value)
        if node is not None:
            try:
                with self.ctx.server.atomic():
                    if node.visible != (len(points) > 0):  # a range window that keeps nothing hides it
                        node.visible = len(points) > 0
                    if len(points):
                        node.points = points
                    if not np.array_equal(node.colors, colours):  # a new colour array rebuilds the material
                        node.colors = colours
                    if node.point_size != size:
                        node.point_size = size
                return
            except RuntimeError:  # removed with a redrawn rig: make a new one
                pass
        self._live_nodes[sensor] = self.ctx.server.scene.add_point_cloud(
            f"{self._sensor_node(sensor)}/live", points, colours, point_size=size, precision=LIVE_PRECISION)

    def _sensor_node(self, sensor: str) -> str:
        """The scene path of ``sensor``'s clouds, ``/steps/lidar/<sensor>``: a node posed where the rig has the
        sensor (made on first use)."""
        with self._nodes_lock:
            if sensor not in self._sensor_nodes:
                self._sensor_nodes[sensor] = self.ctx.server.scene.add_frame(
                    f"{self.ctx.scene.group(STEP)}/{sensor}", show_axes=False,
                    **viser_pose(self.ctx.session.rig.T_root_frame(sensor)))
            return self._sensor_nodes[sensor].name

    def _place_sensors(self) -> None:
        """Re-pose every sensor's node where the rig now has it (after an accept or a revert): their clouds move
        with them."""
        session = self.ctx.session
        with self._nodes_lock:
            for sensor, node in self._sensor_nodes.items():
                if sensor in session.rig.frames:
                    pose = viser_pose(session.rig.T_root_frame(sensor))
                    node.wxyz, node.position = pose["wxyz"], pose["position"]

    def _rates(self, live: dict[str, LiveClouds]) -> str:
        """Per sensor: draw rate, points drawn, and the device's own status when it is not plainly streaming."""
        parts = []
        for name, thread in live.items():
            drawn = self._drawn.get(name)
            frames = "no frame yet" if drawn is None else f"{drawn:,} pts drawn at {self._pacer.rate_hz(name):.1f} Hz"
            text = f"**{name}** {thread.rate_hz:.1f} Hz, {frames}"
            status = thread.device_status
            if status not in (None, "streaming", "closed"):
                text += f" ({status})"
            text += wire_faults(thread.latest.meta if thread.latest is not None else {})
            if name in self._errors:
                text += f" · {WARNING} {self._errors[name]}"
            parts.append(text)
        return " · ".join(parts)

    def _on_status(self, message: str, error: bool) -> None:
        if error:
            sensor, _, reason = message.partition(": ")
            self._errors[sensor] = reason  # stays on the live line; a notification also says it
            self.ctx.notify("LiDAR", message, error=True)
            self.live_text.content = f"{WARNING} {message}"

    def _capture(self) -> None:
        """*Capture clouds*: keep each live LiDAR's next scan, waited for off the UI thread."""
        live = dict(self.live)
        if self.ctx.session is None or not live:
            self.ctx.notify("Nothing captured", "Start live on the LiDARs first and wait for a scan.", error=True)
            return
        seen = {name: thread.latest for name, thread in live.items()}
        self.capture_button.disabled = True
        threading.Thread(target=self._keep_next_scans, args=(self.ctx.session, live, seen), name="lidar-capture",
                         daemon=True).start()

    def _keep_next_scans(self, session, live: dict[str, LiveClouds], seen: dict) -> None:
        """Store each LiDAR's first scan read after the click. Scans read before it may be seconds apart on a
        loaded machine, and captures pair by their time stamps (within the pairing window)."""
        kept, missing = [], []
        try:
            for name, thread in live.items():
                sample = thread.scan_after(seen[name], CAPTURE_WAIT_S)
                if sample is None:
                    missing.append(name)
                    continue
                try:
                    record = store_cloud(session, name, sample, device=thread.device_name)
                except InputError as exc:
                    self.ctx.notify("Cloud not kept", exc.message, error=True)
                    continue
                kept.append(f"{name} {record.id} ({len(sample.points):,} pts)")
        finally:
            self.capture_button.disabled = False
        if missing:
            self.ctx.notify("No new scan", f"{', '.join(missing)} sent no scan within {CAPTURE_WAIT_S:g} s of the "
                            "click: nothing kept from it. Is it still live?", error=True)
        if kept:
            self.ctx.notify("Clouds captured", ", ".join(kept))
            if session is self.ctx.session:
                self._on_captures()

    def _on_captures(self) -> None:
        """Clouds were captured or imported: recount them, list the pairs and redraw the pair's latest."""
        self._show_captures()
        self._list_pairs()
        self._load_pair_clouds()

    def _show_captures(self) -> None:
        session = self.ctx.session
        if session is None:
            return
        counts = [f"{name}: {len([c for c in session.captures(name) if c.n_points])}" for name in self._lidars()]
        self.captures_text.content = ("Captured clouds · " + " · ".join(counts) if counts else
                                      "No LiDAR in this session: add one in step 2, *Sensors*.")

    # -- LiDAR to LiDAR: pair, sliders and the source node -------------------------------------
    @property
    def pair(self) -> tuple[str, str] | None:
        source, target, lidars = self.source.value, self.target.value, self._lidars()
        if source == target or source not in lidars or target not in lidars:  # also while a session fills the lists
            return None
        return source, target

    def _rig_T(self) -> np.ndarray:
        pair = self.pair
        return np.eye(4) if pair is None else self.ctx.session.rig.T_a_b(pair[1], pair[0])

    def slider_T(self) -> np.ndarray:
        """``T_target_source`` on the sliders (m, degrees)."""
        return self.editor.T

    def _on_slider(self, T: np.ndarray) -> None:
        node = self._source_node
        if node is not None:  # the live nudge: only the pose travels
            pose = viser_pose(T)
            node.wxyz, node.position = pose["wxyz"], pose["position"]
            self._schedule_recolour()

    def _select_pair(self) -> None:
        pair = self.pair
        self.editor.frames = None if pair is None else (pair[1], pair[0])
        self.editor.text.content = "Pick two different LiDARs." if pair is None else ""
        self.editor.set(self._rig_T(), undoable=False)
        self._list_pairs()
        self._load_pair_clouds()
        self._show_history(self._accepted_id())

    def _list_pairs(self) -> None:
        """One ticked checkbox per capture pair of the chosen LiDARs, paired by time stamp (kept ticked or not when
        already listed), and the captures that found no partner, named."""
        pair, session = self.pair, self.ctx.session
        try:
            found = None if pair is None else lidar_service.pairing(session, *pair)
        except InputError:  # no clouds of one of them yet
            found = None
        ids = [] if found is None else found.pairs
        self.unpaired_text.content = "" if found is None or not found.unpaired else (
            f"Paired by time stamp (within {lidar_service.PAIR_WINDOW_S:g} s); not paired:\n\n"
            + "\n".join(f"- {WARNING} {why}" for why in found.unpaired))
        old = self.pair_boxes
        self.pair_boxes = {}
        with self.scenes_folder:
            for i, key in enumerate(ids):
                ticked = old[key].value if key in old else True
                self.pair_boxes[key] = self.ctx.server.gui.add_checkbox(f"pair {i}: {key[0]} ↔ {key[1]}",
                                                                        initial_value=ticked)
        for box in old.values():
            box.remove()

    def chosen_pairs(self) -> list[tuple[str, str]]:
        """The ticked (source capture id, target capture id) pairs."""
        return [key for key, box in self.pair_boxes.items() if box.value]

    def _pair_records(self) -> list[dict]:
        """The pair's stored results, newest first."""
        pair = self.pair
        return [] if pair is None else lidar_service.pair_results(self.ctx.session, *pair)

    def _accepted_id(self) -> str | None:
        """The pair's result the rig holds now (all of the pair's results fill one slot), or None."""
        records = self._pair_records()
        return self.ctx.session.accepted(rig_service.slot_of(records[0])) if records else None

    def _show_history(self, result_id: str | None, move_sliders: bool = False) -> None:
        """Fill the result dropdown and show ``result_id`` (or the newest)."""
        self._show_result(self.history.fill([r["id"] for r in self._pair_records()], result_id), move_sliders)

    def _drop_pair_clouds(self) -> None:
        """Remove the pair's clouds from the scene and forget them (a pending recolour finds nothing to do)."""
        if self._recolour_timer is not None:
            self._recolour_timer.cancel()
        with self._lock:
            self._source_node, self._source_points, self._target_tree = None, None, None
        for node in self._l2l_nodes:
            node.remove()
        self._l2l_nodes = []

    def _load_pair_clouds(self) -> None:
        """Draw the latest captured cloud of the target, and of the source posed by the sliders."""
        scene, session, pair = self.ctx.server.scene, self.ctx.session, self.pair
        self._drop_pair_clouds()
        if pair is None:
            return
        source, target = pair
        clouds = {}
        for name in pair:
            captures = [c for c in session.captures(name) if c.n_points]
            if captures:
                clouds[name] = cc.display_subset(session.capture_cloud(name, captures[-1].id)[0], None,
                                                 MAX_DISPLAY_POINTS)[0]
        if target not in clouds:
            return
        size = float(self.point_size.value)
        root = f"{self._sensor_node(target)}/l2l"
        self._l2l_nodes.append(scene.add_point_cloud(f"{root}/target", clouds[target].astype(np.float32),
                                                     TARGET_COLOUR, point_size=size, precision="float32"))
        if source in clouds:
            points = clouds[source].astype(np.float32)
            lidars = self._lidars()
            node = scene.add_point_cloud(f"{root}/source", points, cc.sensor_colour(lidars.index(source)),
                                         point_size=size, precision="float32", **viser_pose(self.slider_T()))
            self._l2l_nodes.append(node)
            with self._lock:
                self._source_node, self._source_points = node, points
                self._target_tree = cKDTree(clouds[target])
            self._schedule_recolour(0.0)

    def _schedule_recolour(self, delay_s: float = RECOLOUR_DELAY_S) -> None:
        if self._recolour_timer is not None:
            self._recolour_timer.cancel()
        self._recolour_timer = threading.Timer(delay_s, self._recolour)
        self._recolour_timer.daemon = True
        self._recolour_timer.start()

    def _recolour(self) -> None:
        """Colour the source cloud by its distance to the target at the slider pose; update the histogram."""
        with self._lock:
            node, points, tree = self._source_node, self._source_points, self._target_tree
        if node is None or points is None or tree is None:
            return
        max_m = self.max_correspondence_m
        fit = lidar_service.fit_at(points, tree, self.slider_T(), max_m)
        try:
            node.colors = distance_colours(fit["distances_m"], max_m)
        except RuntimeError:  # the cloud was replaced (new capture, accept) while this ran
            return
        self.histogram.image = to_rgb(c2c_histogram(fit["inliers_m"], max_m, "at the slider pose"))
        self.jobs.text.content = (f"At the slider pose: fitness {fit['fitness']:.3f}, c2c mean "
                                  f"{1000 * fit['c2c_mean_m']:.1f} mm (distances in mm: 0 dark … "
                                  f"{max_m * 1000:.0f} yellow, beyond red).")

    # -- jobs ---------------------------------------------------------------------------------------
    def _submit(self, title: str, work, on_done) -> None:
        if self.pair is None:
            self.ctx.notify("Pick two LiDARs", "Source and target must be two different LiDARs.", error=True)
            return
        self.ctx.show_step(STEP)
        self.jobs.run(title, work, on_done)

    def _global_guess(self) -> None:
        """RANSAC's starting pose, or the sliders' own when that fits better (by the same score)."""
        session, pair, chosen, T_current = self.ctx.session, self.pair, self.chosen_pairs() or None, self.slider_T()

        def work(progress):
            return lidar_service.global_guess(session, *pair, chosen, progress, T_current)

        def done(start) -> None:
            if start.kept == "global":
                self.editor.set(start.T_target_source)
            self.jobs.text.content = start.message()
            self.ctx.notify("Global guess", start.message())

        self._submit("Global guess", work, done)

    def _refine(self) -> None:
        session, pair, T_init, chosen = self.ctx.session, self.pair, self.slider_T(), self.chosen_pairs()
        if self.pair_boxes and not chosen:
            self.ctx.notify("No capture pair", "Tick at least one pair under Scenes.", error=True)
            return

        def work(progress):
            return lidar_service.solve_session(session, pair[0], pair[1], T_init=T_init, pairs=chosen or None,
                                               progress=progress)[0]

        self._submit("Refine (GICP)", work, lambda result_id: self._show_history(result_id, move_sliders=True))

    # -- result ----------------------------------------------------------------------------------------
    def _show_result(self, result_id: str | None, move_sliders: bool = True) -> None:
        session = self.ctx.session
        if session is None or result_id is None:
            self.card.show(None, None)
            self.scenes_text.content = ""
            return
        record = session.result(result_id)
        self.max_correspondence_m = record["settings"]["max_correspondence_m"]
        if move_sliders:
            self.editor.set(np.array(record["T_parent_child"]))  # also recolours the source cloud
        self.card.show(record, session.accepted(rig_service.slot_of(record)))
        self.scenes_text.content = scenes_markdown(record)


def scenes_markdown(record: dict) -> str:
    """Every scene's own solve (``T_target_source``: x y z in m, yaw pitch roll in degrees), how far it lies from
    the other scenes' joint solve, and the spread between scenes (markdown; a list, which wraps in the narrow
    panel), from the record's diagnostics."""
    diagnostics, inputs = record.get("diagnostics", {}), record.get("inputs", [])
    scenes = diagnostics.get("scenes", [])
    if not scenes:
        return ""
    rows = []
    for k, scene in enumerate(scenes):
        T = np.array(scene["T_target_source"])
        pairs = ", ".join(inputs[i].replace(":", " ↔ ") if i < len(inputs) else str(i) for i in scene["pairs"])
        deviation = scene.get("deviation")
        off = "-" if deviation is None else (f"{1000 * np.linalg.norm(deviation['trans_m']):.1f} mm / "
                                             f"{np.linalg.norm(deviation['rot_deg']):.3f}°")
        agrees = {True: " " + mark("agrees", "good"), False: " " + mark("disagrees", "bad"),
                  None: ""}[scene.get("agrees")]
        rows.append(f"- **scene {k + 1}** ({pairs}): {', '.join(f'{v:.3f}' for v in T[:3, 3])} m · "
                    f"{', '.join(f'{v:.2f}' for v in rotation_vector_deg(T))}° · fitness {scene['fitness']:.3f} · "
                    f"off the others {off}{agrees}")
    spread = diagnostics.get("scene_spread")
    spread_text = ("One scene: capture the rig in two more places for a cross-check." if spread is None else
                   f"Spread between scenes: **{1000 * spread['trans_m']:.1f} mm / {spread['rot_deg']:.3f}°**.")
    return "Scenes (x, y, z · rotation vector):\n\n" + "\n".join(rows) + f"\n\n{spread_text}"
