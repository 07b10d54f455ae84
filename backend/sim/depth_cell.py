"""The simulated depth-camera cell of issue 14: a 10 x 15 x 5 m cell seen by time-of-flight nodes.

The scene is built in the cell's ``world`` frame (origin on the floor in one corner, X and Y
along the walls, Z up, m; :mod:`backend.core.depth_cell`) from Open3D boxes in a
``RaycastingScene``: the floor (top face at z = 0, the whole cell), four walls up to the cell's
height, and the movable white tables (a top ``TABLE_TOP_THICKNESS_M`` thick whose upper face is at
the table's known height, on four legs). The cell's markings are flat on the floor, so they are
not geometry but a lookup of the hit point's x, y: tape lines (brighter than the floor) and
retroreflective crosses (their IR amplitude far above anything else).

A :class:`TablePlacement` puts a table's centre at ``centre_xy_m`` (m, world) with its length
(``TableSpec.size_m[0]``) along ``yaw_deg`` (deg, from world X towards world Y).

:meth:`CellScene.render` casts one ray per pixel of a node (:data:`~backend.core.depth.KINECT_V2`
by default) and returns the depth image (Z along the optical axis, m; 0 = no return) and the IR
amplitude. The noise model (:func:`range_sigma_m`) is that of a Kinect v2 class ToF camera:
range noise about 1.5 mm at 1 m and 6 mm at 5 m on a mid-grey surface, rising quickly past 9 m,
larger on darker surfaces (1 / sqrt of the return strength); pixels straddling a depth edge
become a few "flying pixels" between the foreground and the background, as in real ToF images.
Returns beyond the intrinsics' ``max_range_m`` (range along the ray) are dropped.

:func:`table_placements` stands three tables in a node's view the way the paper's guided
procedure wants them (behind each other, or beside each other), and :func:`truth_dict` is the
``truth.json`` kept beside a simulated session.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any, Literal

import numpy as np

from backend.core.depth import KINECT_V2, DepthIntrinsics, pose_from_row, pose_row
from backend.core.depth_cell import PAPER_NODE_POSES, CellLayout, TablePlacement, default_cell_layout
from backend.core.errors import InputError, shorten
from backend.core.transforms import check_transform, invert, transform_points

SURFACES: dict[str, int] = {"floor": 1, "tape": 2, "cross": 3, "wall": 4, "table": 5, "leg": 6}
"""Surface code of each pixel of :attr:`DepthFrame.labels`; 0 means no return."""

ALBEDO: dict[str, float] = {"floor": 0.35, "tape": 0.85, "cross": 0.9, "wall": 0.5, "table": 0.9, "leg": 0.3}
"""Diffuse IR reflectance of each surface (0..1)."""
_ALBEDO_BY_CODE = np.array([0.0, *(ALBEDO[name] for name in SURFACES)])

RETROREFLECTIVE_GAIN = 20.0
"""How much more a retroreflective cross returns than a white diffuse surface at the same range."""
TABLE_TOP_THICKNESS_M = 0.04
"""Thickness of a table top (m); its upper face is at the table's known height."""
TABLE_LEG_SIDE_M = 0.05
"""Side of a table's square legs (m)."""
TABLE_LEG_INSET_M = 0.08
"""Distance of each leg's centre from the top's edges (m)."""
WALL_THICKNESS_M = 0.2
"""Thickness of the walls and of the floor slab (m), outside the cell's inner faces."""
CROSS_BAR_WIDTH_M = 0.05
"""Width of each bar of a retroreflective cross (m); each arm reaches ``Cross.size_m`` from the centre along
world X and Y."""
MARKING_HEIGHT_TOLERANCE_M = 0.005
"""A hit on an upward-facing surface within this height (m) of a marking's height shows the marking."""
AMPLITUDE_REFERENCE_RANGE_M = 4.0
"""Range (m) at which a white surface at normal incidence returns amplitude ``ALBEDO["table"]``."""
AMPLITUDE_NOISE = (0.03, 0.002)
"""Amplitude noise: relative 1-sigma and absolute 1-sigma (amplitude units)."""
FLYING_PIXEL_JUMP_M = 0.1
"""A depth step (m) between 4-neighbours above this is an edge whose pixels may mix foreground and background."""
FLYING_PIXEL_PROBABILITY = 0.25
"""Chance that a pixel on such an edge returns a mixed depth (noisy renders only)."""
TRACE_CACHE_SIZE = 8
"""Node poses whose noise-free view a :class:`CellScene` keeps (one per node of a cell, with room to spare)."""

# Range noise on a mid-grey (albedo 0.5) surface: sigma = a + b r^2 within the rated range, fitted to the
# Kinect v2's 1.5 mm at 1 m and 6 mm at 5 m; beyond RATED_RANGE_M it grows e-fold every STEEP_M.
_SIGMA_A_M, _SIGMA_B_PER_M = 1.3125e-3, 0.1875e-3
_RATED_RANGE_M, _STEEP_M = 9.0, 0.75


def range_sigma_m(range_m: np.ndarray | float, albedo: np.ndarray | float) -> np.ndarray:
    """1-sigma range noise (m) of a return from ``range_m`` (m, along the ray) off a surface of ``albedo``
    (return strength, 0..1 for diffuse surfaces, more for retroreflectors): 1.5 mm at 1 m and 6 mm at 5 m for
    albedo 0.5, rising quickly beyond 9 m, scaled by ``1 / sqrt(albedo / 0.5)``."""
    r = np.asarray(range_m, dtype=float)
    sigma = (_SIGMA_A_M + _SIGMA_B_PER_M * r**2) * np.exp(np.clip(r - _RATED_RANGE_M, 0.0, None) / _STEEP_M)
    return sigma / np.sqrt(np.clip(np.asarray(albedo, dtype=float), 0.05, None) / 0.5)


@dataclass
class DepthFrame:
    """One rendered time-of-flight frame of a node."""

    depth_m: np.ndarray
    """(H, W) float32 depth along the optical axis (m, node frame), 0 = no return."""
    amplitude: np.ndarray
    """(H, W) float32 IR amplitude (arbitrary units: about 0..1 for diffuse surfaces, crosses far above)."""
    timestamp_s: float
    """Capture time (s)."""
    labels: np.ndarray | None = None
    """(H, W) int8 surface code (:data:`SURFACES`) of each pixel's true hit, 0 = no return (simulation truth)."""


@lru_cache(maxsize=4)
def _pixel_rays(intrinsics: DepthIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Rays of every pixel with Z = 1 (H*W, 3, node frame, row-major) and their lengths (H*W,)."""
    rays = intrinsics.rays().reshape(-1, 3)
    rays.flags.writeable = False
    lengths = np.linalg.norm(rays, axis=1)
    lengths.flags.writeable = False
    return rays, lengths


def table_corners_m(layout: CellLayout, placement: TablePlacement) -> np.ndarray:
    """(4, 3) corners (m, world) of the upper face of a placed table, counter-clockwise from above."""
    spec = layout.table(placement.table)
    half = np.array(spec.size_m) / 2
    local = np.array([[-half[0], -half[1]], [half[0], -half[1]], [half[0], half[1]], [-half[0], half[1]]])
    yaw = np.radians(placement.yaw_deg)
    R = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    xy = local @ R.T + np.asarray(placement.centre_xy_m, dtype=float)
    return np.column_stack([xy, np.full(4, spec.height_m)])


class CellScene:
    """The cell of ``layout`` with tables at ``placements`` in an Open3D ``RaycastingScene``, rendered by nodes."""

    def __init__(self, layout: CellLayout, placements: Sequence[TablePlacement] = ()):
        """Build the floor, walls and placed tables; a placement of an unknown table, of one table twice or
        outside the cell raises :class:`InputError`."""
        import open3d as o3d

        self.layout = layout
        self.placements = list(placements)
        self._o3d = o3d
        self._scene = o3d.t.geometry.RaycastingScene()
        self._surface_of_geometry: list[int] = []
        sx, sy, sz = layout.size_m
        t = WALL_THICKNESS_M
        self._add_box((-t, -t, -t), (sx + 2 * t, sy + 2 * t, t), "floor")
        self._add_box((-t, -t, 0.0), (t, sy + 2 * t, sz), "wall")
        self._add_box((sx, -t, 0.0), (t, sy + 2 * t, sz), "wall")
        self._add_box((0.0, -t, 0.0), (sx, t, sz), "wall")
        self._add_box((0.0, sy, 0.0), (sx, t, sz), "wall")
        seen: set[str] = set()
        for placement in self.placements:
            if placement.table in seen:
                raise InputError(f"table {placement.table!r} is placed twice; a table stands in one place",
                                 "placements")
            seen.add(placement.table)
            self._add_table(placement)
        self._surface = np.array(self._surface_of_geometry, dtype=np.int8)
        self._traces: dict[tuple[bytes, DepthIntrinsics], _Trace] = {}
        self._lock = threading.Lock()

    def _add_box(self, min_corner_m: tuple[float, float, float], size_m: tuple[float, float, float], surface: str,
                 yaw_rad: float = 0.0, pivot_m: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        """An axis-aligned box from ``min_corner_m`` (m, world) of ``size_m``, turned by ``yaw_rad`` about a
        vertical axis through ``pivot_m``."""
        o3d = self._o3d
        box = o3d.t.geometry.TriangleMesh.create_box(*size_m).translate(np.asarray(min_corner_m, dtype=np.float32))
        if yaw_rad:
            c, s = np.cos(yaw_rad), np.sin(yaw_rad)
            box = box.rotate(o3d.core.Tensor(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], dtype=np.float32)),
                             o3d.core.Tensor(np.asarray(pivot_m, dtype=np.float32)))
        self._scene.add_triangles(box)
        self._surface_of_geometry.append(SURFACES[surface])

    def _add_table(self, placement: TablePlacement) -> None:
        """A table's top (upper face at its height) and four legs; :class:`InputError` if it reaches outside."""
        spec = self.layout.table(placement.table)
        corners = table_corners_m(self.layout, placement)
        (sx, sy, _), xy = self.layout.size_m, corners[:, :2]
        if xy.min() < 0 or (xy[:, 0] > sx).any() or (xy[:, 1] > sy).any():
            raise InputError(f"table {placement.table!r} at {list(placement.centre_xy_m)} m (yaw "
                             f"{placement.yaw_deg:g} deg) reaches outside the {sx:g} x {sy:g} m cell", "placements")
        (length, width), h = spec.size_m, spec.height_m
        cx, cy = placement.centre_xy_m
        yaw, pivot = np.radians(placement.yaw_deg), (cx, cy, 0.0)
        self._add_box((cx - length / 2, cy - width / 2, h - TABLE_TOP_THICKNESS_M), (length, width,
                      TABLE_TOP_THICKNESS_M), "table", yaw, pivot)
        leg_h = h - TABLE_TOP_THICKNESS_M
        for ex in (-1, 1):
            for ey in (-1, 1):
                lx = cx + ex * (length / 2 - TABLE_LEG_INSET_M) - TABLE_LEG_SIDE_M / 2
                ly = cy + ey * (width / 2 - TABLE_LEG_INSET_M) - TABLE_LEG_SIDE_M / 2
                self._add_box((lx, ly, 0.0), (TABLE_LEG_SIDE_M, TABLE_LEG_SIDE_M, leg_h), "leg", yaw, pivot)

    def _markings(self, points_world: np.ndarray, normals_z: np.ndarray, surface: np.ndarray) -> None:
        """Relabel (in place) upward-facing hits at ``points_world`` (N, 3, m) that fall on a tape line (on the
        floor) or a cross (at its height) as ``tape`` or ``cross``."""
        up = normals_z > 0.9
        x, y, z = points_world.T
        on_floor = up & (np.abs(z) < MARKING_HEIGHT_TOLERANCE_M)
        for line in self.layout.lines:
            across, along = (x, y) if line.axis == "x" else (y, x)
            tape = (on_floor & (np.abs(across - line.value_m) <= line.width_m / 2)
                    & (along >= line.span_m[0]) & (along <= line.span_m[1]))
            surface[tape] = SURFACES["tape"]
        half_bar = CROSS_BAR_WIDTH_M / 2
        for cross in self.layout.crosses:
            cx, cy, cz = cross.position_m
            dx, dy = np.abs(x - cx), np.abs(y - cy)
            bars = ((dx <= cross.size_m) & (dy <= half_bar)) | ((dy <= cross.size_m) & (dx <= half_bar))
            surface[up & (np.abs(z - cz) < MARKING_HEIGHT_TOLERANCE_M) & bars] = SURFACES["cross"]

    def _trace(self, T_world_node: np.ndarray, intrinsics: DepthIntrinsics) -> _Trace:
        """The noise-free geometry of a node's view, cached per pose: a node at rest sees the same rays every
        frame, so its frames differ only by noise (casting is most of a render's time)."""
        key = (T_world_node.tobytes(), intrinsics)
        with self._lock:
            cached = self._traces.get(key)
        if cached is not None:
            return cached
        rays_node, lengths = _pixel_rays(intrinsics)
        # einsum, not @: numpy's BLAS threads cost 50x more than the product on a busy machine
        dirs_world = np.einsum("ij,kj->ik", rays_node, T_world_node[:3, :3])
        rays = np.empty((len(dirs_world), 6), dtype=np.float32)
        rays[:, :3] = T_world_node[:3, 3]
        rays[:, 3:] = dirs_world
        hits = self._scene.cast_rays(self._o3d.core.Tensor(rays))
        z = hits["t_hit"].numpy().astype(np.float64)  # rays have Z = 1, so the ray parameter is the depth
        range_m = z * lengths
        with np.errstate(invalid="ignore"):
            index = np.flatnonzero(np.isfinite(z) & (range_m >= intrinsics.min_range_m)
                                   & (range_m <= intrinsics.max_range_m))
        surface = self._surface[hits["geometry_ids"].numpy()[index]]
        normals = hits["primitive_normals"].numpy()[index].astype(np.float64)
        self._markings(T_world_node[:3, 3] + dirs_world[index] * z[index, None], normals[:, 2], surface)
        r = range_m[index]
        retro = surface == SURFACES["cross"]
        strength = _ALBEDO_BY_CODE[surface] * np.where(retro, RETROREFLECTIVE_GAIN, 1.0)
        cos_incidence = np.abs(np.einsum("ij,ij->i", normals, dirs_world[index])) / lengths[index]
        amplitude = strength * np.where(retro, 1.0, cos_incidence) / (r / AMPLITUDE_REFERENCE_RANGE_M) ** 2
        shape = (intrinsics.height, intrinsics.width)
        images = np.zeros((2, shape[0] * shape[1]), dtype=np.float32)
        images[0, index], images[1, index] = z[index], amplitude
        labels = np.zeros(shape[0] * shape[1], dtype=np.int8)
        labels[index] = surface
        trace = _Trace(index, r, lengths[index], strength, images[0].reshape(shape), images[1].reshape(shape),
                       labels.reshape(shape))
        with self._lock:
            if len(self._traces) >= TRACE_CACHE_SIZE:
                self._traces.pop(next(iter(self._traces)))
            self._traces[key] = trace
        return trace

    def render(self, T_world_node: np.ndarray, rng: np.random.Generator | None, intrinsics: DepthIntrinsics = KINECT_V2,
               timestamp_s: float = 0.0) -> DepthFrame:
        """The frame a node at ``T_world_node`` (4x4, m; node = optical frame) sees; ``rng`` None renders it
        noise-free (exact depth, no flying pixels). The arrays returned are the caller's to change."""
        T, _ = check_transform(T_world_node, "T_world_node")
        trace = self._trace(T, intrinsics)
        depth, amplitude = trace.depth_m.copy(), trace.amplitude.copy()
        if rng is not None:
            n = len(trace.index)
            r = trace.range_m + rng.normal(0.0, 1.0, n) * range_sigma_m(trace.range_m, trace.strength)
            depth.ravel()[trace.index] = r / trace.ray_length
            amplitude.ravel()[trace.index] = np.clip(
                amplitude.ravel()[trace.index] * (1 + rng.normal(0.0, AMPLITUDE_NOISE[0], n))
                + rng.normal(0.0, AMPLITUDE_NOISE[1], n), 0.0, None)
            _fly_pixels(depth, rng)
        return DepthFrame(depth, amplitude, float(timestamp_s), trace.labels.copy())


@dataclass(frozen=True)
class _Trace:
    """The noise-free result of casting a node's pixels (see :meth:`CellScene._trace`); arrays read-only by use."""

    index: np.ndarray
    """(N,) flat pixel index of the returns kept."""
    range_m: np.ndarray
    """(N,) true range along each ray (m)."""
    ray_length: np.ndarray
    """(N,) length of each pixel's Z = 1 ray (range / depth)."""
    strength: np.ndarray
    """(N,) return strength (albedo, times the gain on crosses) that sets the noise."""
    depth_m: np.ndarray
    """(H, W) float32 true depth (m), 0 = no return."""
    amplitude: np.ndarray
    """(H, W) float32 noise-free amplitude."""
    labels: np.ndarray
    """(H, W) int8 surface codes (:data:`SURFACES`)."""


def _fly_pixels(depth: np.ndarray, rng: np.random.Generator) -> None:
    """Mix (in place) a random :data:`FLYING_PIXEL_PROBABILITY` of the pixels on depth edges (a step above
    :data:`FLYING_PIXEL_JUMP_M` to a valid 4-neighbour) with that neighbour's depth, as a ToF pixel whose footprint
    straddles the edge does. Only the edge pixels move, so flying pixels stay few."""
    original = depth.copy()
    for axis in (0, 1):
        a = np.moveaxis(original, axis, 0)
        here, there = a[:-1], a[1:]
        edge = (here > 0) & (there > 0) & (np.abs(here - there) > FLYING_PIXEL_JUMP_M)
        rows, cols = np.nonzero(edge)
        pick = rng.random(len(rows)) < FLYING_PIXEL_PROBABILITY
        rows, cols = rows[pick], cols[pick]
        side = rng.random(len(rows)) < 0.5  # the pixel on either side of the edge may be the mixed one
        own_r, nb_r = np.where(side, rows, rows + 1), np.where(side, rows + 1, rows)
        mix = rng.random(len(rows))
        target = np.moveaxis(depth, axis, 0)
        target[own_r, cols] = a[own_r, cols] + mix * (a[nb_r, cols] - a[own_r, cols])


def node_pose(node: str) -> np.ndarray:
    """The true ``T_world_node`` (4x4, m) of a simulated node: its pose in :data:`PAPER_NODE_POSES`."""
    if node not in PAPER_NODE_POSES:
        raise InputError(f"no simulated depth node {node!r}; the cell has {sorted(PAPER_NODE_POSES)}", "node")
    return pose_from_row(PAPER_NODE_POSES[node])


PLACEMENT_MARGIN_PX = 8.0
"""A placed table's top corners stay at least this far (px) inside the image."""
PLACEMENT_WALL_MARGIN_M = 0.3
"""A placed table stays at least this far (m) from the walls."""
PLACEMENT_RANGE_MARGIN_M = 0.3
"""A placed table's top corners stay at least this far (m) within the node's range limits."""
BEHIND_FRACTIONS = (0.1, 0.5, 0.9)
"""Where along the reachable ground distances the three tables behind each other stand (near to far)."""
BESIDE_FRACTION = 0.75
"""How far towards the image's left and right edges (fraction of the room there) the side tables stand."""
_SEARCH_STEP_M = 0.02


def _whole_in_view(layout: CellLayout, table: str, centres_xy_m: np.ndarray, yaw_deg: float,
                   T_node_world: np.ndarray, intrinsics: DepthIntrinsics) -> np.ndarray:
    """(S,) whether ``table`` standing at each of ``centres_xy_m`` (S, 2; m, world) turned by ``yaw_deg`` has its
    whole top inside the image (:data:`PLACEMENT_MARGIN_PX`), within range and inside the cell."""
    corners = table_corners_m(layout, TablePlacement(table, (0.0, 0.0), yaw_deg))[None] + np.pad(
        np.asarray(centres_xy_m, dtype=float), ((0, 0), (0, 1)))[:, None]  # (S, 4, 3)
    (sx, sy, _), m = layout.size_m, PLACEMENT_WALL_MARGIN_M
    ok = ((corners[..., 0] >= m) & (corners[..., 0] <= sx - m) & (corners[..., 1] >= m)
          & (corners[..., 1] <= sy - m))
    points = transform_points(T_node_world, corners.reshape(-1, 3))
    uv, z = intrinsics.project(points)
    ranges = np.linalg.norm(points, axis=1)
    with np.errstate(invalid="ignore"):
        seen = ((z > 0) & (uv[:, 0] >= PLACEMENT_MARGIN_PX) & (uv[:, 0] <= intrinsics.width - 1 - PLACEMENT_MARGIN_PX)
                & (uv[:, 1] >= PLACEMENT_MARGIN_PX) & (uv[:, 1] <= intrinsics.height - 1 - PLACEMENT_MARGIN_PX)
                & (ranges >= intrinsics.min_range_m + PLACEMENT_RANGE_MARGIN_M)
                & (ranges <= intrinsics.max_range_m - PLACEMENT_RANGE_MARGIN_M))
    return (ok & seen.reshape(ok.shape)).all(axis=1)


def table_placements(node: str, arrangement: Literal["behind", "beside"], layout: CellLayout | None = None,
                     intrinsics: DepthIntrinsics = KINECT_V2) -> list[TablePlacement]:
    """Three of ``layout``'s tables standing fully in ``node``'s view (deterministic).

    ``behind``: one behind the other along the node's viewing direction (ground distances at
    :data:`BEHIND_FRACTIONS` of those where a table is whole in the image), so they appear at the bottom,
    middle and top of the image (as far up as the range allows), long sides across the view; ``beside``: left,
    centre and right at the middle of those distances, long sides along the view. Each top is fully inside
    the image (:data:`PLACEMENT_MARGIN_PX`), within range and inside the cell; the tables do not touch. Ordered
    near to far (``behind``) or left to right in the image (``beside``).
    """
    layout = default_cell_layout() if layout is None else layout
    if len(layout.tables) < 3:
        raise InputError(f"the layout has {len(layout.tables)} tables; three are needed to place", "layout")
    if arrangement not in ("behind", "beside"):
        raise InputError(f"arrangement must be 'behind' or 'beside', got {arrangement!r}", "arrangement")
    T_world_node = node_pose(node)
    T_node_world = invert(T_world_node)
    forward = T_world_node[:2, 2] / np.linalg.norm(T_world_node[:2, 2])
    right = np.array([-forward[1], forward[0]])
    if right @ T_world_node[:2, 0] < 0:  # the image's right (node X) on the floor
        right = -right
    heading_deg = float(np.degrees(np.arctan2(forward[1], forward[0])))
    tables = layout.tables[:3]
    gap = max(t.size_m[1] for t in tables) + 0.3  # centres this far apart (m) keep the tables from touching

    def reachable(start: np.ndarray, direction: np.ndarray, yaw_deg: float) -> np.ndarray:
        """Distances (m) from ``start`` along ``direction`` (world xy) of the first unbroken run of positions at
        which every one of the tables would stand whole in view."""
        steps = np.arange(0.0, intrinsics.max_range_m, _SEARCH_STEP_M)
        centres = start + steps[:, None] * direction
        ok = np.logical_and.reduce([_whole_in_view(layout, t.name, centres, yaw_deg, T_node_world, intrinsics)
                                    for t in tables])
        if not ok.any():
            return steps[:0]
        first = int(np.argmax(ok))
        last = first + (int(np.argmin(ok[first:])) if not ok[first:].all() else len(ok) - first)
        return steps[first:last]

    origin = T_world_node[:2, 3]
    if arrangement == "behind":
        yaw = (heading_deg + 270.0) % 360.0 - 180.0  # heading + 90 deg, in (-180, 180]
        run = reachable(origin, forward, yaw)
        if len(run) == 0 or run[-1] - run[0] < 2 * gap:
            raise InputError(f"node {node!r} has no room for three tables behind each other in its view", "node")
        distances = run[0] + np.array(BEHIND_FRACTIONS) * (run[-1] - run[0])
        return [TablePlacement(t.name, tuple(float(v) for v in origin + d * forward), yaw)
                for t, d in zip(tables, distances, strict=True)]
    yaw = heading_deg
    run = reachable(origin, forward, yaw)
    if len(run) == 0:
        raise InputError(f"node {node!r} has no room for a table in its view", "node")
    centre = origin + (run[0] + run[-1]) / 2 * forward
    sides = []
    for sign in (-1.0, 1.0):
        room = reachable(centre, sign * right, yaw)
        sides.append(sign * BESIDE_FRACTION * (room[-1] if len(room) else 0.0))
    if min(abs(s) for s in sides) < gap:
        raise InputError(f"node {node!r} has no room for three tables beside each other in its view", "node")
    return [TablePlacement(t.name, tuple(float(v) for v in centre + s * right), yaw)
            for t, s in zip(tables, (sides[0], 0.0, sides[1]), strict=True)]


def placement_to_dict(placement: TablePlacement) -> dict[str, Any]:
    """A placement as JSON: ``{"table", "centre_xy_m": [x, y] (m, world), "yaw_deg"}``."""
    return {"table": placement.table, "centre_xy_m": [float(v) for v in placement.centre_xy_m],
            "yaw_deg": float(placement.yaw_deg)}


def placement_from_dict(data: Any) -> TablePlacement:
    """Read :func:`placement_to_dict` back (or pass a :class:`TablePlacement` through); a malformed one raises
    :class:`InputError` naming what was expected."""
    if isinstance(data, TablePlacement):
        return data
    try:
        centre = tuple(float(v) for v in data["centre_xy_m"])
        placement = TablePlacement(str(data["table"]), centre, float(data.get("yaw_deg", 0.0)))
    except (KeyError, TypeError, ValueError, AttributeError):
        raise InputError(f"a table placement is {{'table': name, 'centre_xy_m': [x, y] (m), 'yaw_deg': deg}}, "
                         f"got {shorten(data)}", "placements") from None
    if len(centre) != 2 or not np.isfinite([*centre, placement.yaw_deg]).all():
        raise InputError(f"a table placement's centre_xy_m is two finite numbers (m) and yaw_deg finite, got "
                         f"{shorten(data)}", "placements")
    return placement


def truth_dict(layout: CellLayout, node_poses: dict[str, np.ndarray],
               placements: dict[str, list[TablePlacement]]) -> dict[str, Any]:
    """The simulated cell's ground truth as ``truth.json`` keeps it (JSON-friendly; m, deg).

    ``{"nodes": {name: {"T_world_node": 4x4, "pose_row": [X, Y, Z, RotZ, RotY, RotX]}}, "frames": {name:
    T_world_node} (what the rig step compares each frame with), "layout": ...,
    "table_placements": {key: [TablePlacement dicts]}, "table_tops": {key: [{"table", "height_m", "corners_m"}]},
    "crosses": {name: [x, y, z]}}``; ``placements`` is keyed by capture (or by whatever the caller groups them
    by), ``node_poses`` holds ``T_world_node`` (4x4, m).
    """
    nodes = {}
    for name, T in node_poses.items():
        T_world_node, _ = check_transform(T, f"node_poses[{name!r}]")
        nodes[name] = {"T_world_node": T_world_node.tolist(), "pose_row": list(pose_row(T_world_node))}
    return {
        "nodes": nodes,
        "frames": {name: node["T_world_node"] for name, node in nodes.items()},
        "layout": layout.to_dict(),
        "table_placements": {key: [placement_to_dict(p) for p in group] for key, group in placements.items()},
        "table_tops": {key: [{"table": p.table, "height_m": layout.table(p.table).height_m,
                              "corners_m": table_corners_m(layout, p).tolist()} for p in group]
                       for key, group in placements.items()},
        "crosses": {cross.name: [float(v) for v in cross.position_m] for cross in layout.crosses},
    }


def node_visibility(scene: CellScene, T_world_node: np.ndarray,
                    intrinsics: DepthIntrinsics = KINECT_V2) -> dict[str, Any]:
    """What a node at ``T_world_node`` sees of the cell's markings in a noise-free render.

    ``{"floor_pixels": n, "lines": {name: visible length (m) along the line}, "crosses": {name: pixels on it}}``;
    only lines and crosses with at least one pixel are listed. The visible length is the extent of the line's
    tape pixels along it.
    """
    frame = scene.render(T_world_node, None, intrinsics)
    points, index = intrinsics.unproject(frame.depth_m)
    points_world = transform_points(check_transform(T_world_node, "T_world_node")[0], points)
    labels = frame.labels.ravel()[index]
    x, y, _ = points_world.T
    tape, cross = labels == SURFACES["tape"], labels == SURFACES["cross"]
    lines: dict[str, float] = {}
    for line in scene.layout.lines:
        across, along = (x, y) if line.axis == "x" else (y, x)
        mine = tape & (np.abs(across - line.value_m) <= line.width_m / 2 + 1e-6)
        if mine.any():
            lines[line.name] = float(along[mine].max() - along[mine].min())
    crosses: dict[str, int] = {}
    for c in scene.layout.crosses:
        mine = cross & (np.abs(x - c.position_m[0]) <= c.size_m + 1e-6) & (np.abs(y - c.position_m[1]) <= c.size_m
                                                                              + 1e-6)
        if mine.any():
            crosses[c.name] = int(mine.sum())
    on_floor = np.isin(labels, [SURFACES["floor"], SURFACES["tape"], SURFACES["cross"]])
    return {"floor_pixels": int(on_floor.sum()), "lines": lines, "crosses": crosses}
