"""Features of a depth-cell capture: the floor, the tables, the tape lines and the crosses one node sees.

A depth node calibrates against the cell's known geometry (:mod:`backend.core.depth_cell`): the
floor is the plane ``z = 0``, each table top a horizontal plane at its known height, each tape
line the set of floor points with ``x`` (or ``y``) equal to its value, and a surveyed cross a known
point. :func:`extract_features` finds them in one capture (points in the node frame, m) given a
pose guess as good as a tape measure gives (about 10 cm and 5 deg); the solvers
(:mod:`backend.calib.depth.node`, :mod:`backend.calib.depth.guided`) fit the pose to them.

How a capture is read, in order:

1. **floor**: Open3D RANSAC (``segment_plane``) on the points the guess puts near ``z = 0``, refined
   by a least-squares plane on its inliers; the guess is then *levelled* on it (tilt and height
   from the floor), so that the rest is found at ``z`` accurate to millimetres whatever the guess's tilt;
2. **tables**: points within ``table_band_m`` of a declared height above the floor whose normals
   are vertical, eroded by ``erode_px`` pixels in the image (mixed pixels at the edges go), cut into
   connected parts (image components, or DBSCAN without a pixel index), one plane each;
3. **tape** and **crosses** from the IR amplitude of the floor points, relative to the floor's own
   amplitude fall-off with range and incidence (fitted per capture, so no camera's units matter):
   a little brighter is tape, far brighter a retroreflective cross;
4. tape points go to the nearest known line within the gate the guess allows, crosses to the
   nearest known cross.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from scipy import ndimage

from backend.core.depth import KINECT_V2, DepthIntrinsics
from backend.core.depth_cell import CellLayout, TableSpec
from backend.core.errors import InputError
from backend.core.transforms import check_transform, make_T, transform_points

FeatureKind = Literal["floor", "table", "line", "point"]
Arrangement = Literal["behind", "beside", "free"]


@dataclass
class DepthObservation:
    """One capture of one node: its valid pixels as points and what the user says stands in view."""

    capture_id: str
    points: np.ndarray
    """(N, 3) points in the node frame (m)."""
    amplitude: np.ndarray
    """(N,) IR amplitude of each point (the camera's units)."""
    pixel_index: np.ndarray | None
    """(N,) flat row-major pixel index into the ``intrinsics`` image, or None (no image structure)."""
    tables: list[TableSpec]
    """The tables the user says stand in view (known heights)."""
    arrangement: Arrangement = "free"
    """How the tables stand: ``behind`` each other (near to far), ``beside`` each other (left to right)."""
    intrinsics: DepthIntrinsics = KINECT_V2
    """The image ``pixel_index`` indexes (for erosion and left-to-right order)."""


@dataclass
class Feature:
    """One piece of known geometry seen in one capture."""

    kind: FeatureKind
    name: str
    """``floor``, ``table1@c0003``, ``x2`` (a line's name), ``cross gantry_a1``."""
    points: np.ndarray
    """(M, 3) the feature's points in the node frame (m)."""
    known: float | tuple[float, float, float]
    """floor: 0.0; table: top height (m); line: its value (m) along ``axis``; point: its position (m, world)."""
    axis: str | None = None
    """A line's axis, ``x`` or ``y``."""
    capture_id: str = ""


@dataclass
class DepthNodeSettings:
    """How features are found and a node's pose is solved (m, deg)."""

    guess_trans_m: float = 0.10
    """How far the pose guess's position may be off (tape measure): gates the association of lines and crosses."""
    guess_rot_deg: float = 5.0
    """How far the guess's rotations may be off: the floor search band and the gates grow with range by it."""
    refine_trans_m: float = 0.02
    """The gate's position term once the pose has been solved once (re-extraction)."""
    refine_rot_deg: float = 0.3
    floor_band_m: float = 0.15
    """Floor candidates: within this (plus the guess's rotation error times range) of ``z = 0`` under the guess."""
    floor_ransac_m: float = 0.04
    """Open3D RANSAC inlier distance of the floor plane (m)."""
    ransac_points: int = 20000
    """Points the floor RANSAC samples from (a random subset: the plane is the same, the search faster)."""
    max_floor_tilt_deg: float = 15.0
    """A floor plane further than this from horizontal under the guess is refused (a wall, a wrong guess)."""
    max_floor_points: int = 4000
    """Floor points kept per capture as the floor feature (a random subset: the floor is huge)."""
    table_band_m: float = 0.15
    """Table candidates: within this of a declared height above the floor."""
    table_normal_deg: float = 15.0
    """Largest angle between a table candidate's normal and the floor's."""
    min_table_points: int = 80
    erode_px: int = 2
    """Pixels eroded off each table's image region (mixed pixels at its edges)."""
    tape_ratio: float = 1.4
    """A floor pixel this much brighter than the floor's fitted amplitude is tape."""
    cross_ratio: float = 6.0
    """... and this much brighter a retroreflective cross."""
    min_line_points: int = 30
    min_cross_points: int = 4
    sigma_1m_m: float = 0.0015
    """Depth noise 1-sigma at 1 m range (m); with ``sigma_5m_m`` it sets the quadratic range noise model."""
    sigma_5m_m: float = 0.006
    line_sigma_m: float = 0.015
    """1-sigma of a tape pixel about its line's centre (a 5 cm tape sampled uniformly: 5 cm / sqrt(12))."""
    point_sigma_m: float = 0.004
    """1-sigma of a seen cross's centre (m): about 3 mm RMS on the simulated cell's whole crosses, 4 to 9 m away."""
    robust_scale: float = 3.0
    """soft-L1 loss scale, in sigmas of each residual."""
    rounds: int = 3
    """Extract-and-solve rounds (the association of lines may change once the pose moves)."""
    translation_tolerance_m: float = 0.005
    rotation_tolerance_deg: float = 0.05
    cross_tolerance_m: float = 0.02
    """A seen cross's centre within this of its known position passes the cross-check."""
    seed: int = 0
    """Seed of the random subsets (RANSAC sample, floor points): results repeat."""

    def refined(self) -> DepthNodeSettings:
        """These settings once the pose has been solved: tight association gates."""
        return replace(self, guess_trans_m=self.refine_trans_m, guess_rot_deg=self.refine_rot_deg)

    def sigma_m(self, range_m: np.ndarray) -> np.ndarray:
        """Depth noise 1-sigma (m) at ``range_m`` (m): ``a + b r^2`` through the 1 m and 5 m values."""
        b = (self.sigma_5m_m - self.sigma_1m_m) / 24.0
        return self.sigma_1m_m - b + b * np.asarray(range_m, dtype=float) ** 2


@dataclass
class _Floor:
    """The floor plane in the node frame: ``normal . p + offset_m = 0`` (normal towards the camera) and its inliers."""

    normal: np.ndarray
    offset_m: float
    inliers: np.ndarray = field(repr=False)
    """(N,) bool over the capture's points."""


def check_observation(obs: DepthObservation) -> tuple[np.ndarray, np.ndarray]:
    """The observation's finite points (N, 3) and amplitudes (N,) mask; InputError naming the field when the
    shapes disagree."""
    points = np.asarray(obs.points, dtype=float)
    amplitude = np.asarray(obs.amplitude, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"capture {obs.capture_id}: points must be (N, 3) in metres, got shape {points.shape}",
                         "points")
    if amplitude.shape != (len(points),):
        raise InputError(f"capture {obs.capture_id}: amplitude must be (N,) = ({len(points)},), got "
                         f"{amplitude.shape}", "amplitude")
    if obs.pixel_index is not None and np.shape(obs.pixel_index) != (len(points),):
        raise InputError(f"capture {obs.capture_id}: pixel_index must be (N,) = ({len(points)},), got "
                         f"{np.shape(obs.pixel_index)}", "pixel_index")
    return points, np.isfinite(points).all(axis=1) & np.isfinite(amplitude)


def _fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane ``n . p + d = 0`` (unit ``n``) through (M, 3) points: the scatter matrix's eigenvector
    of the smallest eigenvalue (a 3x3 problem, where an SVD of the M x 3 points costs far more)."""
    centre = points.mean(axis=0)
    spread = points - centre
    normal = np.linalg.eigh(spread.T @ spread)[1][:, 0]
    return normal, float(-normal @ centre)


def ranges_m(points: np.ndarray) -> np.ndarray:
    """(N,) distance (m) of each point (N, 3, node frame) from the sensor."""
    return np.sqrt(np.einsum("ij,ij->i", points, points))


def _find_floor(points: np.ndarray, ranges: np.ndarray, T_guess: np.ndarray, settings: DepthNodeSettings,
                rng: np.random.Generator) -> _Floor | None:
    """The floor plane (node frame) near ``z = 0`` under ``T_guess``, or None when there is none near enough;
    ``ranges`` (N,, m) are the points' :func:`ranges_m`."""
    import open3d as o3d

    z = points @ T_guess[2, :3] + T_guess[2, 3]
    band = settings.floor_band_m + ranges * np.sin(np.radians(settings.guess_rot_deg))
    candidates = np.flatnonzero(np.abs(z) < band)
    if len(candidates) < 3 * settings.min_table_points:
        return None
    sample = rng.choice(candidates, min(len(candidates), settings.ransac_points), replace=False)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[sample]))
    o3d.utility.random.seed(settings.seed)
    plane, _ = cloud.segment_plane(settings.floor_ransac_m, 3, 500)
    normal, offset = np.asarray(plane[:3], dtype=float), float(plane[3])
    scale = np.linalg.norm(normal)
    normal, offset = normal / scale, offset / scale
    if offset < 0:  # the camera (origin) is above the floor: n points towards it
        normal, offset = -normal, -offset
    for _ in range(2):  # least-squares refinement on the inliers at the noise the range gives
        inliers = np.abs(points @ normal + offset) < np.maximum(3 * settings.sigma_m(ranges), 0.01)
        if inliers.sum() < 3 * settings.min_table_points:
            return None
        normal, offset = _fit_plane(points[inliers])
        if offset < 0:
            normal, offset = -normal, -offset
    tilt = np.degrees(np.arccos(np.clip((T_guess[:3, :3] @ normal)[2], -1, 1)))
    if tilt > settings.max_floor_tilt_deg:
        return None
    inliers = np.abs(points @ normal + offset) < np.maximum(3 * settings.sigma_m(ranges), 0.01)
    return _Floor(normal, offset, inliers)


def levelled_pose(T_guess: np.ndarray, floor_normal: np.ndarray, floor_offset_m: float) -> np.ndarray:
    """``T_guess`` turned (least rotation) so the floor plane ``normal . p + offset = 0`` (node frame) is ``z = 0``
    in the world: the floor's tilt and height replace the guess's, its X, Y and heading stay."""
    from scipy.spatial.transform import Rotation

    up = T_guess[:3, :3] @ floor_normal
    axis = np.cross(up, [0.0, 0.0, 1.0])
    angle = np.arctan2(np.linalg.norm(axis), up[2])
    turn = Rotation.from_rotvec(axis / max(np.linalg.norm(axis), 1e-12) * angle).as_matrix()
    return make_T(turn @ T_guess[:3, :3], [T_guess[0, 3], T_guess[1, 3], floor_offset_m])


def _amplitude_ratio(points: np.ndarray, ranges: np.ndarray, amplitude: np.ndarray, floor: _Floor) -> np.ndarray:
    """(N,) each point's amplitude over the floor's fitted amplitude at its range and incidence.

    The floor's amplitude is modelled as ``log a = c0 + c1 log r + c2 log cos(incidence)`` (the
    inverse-square fall-off and Lambert's cosine, with fitted exponents), fitted by least squares on
    the floor inliers with two rounds of rejecting outliers (the tape and crosses are few)."""
    cosine = np.clip(np.abs(points @ floor.normal) / np.maximum(ranges, 1e-9), 1e-3, 1.0)
    design = np.column_stack([np.ones(len(points)), np.log(np.maximum(ranges, 1e-3)), np.log(cosine)])
    log_a = np.log(np.maximum(amplitude, 1e-9))
    rows = np.flatnonzero(floor.inliers & (amplitude > 0))
    X, y = design[rows], log_a[rows]
    keep = np.ones(len(rows), dtype=bool)
    for _ in range(3):
        coef = np.linalg.solve(X[keep].T @ X[keep], X[keep].T @ y[keep])  # the normal equations (3 x 3)
        residual = y - X @ coef
        keep = np.abs(residual) < 2.5 * max(1.4826 * np.median(np.abs(residual[keep])), 1e-3)
    return np.exp(log_a - design @ coef)


def _table_parts(points: np.ndarray, candidates: np.ndarray, obs: DepthObservation,
                 settings: DepthNodeSettings) -> list[np.ndarray]:
    """Connected parts (index arrays into ``points``) of the table candidates: image components after eroding
    ``erode_px`` pixels (mixed pixels at the edges go) when the pixels are known, else Open3D DBSCAN."""
    if len(candidates) == 0:
        return []
    if obs.pixel_index is not None:
        shape = (obs.intrinsics.height, obs.intrinsics.width)
        mask = np.zeros(shape[0] * shape[1], dtype=bool)
        pixels = np.asarray(obs.pixel_index, dtype=np.int64)[candidates]
        mask[pixels] = True
        mask = mask.reshape(shape)
        if settings.erode_px:
            mask = ndimage.binary_erosion(mask, iterations=settings.erode_px)
        labels, _ = ndimage.label(mask, structure=np.ones((3, 3)))
        point_labels = labels.ravel()[pixels]
    else:
        import open3d as o3d

        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[candidates]))
        point_labels = np.asarray(cloud.cluster_dbscan(eps=0.1, min_points=8)) + 1
    order = np.argsort(point_labels, kind="stable")
    bounds = np.flatnonzero(np.diff(point_labels[order])) + 1
    return [candidates[group] for group in np.split(order, bounds)
            if point_labels[group[0]] > 0 and len(group) >= settings.min_table_points]


def _vertical_normals(points: np.ndarray, up_node: np.ndarray, max_angle_deg: float) -> np.ndarray:
    """(M,) True where the local normal (Open3D, 16 nearest neighbours) is within ``max_angle_deg`` of ``up_node``."""
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(16))
    return np.abs(np.asarray(cloud.normals) @ up_node) > np.cos(np.radians(max_angle_deg))


def _tables(points: np.ndarray, obs: DepthObservation, floor: _Floor, ranges: np.ndarray,
            settings: DepthNodeSettings) -> tuple[list[Feature], list[str]]:
    """One table feature per declared table found (name ``table@capture``), ordered as the arrangement says
    (behind: near to far; beside: left to right in the image), and a problem per table not found."""
    if not obs.tables:
        return [], []
    height = points @ floor.normal + floor.offset_m
    heights = np.array([t.height_m for t in obs.tables])
    in_band = np.abs(height[:, None] - heights[None, :]).min(axis=1) < settings.table_band_m
    candidates = np.flatnonzero(in_band)
    if len(candidates):
        candidates = candidates[_vertical_normals(points[candidates], floor.normal, settings.table_normal_deg)]
    found = []  # (index array, mean height above floor, mean range, image column)
    for part in _table_parts(points, candidates, obs, settings):
        normal, offset = _fit_plane(points[part])
        part = part[np.abs(points[part] @ normal + offset) < np.maximum(3 * settings.sigma_m(ranges[part]), 0.01)]
        if len(part) < settings.min_table_points:
            continue
        normal, offset = _fit_plane(points[part])
        if np.degrees(np.arccos(min(abs(normal @ floor.normal), 1.0))) > settings.table_normal_deg / 3:
            continue
        centre = points[part].mean(axis=0)
        column = obs.intrinsics.fx * centre[0] / centre[2] + obs.intrinsics.cx
        found.append((part, float(height[part].mean()), float(ranges[part].mean()), float(column)))
    claimed: dict[int, int] = {}  # declared table (index into obs.tables) -> part (index into found)
    problems = []
    for k, spec in enumerate(obs.tables):  # each declared table takes the largest unclaimed part near its height
        options = [i for i, f in enumerate(found)
                   if i not in claimed.values() and abs(f[1] - spec.height_m) < settings.table_band_m]
        if options:
            claimed[k] = max(options, key=lambda i: len(found[i][0]))
        else:
            problems.append(f"{spec.name} not found in capture {obs.capture_id} (no horizontal plane "
                            f"{spec.height_m:.2f} +- {settings.table_band_m:.2f} m above the floor)")
    # tables of one height cannot be told apart: they are named in the arrangement's order
    # (behind: near to far; beside: left to right in the image), in the order they were declared
    key = 3 if obs.arrangement == "beside" else 2
    tables = []
    for height in sorted({obs.tables[k].height_m for k in claimed}):
        specs = [k for k in claimed if obs.tables[k].height_m == height]
        parts = sorted((claimed[k] for k in specs), key=lambda i: found[i][key])
        tables += [Feature("table", f"{obs.tables[k].name}@{obs.capture_id}", points[found[i][0]], height,
                           capture_id=obs.capture_id) for k, i in zip(specs, parts, strict=True)]
    return tables, problems


def _gate_m(ranges: np.ndarray, settings: DepthNodeSettings, extra_m: float) -> np.ndarray:
    """How far (m) a point's world position may be off under the guess: position error plus range times the
    rotation error, plus ``extra_m`` (half a tape, a cross's arm)."""
    return settings.guess_trans_m + ranges * np.sin(np.radians(settings.guess_rot_deg)) + extra_m


def _lines(points: np.ndarray, world: np.ndarray, tape: np.ndarray, ranges: np.ndarray, layout: CellLayout,
           capture_id: str, settings: DepthNodeSettings) -> list[Feature]:
    """A line feature per known line with at least ``min_line_points`` tape points within the gate of it and of
    no other line. ``points`` are the tape pixels on the floor plane (node frame; see :func:`extract_features`)."""
    index = np.flatnonzero(tape)
    if len(index) == 0 or not layout.lines:
        return []
    xy = world[index, :2]
    distance = np.full((len(index), len(layout.lines)), np.inf)
    for j, line in enumerate(layout.lines):
        along, across = (1, 0) if line.axis == "x" else (0, 1)
        within = (xy[:, along] > line.span_m[0] - 0.5) & (xy[:, along] < line.span_m[1] + 0.5)
        distance[within, j] = np.abs(xy[within, across] - line.value_m)
    gate = _gate_m(ranges[index], settings, 0.5 * max((ln.width_m for ln in layout.lines), default=0.0))
    inside = distance < gate[:, None]
    unique = inside.sum(axis=1) == 1
    nearest = np.argmin(distance, axis=1)
    features = []
    for j, line in enumerate(layout.lines):
        members = index[unique & (nearest == j)]
        if len(members) >= settings.min_line_points:
            features.append(Feature("line", line.name, points[members], line.value_m, line.axis, capture_id))
    return features


CROSS_ARM_CLEARANCE_M = 0.08
"""Points further than this (m) from a cross's centre along one bar belong to the other bar's arms."""


def cross_centre(points_world: np.ndarray) -> np.ndarray:
    """The centre (m, world) of a cross whose bars lie along world X and Y, from its points (M, 3, world).

    Not the centroid: a node sees the near arms with more pixels than the far ones, which pulls a
    centroid towards it. Each coordinate comes from the other bar's arms instead (the bar along Y
    gives X: its points' X spread evenly across its width whatever their density along it)."""
    centre = np.median(points_world, axis=0)
    for axis, other in ((0, 1), (1, 0)):
        arms = np.abs(points_world[:, other] - centre[other]) > CROSS_ARM_CLEARANCE_M
        if arms.any():
            centre[axis] = np.median(points_world[arms, axis])
    return centre


def _crosses(points: np.ndarray, world: np.ndarray, bright: np.ndarray, ranges: np.ndarray, layout: CellLayout,
             capture_id: str, settings: DepthNodeSettings) -> list[Feature]:
    """A point feature (``cross NAME``, its blob's points) per known cross with a retroreflective blob in its gate."""
    index = np.flatnonzero(bright)
    if len(index) < settings.min_cross_points or not layout.crosses:
        return []
    import open3d as o3d

    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(world[index]))
    labels = np.asarray(cloud.cluster_dbscan(eps=0.1, min_points=settings.min_cross_points))
    known = np.array([c.position_m for c in layout.crosses], dtype=float)
    features = {}
    for label in range(labels.max() + 1):
        blob = index[labels == label]
        centre = cross_centre(world[blob])
        distance = np.linalg.norm(known[:, :2] - centre[:2], axis=1)
        j = int(np.argmin(distance))
        cross = layout.crosses[j]
        gate = _gate_m(ranges[blob].mean(), settings, cross.size_m)
        extent = np.ptp(world[blob, :2], axis=0)
        whole = bool((extent > 1.5 * cross.size_m).all())  # both bars seen end to end (not cut by the image)
        if whole and distance[j] < gate and (cross.name not in features
                                             or len(blob) > len(features[cross.name].points)):
            features[cross.name] = Feature("point", f"cross {cross.name}", points[blob],
                                           tuple(float(v) for v in cross.position_m), capture_id=capture_id)
    return list(features.values())


def extract_features(obs: DepthObservation, T_world_node_guess: np.ndarray, layout: CellLayout,
                     settings: DepthNodeSettings | None = None) -> tuple[list[Feature], list[str]]:
    """The floor, tables, lines and crosses of one capture (points in the node frame, m), found under
    ``T_world_node_guess`` (off by up to ``settings.guess_trans_m`` and ``guess_rot_deg``), and the problems met
    ("table3 not found in capture c0003 (...)", "no floor plane found ..."). See the module's docstring for how.

    Raises :class:`InputError` for malformed arrays or a non-rigid guess; an empty or unusable capture is a
    problem, not an error (the other captures may do)."""
    settings = settings or DepthNodeSettings()
    T_guess, _ = check_transform(T_world_node_guess, "T_world_node")
    points, finite = check_observation(obs)
    if finite.sum() < 10 * settings.min_table_points:
        return [], [f"capture {obs.capture_id}: the depth is empty or nearly so ({int(finite.sum())} valid points)"]
    keep = np.flatnonzero(finite)
    obs = replace(obs, points=points[keep], amplitude=np.asarray(obs.amplitude, dtype=float)[keep],
                  pixel_index=None if obs.pixel_index is None else np.asarray(obs.pixel_index)[keep])
    points = obs.points
    rng = np.random.default_rng(settings.seed)
    ranges = ranges_m(points)
    floor = _find_floor(points, ranges, T_guess, settings, rng)
    if floor is None:
        return [], [f"no floor plane found in capture {obs.capture_id} within {settings.max_floor_tilt_deg:g} deg "
                    "of level near z = 0 under the pose guess: check the initial pose (RotX about -140 deg for a "
                    "ceiling node) and that the floor is in view"]
    ratio = _amplitude_ratio(points, ranges, obs.amplitude, floor)
    near_floor = np.abs(points @ floor.normal + floor.offset_m) < 0.05
    bright = near_floor & (ratio > settings.cross_ratio)
    tape = floor.inliers & (ratio > settings.tape_ratio) & ~bright
    world = np.zeros_like(points)  # world positions under the levelled guess, of the markings only (few)
    world[tape | bright] = transform_points(levelled_pose(T_guess, floor.normal, floor.offset_m),
                                            points[tape | bright])
    # tape points are moved along their rays onto the capture's floor plane (fitted to thousands of points):
    # their range noise goes, and only the tape's width spreads them about the line
    on_plane = points.copy()
    on_plane[tape] *= (-floor.offset_m / (points[tape] @ floor.normal))[:, None]
    plain = np.flatnonzero(floor.inliers & ~bright)
    plain = rng.choice(plain, min(len(plain), settings.max_floor_points), replace=False)
    features = [Feature("floor", "floor", points[np.sort(plain)], 0.0, capture_id=obs.capture_id)]
    tables, problems = _tables(points, obs, floor, ranges, settings)
    features += tables
    features += _lines(on_plane, world, tape, ranges, layout, obs.capture_id, settings)
    features += _crosses(points, world, bright, ranges, layout, obs.capture_id, settings)
    return features, problems


AXES = {"x": 0, "y": 1, "z": 2}


def feature_residuals(features: list[Feature], T_world_node: np.ndarray) -> list[dict]:
    """Each feature's fit at ``T_world_node``: ``{"kind", "name", "capture_id", "n_points", "known_m",
    "measured_m", "error_m", "rms_m"}`` (m). Floor and tables: the mean world ``z`` against the known height;
    lines: the mean world ``x`` (or ``y``) against the line's value; points (crosses): the centre's
    (:func:`cross_centre`) distance from the known position (``known_m`` 0; ``known_xyz_m`` and
    ``measured_xyz_m`` added). ``rms_m`` is the RMS of the per-point offsets (the spread included)."""
    rows = []
    for feature in features:
        world = transform_points(T_world_node, feature.points)
        row = {"kind": feature.kind, "name": feature.name, "capture_id": feature.capture_id,
               "n_points": len(feature.points)}
        if feature.kind == "point":
            known = np.asarray(feature.known, dtype=float)
            centre = cross_centre(world)
            distance = float(np.linalg.norm(centre - known))
            row |= {"known_m": 0.0, "measured_m": distance, "error_m": distance,
                    "rms_m": float(np.sqrt(np.mean(np.sum((world - known) ** 2, axis=1)))),
                    "known_xyz_m": known.tolist(), "measured_xyz_m": centre.tolist()}
        else:
            values = world[:, AXES[feature.axis or "z"]]
            known = float(feature.known)
            row |= {"known_m": known, "measured_m": float(values.mean()), "error_m": float(values.mean() - known),
                    "rms_m": float(np.sqrt(np.mean((values - known) ** 2)))}
            if feature.axis:
                row["axis"] = feature.axis
        rows.append(row)
    return rows
