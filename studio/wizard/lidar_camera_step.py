"""Step 6: LiDAR to camera - the LiDAR's points drawn onto the camera's image, nudged by hand.

The six sliders *are* ``T_camera_lidar`` (m, ROS yaw/pitch/roll in degrees; it maps LiDAR
points into the camera's optical frame), with nudges, undo and redo
(:class:`~studio.transform_sliders.TransformSliders`). Every change redraws the overlay: the latest
captured cloud of the LiDAR projected with the camera's intrinsics onto its latest captured
image (:mod:`backend.core.projection`: points behind the camera, outside the image or
outside the range window dropped, hidden points filtered), coloured by depth, intensity or
height. Redraws run on one worker thread that always draws the newest slider pose, so
dragging never queues work. The overlay also fills the camera's frustum in 3D, and the
cloud can be painted with the image's colours (the reverse view).
"""

from __future__ import annotations

import threading

import cv2
import numpy as np

from backend.core.colour_maps import depth_colours, height_colours, intensity_colours
from backend.core.errors import InputError
from backend.core.projection import colourise_cloud, draw_points, project_cloud
from backend.services import lidar_camera as lidar_camera_service
from backend.services import lidar_lidar as lidar_service
from studio.context import StudioContext
from studio.transform_sliders import TransformSliders

NONE = "(none)"
COLOUR_MODES = ("depth", "intensity", "height")
HEIGHT_RANGE_M = (-0.5, 3.0)
OVERLAY_WIDTH_PX = 960
"""Width of the overlay shown in the panel (the projection itself runs at the image's full size)."""
OCCLUSION_PX = 6
COLOURISED_POINT_SIZE_M = 0.02
HELP = ("Pick a camera with intrinsics and a LiDAR with a captured cloud: the cloud's latest capture is drawn on "
        "the camera's latest image. Move the sliders until edges, poles and the board line up, within the range "
        "window that holds your target.")


class LidarCameraStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self._inputs: list[str] = []
        """The captures on screen, as ``sensor:capture`` (what an accepted transform was judged on)."""
        self._image: np.ndarray | None = None
        self._cloud: tuple[np.ndarray, np.ndarray | None] | None = None
        self._wake = threading.Event()
        self._colourised = None
        self.redraws = 0
        """Overlays drawn so far (tests and the status line read it)."""
        gui = ctx.server.gui
        with gui.add_folder("6 · LiDAR to camera", expand_by_default=False):
            gui.add_markdown(HELP)
            self.camera = gui.add_dropdown("Onto camera", options=[NONE])
            self.lidar = gui.add_dropdown("From LiDAR", options=[NONE])
            self.data_text = gui.add_markdown("")
            self.editor = TransformSliders(gui, lambda _: self._wake.set(), max_translation_m=3.0)
            self.reset_button = gui.add_button("Reset to rig")
            self.accept_button = gui.add_button("Accept as the mounting", color="green",
                                                hint="keep this transform as a result and make it the LiDAR's mounting")
            self.colour_by = gui.add_dropdown("Colour by", options=list(COLOUR_MODES))
            self.window = gui.add_multi_slider("Range window (m)", min=0.0, max=100.0, step=0.5,
                                               initial_value=(0.5, 40.0))
            self.occlusion = gui.add_checkbox("Hide occluded points", initial_value=True)
            self.radius = gui.add_slider("Point radius (px)", min=0, max=4, step=1, initial_value=1)
            self.paint_cloud = gui.add_checkbox("Paint the cloud with the image (3D)", initial_value=False)
            self.overlay = gui.add_image(np.full((270, 480, 3), 235, np.uint8), label="Overlay", format="jpeg")
            self.status = gui.add_markdown("")
        self.camera.on_update(lambda _: self._select())
        self.lidar.on_update(lambda _: self._select())
        for handle in (self.colour_by, self.window, self.occlusion, self.radius, self.paint_cloud):
            handle.on_update(lambda _: self._wake.set())
        self.reset_button.on_click(lambda _: self.editor.set(self._rig_T()))
        self.accept_button.on_click(lambda _: self._accept())
        threading.Thread(target=self._redraw_loop, name="overlay", daemon=True).start()
        ctx.on_session_changed(self._on_session)

    # -- session, sensors and data ------------------------------------------------------------
    def _on_session(self, session) -> None:
        self._colourised = None  # the scene was redrawn
        cameras = [f.name for f in session.rig.sensors("camera")]
        lidars = lidar_service.lidar_names(session.rig)
        self.camera.options, self.lidar.options = cameras or [NONE], lidars or [NONE]
        self.camera.value, self.lidar.value = self.camera.options[0], self.lidar.options[0]
        self._select()

    @property
    def pair(self) -> tuple[str, str] | None:
        if self.ctx.session is None or NONE in (self.camera.value, self.lidar.value):
            return None
        return self.camera.value, self.lidar.value

    def _rig_T(self) -> np.ndarray:
        pair = self.pair
        return np.eye(4) if pair is None else self.ctx.session.rig.T_a_b(*pair)

    def _select(self) -> None:
        """Load the pair's latest image and cloud, put the rig's transform on the sliders, redraw."""
        session, pair = self.ctx.session, self.pair
        self._image = self._cloud = None
        self._inputs = []
        if pair is not None:
            camera, lidar = pair
            images = [c for c in session.captures(camera) if not c.n_points]
            clouds = [c for c in session.captures(lidar) if c.n_points]
            if images:
                self._image = session.capture_image(camera, images[-1].id)
                self._inputs.append(f"{camera}:{images[-1].id}")
            if clouds:
                self._cloud = session.capture_cloud(lidar, clouds[-1].id)
                self._inputs.append(f"{lidar}:{clouds[-1].id}")
            intrinsics = session.rig.get(camera).intrinsics
            self.data_text.content = (
                f"Image: {images[-1].id if images else '**none captured yet** (step 3)'} · "
                f"cloud: {clouds[-1].id + f' ({clouds[-1].n_points:,} pts)' if clouds else '**none yet** (step 4)'}"
                + ("" if intrinsics else " · ⚠️ this camera has no intrinsics yet: calibrate it in step 3"))
        self.editor.frames = pair
        self.editor.set(self._rig_T(), undoable=False)

    def _accept(self) -> None:
        session, pair = self.ctx.session, self.pair
        if pair is None:
            self.ctx.notify("Nothing to accept", "Pick a camera and a LiDAR first.", error=True)
            return
        camera, lidar = pair
        try:
            result_id = lidar_camera_service.store_manual(session, camera, lidar, self.editor.T, inputs=self._inputs)
            lidar_camera_service.accept(session, lidar, result_id)
        except InputError as exc:
            self.ctx.notify("Cannot accept", exc.message, error=True)
            return
        self.ctx.scene.update_rig(session.rig)
        self.ctx.notify("Accepted", f"{result_id}: {lidar} is now mounted so that T_{camera}_{lidar} is the sliders' "
                        "transform (set by hand, no uncertainty).")

    # -- drawing (worker thread) ------------------------------------------------------------------
    def _redraw_loop(self) -> None:
        while True:
            self._wake.wait()
            self._wake.clear()  # changes from now on wake the next pass; this one draws the newest state
            try:
                self._redraw()
            except Exception as exc:  # noqa: BLE001 - the worker must survive one bad input and say why
                self.status.content = f"⚠️ overlay failed: {exc}"

    def _redraw(self) -> None:
        session, pair, image, cloud = self.ctx.session, self.pair, self._image, self._cloud
        intrinsics = None if pair is None else session.rig.get(pair[0]).intrinsics
        if pair is None or image is None or cloud is None or intrinsics is None:
            self.status.content = "Nothing to draw yet."
            return
        camera, lidar = pair
        points, intensity = cloud
        if image.shape[1] != intrinsics.width or image.shape[0] != intrinsics.height:
            self.status.content = (f"⚠️ the image is {image.shape[1]}×{image.shape[0]} px but {camera}'s intrinsics "
                                   f"are for {intrinsics.width}×{intrinsics.height}")
            return
        T_camera_lidar = self.editor.T
        projection = project_cloud(points, T_camera_lidar, intrinsics, range_m=tuple(self.window.value),
                                   occlusion_px=OCCLUSION_PX if self.occlusion.value else 0)
        colours = self._colours(projection, points, intensity, lidar)
        drawn = draw_points(image, projection.uv, colours, radius_px=int(self.radius.value))
        scale = OVERLAY_WIDTH_PX / drawn.shape[1]
        small = cv2.resize(drawn, (OVERLAY_WIDTH_PX, round(drawn.shape[0] * scale)), interpolation=cv2.INTER_AREA)
        self.overlay.image = cv2.cvtColor(small, cv2.COLOR_BGR2RGB)
        self.ctx.scene.show_camera_image(camera, drawn)
        self._paint_cloud(points, T_camera_lidar, intrinsics, image, lidar)
        self.redraws += 1
        self.status.content = f"{len(projection.index):,} of {len(points):,} points drawn"

    def _colours(self, projection, points: np.ndarray, intensity: np.ndarray | None, lidar: str) -> np.ndarray:
        mode = self.colour_by.value
        if mode == "intensity" and intensity is not None and np.isfinite(intensity).any():
            return intensity_colours(intensity[projection.index])
        if mode == "height":
            return height_colours(points[projection.index], self.ctx.session.rig.T_root_frame(lidar),
                                  *HEIGHT_RANGE_M)
        return depth_colours(projection.depth_m, *self.window.value)

    def _paint_cloud(self, points: np.ndarray, T_camera_lidar: np.ndarray, intrinsics, image: np.ndarray,
                     lidar: str) -> None:
        """The reverse view: the cloud in 3D in the image's colours (points the camera does not see left out)."""
        if self._colourised is not None:
            self._colourised.remove()
            self._colourised = None
        if not self.paint_cloud.value:
            return
        colours, seen = colourise_cloud(points, T_camera_lidar, intrinsics, image, occlusion_px=OCCLUSION_PX)
        self._colourised = self.ctx.server.scene.add_point_cloud(
            f"/rig/{lidar}/colourised", points[seen].astype(np.float32), colours[seen],
            point_size=COLOURISED_POINT_SIZE_M, precision="float32")
