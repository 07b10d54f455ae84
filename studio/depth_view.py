"""The depth-network step's 3D layers: the cell's known geometry, a node's capture at the pose being tuned,
the features found in it, the merged voxel map of every node and the verification picks.

Everything is drawn in the cell's ``world`` frame (m, Z up) under the step's layer group
(``/steps/depth_network/...``, :meth:`studio.scene.RigScene.group`), so it shows and hides with the step:

- ``cell/``: the floor outline and the walls' top edges, every floor line (tape) with its label
  (``X = 2 m``), every retroreflective cross as an X with its name;
- ``node/``: the node being tuned at the pose on the editor (a frustum) and its latest capture mapped
  into ``world`` with that pose, coloured by height, so a tilted floor or a table top below its known
  height shows at once as a change of colour;
- ``map``: the merged voxel map (cube centres, one per occupied voxel), coloured per node or by count;
- ``picks/``: the two verification points and the segment between them.

Only drawing lives here; every number comes from the services (:mod:`backend.calib.depth.service`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from backend.core.colour_maps import colormap, height_colours
from backend.core.depth import KINECT_V2, DepthIntrinsics
from backend.core.depth_cell import CellLayout
from backend.core.transforms import transform_points
from studio.cloud_colours import display_subset, sensor_colour
from studio.scene import INITIAL_CAMERA_POSITION_M, INITIAL_LOOK_AT_M, RigScene, viser_pose

STEP = "depth_network"
"""The step's layer group (:meth:`studio.scene.RigScene.group`)."""
TAPE_COLOUR = (240, 200, 30)
CROSS_COLOUR = (220, 40, 40)
OUTLINE_COLOUR = (120, 120, 120)
CAPTURE_COLOUR = (60, 140, 220)
HEIGHT_RANGE_M = (-0.1, 1.0)
"""World heights (m) at the ends of the capture's colour map: the floor blue, a 0.74 m table top orange-red."""
PICK_COLOUR = (230, 40, 200)
LINE_HEIGHT_M = 0.004
"""Floor lines and crosses are drawn this far above the floor (m), so the floor's points do not hide them."""
CAPTURE_POINT_SIZE_M = 0.025
MAX_CAPTURE_POINTS = 40_000
"""Most points of one capture drawn (an even stride through it; a Kinect v2 frame has up to 217k)."""
FRUSTUM_SCALE_M = 0.6
OVERVIEW_FROM = (-0.25, -0.3, 2.2)
"""Where the cell's overview is seen from, in fractions of the cell's size (x, y, z): beyond its origin corner and
above it, so that the whole floor and every node on the ceiling are in view."""
OVERVIEW_TARGET = (0.65, 0.5, 0.0)
"""What the overview looks at (fractions of the cell's size): right of the floor's centre, as the wizard panel
covers the view's right side."""
COUNT_COLOUR_MAX = 30
"""Voxel counts at or above this are drawn at the colour map's hot end (TURBO, from 1)."""


def frustum_fov_aspect(intrinsics: DepthIntrinsics = KINECT_V2) -> tuple[float, float]:
    """Vertical field of view (rad) and aspect ratio of a depth camera's frustum."""
    return float(2.0 * np.arctan2(intrinsics.height / 2.0, intrinsics.fy)), intrinsics.width / intrinsics.height


def cell_outline(layout: CellLayout) -> np.ndarray:
    """(12, 2, 3) segments (m, world) of the cell's box: the floor's four edges, the walls' top edges and the
    four vertical corners."""
    sx, sy, sz = layout.size_m
    corners = np.array([[0.0, 0.0], [sx, 0.0], [sx, sy], [0.0, sy]])
    floor = np.column_stack([corners, np.zeros(4)])
    top = np.column_stack([corners, np.full(4, sz)])
    ring = np.roll(np.arange(4), -1)
    return np.concatenate([np.stack([floor, floor[ring]], axis=1), np.stack([top, top[ring]], axis=1),
                           np.stack([floor, top], axis=1)])


def floor_line_segments(layout: CellLayout) -> np.ndarray:
    """(L, 2, 3) one segment per floor line (m, world), just above the floor."""
    segments = np.zeros((len(layout.lines), 2, 3))
    for i, line in enumerate(layout.lines):
        along = 1 if line.axis == "x" else 0  # an X = value line runs along Y
        segments[i, :, 1 - along] = line.value_m
        segments[i, :, along] = line.span_m
    segments[:, :, 2] = LINE_HEIGHT_M
    return segments


def cross_segments(layout: CellLayout) -> np.ndarray:
    """(2C, 2, 3) each cross as two diagonal arms of its size (m, world), just above the floor."""
    if not layout.crosses:
        return np.zeros((0, 2, 3))
    centres = np.array([c.position_m for c in layout.crosses], dtype=float)
    half = np.array([c.size_m / 2.0 for c in layout.crosses])[:, None]
    arms = []
    for direction in (np.array([1.0, 1.0, 0.0]), np.array([1.0, -1.0, 0.0])):
        offset = half * direction / np.sqrt(2.0)
        arms.append(np.stack([centres - offset, centres + offset], axis=1))
    segments = np.concatenate(arms)
    segments[:, :, 2] += LINE_HEIGHT_M
    return segments


def count_colours(counts: np.ndarray) -> np.ndarray:
    """(M, 3) uint8 colours of voxel point counts: TURBO from 1 to :data:`COUNT_COLOUR_MAX` on a log scale."""
    return colormap(np.log(np.maximum(np.asarray(counts, float), 1.0)), 0.0, np.log(COUNT_COLOUR_MAX))


class DepthView:
    """Holds the step's scene handles and redraws them; every method replaces what it drew last."""

    def __init__(self, scene: RigScene):
        self.scene = scene
        self._handles: dict[str, list] = {}

    @property
    def root(self) -> str:
        return self.scene.group(STEP)

    def _layer(self, key: str) -> list:
        """Remove what layer ``key`` drew and return its (empty) list of handles to draw it afresh into (removed
        first: a node added under a drawn one's name replaces it, and removing the old handle then would remove
        the new node)."""
        self.clear(key)
        return self._handles.setdefault(key, [])

    def clear(self, key: str | None = None) -> None:
        """Remove what one layer (``cell``, ``node``, ``map``, ``picks``) drew, or all of them."""
        for name in [key] if key else list(self._handles):
            for handle in reversed(self._handles.pop(name, [])):
                handle.remove()

    def forget(self) -> None:
        """The session is left and the scene is about to be redrawn afresh: drop the handles without removing them."""
        self._handles = {}

    def look_at(self, layout: CellLayout | None) -> None:
        """Put every page's view (and a new page's) on the cell's overview, or with ``None`` back on the rig's
        close-up (:data:`studio.scene.INITIAL_CAMERA_POSITION_M`)."""
        if layout is None:
            position, target = np.array(INITIAL_CAMERA_POSITION_M), np.array(INITIAL_LOOK_AT_M)
        else:
            size = np.array(layout.size_m)
            position, target = size * OVERVIEW_FROM, size * OVERVIEW_TARGET
        server = self.scene.server
        server.initial_camera.position, server.initial_camera.look_at = position, target
        for client in server.get_clients().values():
            client.camera.position, client.camera.look_at = position, target

    def show_cell(self, layout: CellLayout) -> None:
        """The cell's box, its floor lines with labels and its crosses with names (``cell/``)."""
        server, root, handles = self.scene.server, f"{self.root}/cell", self._layer("cell")
        handles.append(server.scene.add_line_segments(f"{root}/outline", cell_outline(layout), OUTLINE_COLOUR,
                                                      thickness=0.02))
        if layout.lines:
            handles.append(server.scene.add_line_segments(f"{root}/lines", floor_line_segments(layout), TAPE_COLOUR,
                                                          thickness=0.05))
        for line, segment in zip(layout.lines, floor_line_segments(layout), strict=True):
            handles.append(server.scene.add_label(f"{root}/line_labels/{line.name}", line.label,
                                                  position=segment.mean(axis=0) + (0.0, 0.0, 0.05),
                                                  font_screen_scale=0.7))
        if layout.crosses:
            handles.append(server.scene.add_line_segments(f"{root}/crosses", cross_segments(layout), CROSS_COLOUR,
                                                          thickness=0.04))
        for cross in layout.crosses:
            handles.append(server.scene.add_label(f"{root}/cross_labels/{cross.name}", cross.name,
                                                  position=np.add(cross.position_m, (0.0, 0.0, 0.05)),
                                                  font_screen_scale=0.6))

    def show_node(self, node: str, T_world_node: np.ndarray, points_node: np.ndarray | None,
                  intrinsics: DepthIntrinsics = KINECT_V2) -> None:
        """``node``'s frustum at ``T_world_node`` (the editor's pose) and its capture (N, 3, node frame, m) mapped
        into ``world`` with it, coloured by height (``node/``); at most :data:`MAX_CAPTURE_POINTS` points."""
        server, root, handles = self.scene.server, f"{self.root}/node", self._layer("node")
        fov, aspect = frustum_fov_aspect(intrinsics)
        pose = viser_pose(T_world_node)
        handles += [server.scene.add_camera_frustum(f"{root}/frustum", fov=fov, aspect=aspect, scale=FRUSTUM_SCALE_M,
                                                    color=CAPTURE_COLOUR, thickness=0.02, **pose),
                    server.scene.add_label(f"{root}/label", f"{node} (editor)", font_screen_scale=0.8,
                                           position=pose["position"] + (0.0, 0.0, 0.15))]
        if points_node is not None and len(points_node):
            shown, _ = display_subset(np.asarray(points_node, float), None, MAX_CAPTURE_POINTS)
            handles.append(server.scene.add_point_cloud(
                f"{root}/capture", transform_points(T_world_node, shown).astype(np.float32),
                height_colours(shown, T_world_node, *HEIGHT_RANGE_M), point_size=CAPTURE_POINT_SIZE_M,
                precision="float32"))

    def show_voxel_map(self, centres_m: np.ndarray, counts: np.ndarray, node_index: np.ndarray, voxel_m: float,
                       colour_by: str) -> None:
        """The merged voxel map (``map``): one cube centre per voxel (M, 3, m, world), coloured per node
        (``colour_by="node"``, the index into the network's node list) or by its point count (``"count"``)."""
        handles = self._layer("map")
        if not len(centres_m):
            return
        colours = (count_colours(counts) if colour_by == "count"
                   else np.array([sensor_colour(int(i)) for i in range(int(np.max(node_index)) + 1)],
                                 np.uint8)[np.asarray(node_index, int)])
        handles.append(self.scene.server.scene.add_point_cloud(
            f"{self.root}/map", np.asarray(centres_m, np.float32), colours, point_size=float(voxel_m),
            point_shape="square", precision="float32"))

    def show_picks(self, points_m: Sequence[np.ndarray]) -> None:
        """The verification points picked so far (m, world) and, once there are two, the segment between them."""
        server, root, handles = self.scene.server, f"{self.root}/picks", self._layer("picks")
        handles += [server.scene.add_icosphere(f"{root}/{i}", radius=0.06, color=PICK_COLOUR,
                                               position=np.asarray(p, float)) for i, p in enumerate(points_m)]
        if len(points_m) == 2:
            handles.append(server.scene.add_line_segments(f"{root}/segment", np.array([points_m], float),
                                                          PICK_COLOUR, thickness=0.03))
