"""The rig in 3D: frames, camera frusta with their images, boards at their poses, and a solved camera rig.

Holds viser scene handles and updates them; all geometry comes from
:mod:`backend.core` (poses are ``T_root_frame`` from the rig). The root frame is
drawn z-up, like ROS's ``base_link``.
"""

from __future__ import annotations

import cv2
import numpy as np
import viser
import viser.transforms as vtf

from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.rig import Frame, Rig

DEFAULT_FOV_RAD = np.radians(60.0)
FRUSTUM_SCALE_M = 0.15
BOARD_TEXTURE_PX = 24
"""Pixels per square of the board texture drawn in 3D."""
R_PLANE_BOARD = np.diag([1.0, -1.0, -1.0])
"""Rotation from board axes (x right, y down the printed rows) to a viser image plane (x right, y up)."""
INITIAL_CAMERA_POSITION_M = (-0.9, -1.5, 1.4)
INITIAL_LOOK_AT_M = (0.6, 0.0, 0.3)
"""Where a new page's view starts (and "Reset View" returns): close enough to read the frame labels, with the
rig and the boards in front of its cameras in view."""
SENSOR_COLOURS = {
    "camera": (40, 110, 220),
    "lidar3d": (220, 120, 30),
    "lidar2d": (200, 60, 160),
    "depth": (40, 170, 90),
}
SOLVED_COLOUR = (235, 130, 20)
"""Frusta of a solved camera rig on show (:meth:`RigScene.show_solved_cameras`), beside the rig's own (blue)."""


def _pose(T: np.ndarray) -> dict[str, np.ndarray]:
    """viser ``wxyz`` / ``position`` keyword arguments of a 4x4 transform."""
    se3 = vtf.SE3.from_matrix(T)
    return {"wxyz": se3.rotation().wxyz, "position": se3.translation()}


def _fov_aspect(frame: Frame) -> tuple[float, float]:
    """Vertical field of view (rad) and aspect ratio of a camera's frustum (a nominal one before calibration)."""
    camera = frame.intrinsics
    if camera is None:
        return float(DEFAULT_FOV_RAD), 16 / 9
    return float(camera.fov_y_rad), camera.width / camera.height


def _board_drawing(board: BoardSpec) -> tuple[np.ndarray, float, float, np.ndarray]:
    """The board's texture (RGB), its size (m) and ``T_board_plane``, which places a viser image plane on it."""
    texture = cv2.cvtColor(board.render(BOARD_TEXTURE_PX), cv2.COLOR_GRAY2RGB)
    width_m, height_m = board.size_m
    T_board_plane = np.eye(4)
    T_board_plane[:3, :3] = R_PLANE_BOARD
    T_board_plane[:3, 3] = board.outer_origin_m + np.array([width_m / 2, height_m / 2, 0.0])
    return texture, width_m, height_m, T_board_plane


def _thumbnail(image: np.ndarray, width: int = 320) -> np.ndarray:
    scale = width / image.shape[1]
    small = cv2.resize(image, (width, int(round(image.shape[0] * scale))), interpolation=cv2.INTER_AREA)
    return cv2.cvtColor(small, cv2.COLOR_GRAY2RGB) if small.ndim == 2 else cv2.cvtColor(small, cv2.COLOR_BGR2RGB)


class RigScene:
    """Draws one session's rig and keeps the handles to update it."""

    def __init__(self, server: viser.ViserServer):
        self.server = server
        self._frames: dict[str, viser.FrameHandle] = {}
        self._frusta: dict[str, viser.CameraFrustumHandle] = {}
        self._boards: dict[str, list[viser.ImageHandle]] = {"live": [], "captured": []}
        self._solved: list[viser.SceneNodeHandle] = []
        server.scene.set_up_direction("+z")
        server.initial_camera.position = INITIAL_CAMERA_POSITION_M
        server.initial_camera.look_at = INITIAL_LOOK_AT_M
        server.scene.add_grid("/ground", width=4.0, height=4.0, cell_size=0.25, section_size=1.0)

    def show_rig(self, rig: Rig) -> None:
        """Draw ``rig`` afresh (a session was opened): axes for every frame, a frustum for each camera."""
        self.server.scene.reset()
        self.server.scene.add_grid("/ground", width=4.0, height=4.0, cell_size=0.25, section_size=1.0)
        self._frames.clear()
        self._frusta.clear()
        self._boards = {"live": [], "captured": []}
        self._solved = []
        self.update_rig(rig)

    def update_rig(self, rig: Rig) -> None:
        """Bring the drawing up to date with ``rig`` after an accept or a new sensor, keeping everything else.

        Each frame node is re-posed (what hangs under ``/rig/<frame>``, clouds included, moves with it) and
        each frustum takes its camera's current field of view; frames new to the rig are drawn.
        """
        for frame in rig.frames.values():
            pose = _pose(rig.T_root_frame(frame.name))
            handle = self._frames.get(frame.name)
            if handle is not None:
                handle.wxyz, handle.position = pose["wxyz"], pose["position"]
            else:
                self._frames[frame.name] = self._add_frame(frame, pose)
            if frame.name in self._frusta:
                self._frusta[frame.name].fov, self._frusta[frame.name].aspect = _fov_aspect(frame)

    def _add_frame(self, frame: Frame, pose: dict[str, np.ndarray]) -> viser.FrameHandle:
        node = f"/rig/{frame.name}"
        handle = self.server.scene.add_frame(node, axes_length=0.08, axes_radius=0.004, **pose)
        self.server.scene.add_label(f"{node}/label", frame.name, position=(0.0, 0.0, 0.03), font_screen_scale=0.8)
        if frame.kind == "camera":
            fov, aspect = _fov_aspect(frame)
            self._frusta[frame.name] = self.server.scene.add_camera_frustum(
                f"{node}/frustum", fov=fov, aspect=aspect, scale=FRUSTUM_SCALE_M, color=SENSOR_COLOURS["camera"],
                format="jpeg")
        elif frame.kind in SENSOR_COLOURS:
            self.server.scene.add_box(f"{node}/body", color=SENSOR_COLOURS[frame.kind], dimensions=(0.06, 0.06, 0.05))
        return handle

    def show_camera_image(self, camera: str, image: np.ndarray) -> None:
        """Paint the latest live or captured image into a camera's frustum."""
        handle = self._frusta.get(camera)
        if handle is not None:
            handle.image = _thumbnail(image)

    def clear_boards(self, live: bool = False) -> None:
        """Remove the boards drawn by :meth:`show_boards` (the live one, or the captured views)."""
        group = "live" if live else "captured"
        for handle in self._boards[group]:
            handle.remove()
        self._boards[group] = []

    def show_boards(self, rig: Rig, camera: str, board: BoardSpec, T_camera_boards: list[np.ndarray],
                    live: bool = False) -> None:
        """Draw the board at each pose in front of ``camera`` (captured views, or the live view)."""
        group = "live" if live else "captured"
        self.clear_boards(live)
        texture, width_m, height_m, T_board_plane = _board_drawing(board)
        T_root_camera = rig.T_root_frame(camera)
        self._boards[group] = [
            self.server.scene.add_image(f"/boards/{group}/{i}", texture, render_width=width_m, render_height=height_m,
                                        format="png", **_pose(T_root_camera @ T_camera_board @ T_board_plane))
            for i, T_camera_board in enumerate(T_camera_boards)
        ]

    def clear_solved_cameras(self) -> None:
        """Remove what :meth:`show_solved_cameras` drew."""
        for handle in reversed(self._solved):  # children before their parents
            try:
                handle.remove()
            except RuntimeError:  # gone with its parent or a redrawn rig
                pass
        self._solved = []

    def show_solved_cameras(self, rig: Rig, reference: str, T_ref_cams: dict[str, np.ndarray],
                            cameras: dict[str, CameraIntrinsics], board: BoardSpec,
                            T_ref_boards: dict[str, np.ndarray], tag: str = "solved") -> None:
        """Draw a solved camera rig beside the rig's own, placed from the reference camera's pose in the rig.

        Each camera's frustum (:data:`SOLVED_COLOUR`, its solved field of view) sits at
        ``T_root_ref @ T_ref_cam`` and is labelled ``name · tag``; the board is drawn at every
        ``T_ref_board`` (4x4, m, in the reference's optical frame) it was seen at.
        """
        self.clear_solved_cameras()
        scene = self.server.scene
        T_root_ref = rig.T_root_frame(reference)
        for name, T_ref_cam in T_ref_cams.items():
            node = f"/solved/cameras/{name}"
            camera = cameras[name]
            self._solved.append(scene.add_frame(node, axes_length=0.05, axes_radius=0.003,
                                                **_pose(T_root_ref @ T_ref_cam)))
            self._solved.append(scene.add_camera_frustum(
                f"{node}/frustum", fov=float(camera.fov_y_rad), aspect=camera.width / camera.height,
                scale=FRUSTUM_SCALE_M, color=SOLVED_COLOUR))
            self._solved.append(scene.add_label(f"{node}/label", f"{name} · {tag}", position=(0.0, -0.05, 0.0),
                                                font_screen_scale=0.7))
        texture, width_m, height_m, T_board_plane = _board_drawing(board)
        self._solved += [
            scene.add_image(f"/solved/boards/{name}", texture, render_width=width_m, render_height=height_m,
                            format="png", **_pose(T_root_ref @ T_ref_board @ T_board_plane))
            for name, T_ref_board in T_ref_boards.items()
        ]
