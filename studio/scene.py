"""The rig in 3D: frames, camera frusta with their images, boards at their poses, a solved camera rig, and the
fused rig tree (sigma ellipsoids and edges coloured by their residual).

Holds viser scene handles and updates them; all geometry comes from
:mod:`backend.core` (poses are ``T_root_frame`` from the rig). The root frame is
drawn z-up, like ROS's ``base_link``.

Every wizard step draws its own layers under one group node, ``/steps/<step>/...`` (the rig step's
tree under ``/rig_tree/...``): :meth:`RigScene.group` gives a step's path and
:meth:`RigScene.set_group_visible` shows or hides everything under it at once.
"""

from __future__ import annotations

import cv2
import numpy as np
import viser
import viser.transforms as vtf

from backend.calib.rig.service import EdgeResidual, RigTree
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.rig import Frame, Rig
from backend.core.targets import CameraTarget
from backend.core.test_field import TestField
from backend.core.transforms import transform_points

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
TEST_FIELD_COLOUR = (250, 200, 40)
"""Colour of a test field's surveyed marker centres."""
TEST_FIELD_POINT_M = 0.05
"""Drawn size of a test field's marker centre (m)."""
"""Frusta of a solved camera rig on show (:meth:`RigScene.show_solved_cameras`), beside the rig's own (blue)."""
RIG_TREE = "/rig_tree"
"""Scene path of the fused rig tree, the rig step's layer group."""
ELLIPSOID_COLOUR = (130, 80, 220)
ELLIPSOID_MAX_M = 0.3
"""Longest semi-axis drawn (m): a larger one (a frame known only from its mounting guess, scaled up) is cut to this
and drawn as a wireframe."""
EDGE_COLOURS = {"green": (40, 170, 70), "amber": (240, 170, 20), "red": (220, 40, 40), "grey": (150, 150, 150)}
"""Edges of the rig tree by residual: normalised chi2 <= 1 green, <= 9 amber, beyond or flagged red, no residual
(the edge reaches no fused frame) grey."""


def viser_pose(T: np.ndarray) -> dict[str, np.ndarray]:
    """viser ``wxyz`` / ``position`` keyword arguments of a 4x4 transform (m)."""
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


def step_group(step: str) -> str:
    """Scene path of a wizard step's layer group: ``/steps/<step>`` (the rig step's is :data:`RIG_TREE`)."""
    return RIG_TREE if step == "rig" else f"/steps/{step}"


def edge_colour(residual: EdgeResidual) -> str:
    """``green`` (normalised chi2 <= 1), ``amber`` (<= 9), ``red`` (beyond, or flagged) or ``grey`` (no residual)."""
    if residual.flagged:
        return "red"
    if not np.isfinite(residual.chi2):
        return "grey"
    return "green" if residual.chi2 <= 1.0 else "amber" if residual.chi2 <= 9.0 else "red"


def ellipsoid_pose(covariance_m2: np.ndarray, scale: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Principal axes of a 3x3 position covariance (m^2) as a rotation (wxyz, right-handed) and the 1-sigma
    semi-axes times ``scale`` (m, uncut); None when the covariance is undetermined (NaN)."""
    covariance_m2 = np.asarray(covariance_m2, dtype=float)
    if not np.isfinite(covariance_m2).all():
        return None
    variances, axes = np.linalg.eigh(0.5 * (covariance_m2 + covariance_m2.T))
    if np.linalg.det(axes) < 0:
        axes[:, 0] = -axes[:, 0]
    semi_axes_m = scale * np.sqrt(np.clip(variances, 0.0, None))
    return vtf.SO3.from_matrix(axes).wxyz, np.maximum(semi_axes_m, 1e-4)


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
        self._boards: dict[str, list[viser.ImageHandle]] = {}
        """Board images drawn by :meth:`show_boards`, by ``<step>/<live|captured>``."""
        self._solved: list[viser.SceneNodeHandle] = []
        self._groups: dict[str, viser.FrameHandle] = {}
        self._hidden: set[str] = set()
        """Steps whose layer group is hidden; kept across a redrawn rig."""
        self._tree: list[viser.SceneNodeHandle] = []
        server.scene.set_up_direction("+z")
        server.scene.configure_default_lights(cast_shadow=False)
        server.initial_camera.position = INITIAL_CAMERA_POSITION_M
        server.initial_camera.look_at = INITIAL_LOOK_AT_M
        server.scene.add_grid("/ground", width=4.0, height=4.0, cell_size=0.25, section_size=1.0)

    def show_rig(self, rig: Rig) -> None:
        """Draw ``rig`` afresh (a session was opened): axes for every frame, a frustum for each camera."""
        self.server.scene.reset()
        self.server.scene.add_grid("/ground", width=4.0, height=4.0, cell_size=0.25, section_size=1.0)
        self._frames.clear()
        self._frusta.clear()
        self._boards = {}
        self._solved = []
        self._tree = []
        steps, self._groups = list(self._groups), {}
        for step in steps:  # every group node afresh, before any step draws into it
            self.group(step)
        self.update_rig(rig)

    def group(self, step: str) -> str:
        """Scene path of ``step``'s layer group (:func:`step_group`), its node created when it is not there yet;
        draw the step's layers under it."""
        path = step_group(step)
        if step not in self._groups:
            self._groups[step] = self.server.scene.add_frame(path, show_axes=False, visible=step not in self._hidden)
        return path

    def set_group_visible(self, step: str, visible: bool) -> None:
        """Show or hide everything under ``step``'s layer group (a redrawn rig keeps the choice)."""
        self.group(step)
        self._groups[step].visible = visible
        if visible:
            self._hidden.discard(step)
        else:
            self._hidden.add(step)

    def update_rig(self, rig: Rig) -> None:
        """Bring the drawing up to date with ``rig`` after an accept or a new sensor, keeping everything else.

        Each frame node is re-posed (what hangs under ``/rig/<frame>``, clouds included, moves with it) and
        each frustum takes its camera's current field of view; frames new to the rig are drawn.
        """
        for frame in rig.frames.values():
            pose = viser_pose(rig.T_root_frame(frame.name))
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

    def clear_boards(self, step: str, live: bool = False) -> None:
        """Remove the boards ``step`` drew with :meth:`show_boards` (the live one, or the captured views)."""
        for handle in self._boards.pop(f"{step}/{'live' if live else 'captured'}", []):
            handle.remove()

    def show_boards(self, step: str, rig: Rig, camera: str, board: CameraTarget, T_camera_boards: list[np.ndarray],
                    live: bool = False) -> None:
        """Draw the board at each pose in front of ``camera`` (captured views, or the live view) in ``step``'s
        layer group, under ``/steps/<step>/boards/<live|captured>/`` (a test field as its marker centres)."""
        kind = "live" if live else "captured"
        self.clear_boards(step, live)
        root = f"{self.group(step)}/boards/{kind}"
        T_root_camera = rig.T_root_frame(camera)
        if isinstance(board, TestField):  # the surveyed marker centres, where each view puts the wall
            self._boards[f"{step}/{kind}"] = [
                self.server.scene.add_point_cloud(f"{root}/{i}", transform_points(T_root_camera @ T_camera_wall,
                                                                                  board.centres_m),
                                                  colors=TEST_FIELD_COLOUR, point_size=TEST_FIELD_POINT_M)
                for i, T_camera_wall in enumerate(T_camera_boards)]
            return
        texture, width_m, height_m, T_board_plane = _board_drawing(board)
        self._boards[f"{step}/{kind}"] = [
            self.server.scene.add_image(f"{root}/{i}", texture, render_width=width_m, render_height=height_m,
                                        format="png", **viser_pose(T_root_camera @ T_camera_board @ T_board_plane))
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

    def show_solved_cameras(self, step: str, rig: Rig, reference: str, T_ref_cams: dict[str, np.ndarray],
                            cameras: dict[str, CameraIntrinsics], board: BoardSpec,
                            T_ref_boards: dict[str, np.ndarray], tag: str = "solved") -> None:
        """Draw a solved camera rig beside the rig's own, placed from the reference camera's pose in the rig, in
        ``step``'s layer group (``/steps/<step>/solved/...``).

        Each camera's frustum (:data:`SOLVED_COLOUR`, its solved field of view) sits at
        ``T_root_ref @ T_ref_cam`` and is labelled ``name · tag``; the board is drawn at every
        ``T_ref_board`` (4x4, m, in the reference's optical frame) it was seen at.
        """
        self.clear_solved_cameras()
        scene = self.server.scene
        root = f"{self.group(step)}/solved"
        T_root_ref = rig.T_root_frame(reference)
        for name, T_ref_cam in T_ref_cams.items():
            node = f"{root}/cameras/{name}"
            camera = cameras[name]
            self._solved.append(scene.add_frame(node, axes_length=0.05, axes_radius=0.003,
                                                **viser_pose(T_root_ref @ T_ref_cam)))
            self._solved.append(scene.add_camera_frustum(
                f"{node}/frustum", fov=float(camera.fov_y_rad), aspect=camera.width / camera.height,
                scale=FRUSTUM_SCALE_M, color=SOLVED_COLOUR))
            self._solved.append(scene.add_label(f"{node}/label", f"{name} · {tag}", position=(0.0, -0.05, 0.0),
                                                font_screen_scale=0.7))
        texture, width_m, height_m, T_board_plane = _board_drawing(board)
        self._solved += [
            scene.add_image(f"{root}/boards/{name}", texture, render_width=width_m, render_height=height_m,
                            format="png", **viser_pose(T_root_ref @ T_ref_board @ T_board_plane))
            for name, T_ref_board in T_ref_boards.items()
        ]

    def show_rig_tree(self, tree: RigTree, ellipsoid_scale: float) -> None:
        """Draw the fused rig tree under :data:`RIG_TREE`, replacing the last drawing.

        Every frame gets its origin's 1-sigma ellipsoid (``covariance_root_translation``, semi-axes times
        ``ellipsoid_scale`` so that millimetres show, cut at :data:`ELLIPSOID_MAX_M`) at
        ``/rig_tree/ellipsoids/<frame>``; every edge
        ``i`` of ``tree.edges`` whose two frames are fused gets a line from the parent's origin to the
        child's at ``/rig_tree/edges/<i>``, coloured by :func:`edge_colour` (priors thinner).
        """
        for handle in self._tree:
            handle.remove()
        scene, root = self.server.scene, self.group("rig")
        origins = {tree.root: np.zeros(3)} | {name: f.T_root_frame[:3, 3] for name, f in tree.frames.items()}
        self._tree = []
        for name, frame in tree.frames.items():
            pose = ellipsoid_pose(frame.covariance_root_translation, ellipsoid_scale)
            if pose is not None:
                wxyz, semi_axes_m = pose
                self._tree.append(scene.add_icosphere(
                    f"{root}/ellipsoids/{name}", radius=1.0, color=ELLIPSOID_COLOUR, subdivisions=2,
                    scale=tuple(float(a) for a in np.minimum(semi_axes_m, ELLIPSOID_MAX_M)),
                    wireframe=bool(semi_axes_m.max() > ELLIPSOID_MAX_M), opacity=0.35, cast_shadow=False,
                    receive_shadow=False, wxyz=wxyz, position=origins[name]))
        for i, residual in enumerate(tree.edges):
            edge = residual.edge
            if edge.parent not in origins or edge.child not in origins:
                continue
            self._tree.append(scene.add_line_segments(
                f"{root}/edges/{i}", np.array([[origins[edge.parent], origins[edge.child]]]),
                EDGE_COLOURS[edge_colour(residual)], thickness=0.003 if edge.kind == "prior" else 0.008))
