"""Calibrate the geometry of a swept 2D scanner by making its 3D cloud as planar as possible.

A sweep (:class:`~backend.core.sweep_geometry.SweepGeometry`, frames in :mod:`backend.core.sweep_geometry`) of a
scene with planes (floor, walls, box faces) is flat only with the right geometry: a wrong offset
between the servo axis and the scanner's optical centre, or a tilted scanner, bends and doubles
every plane. The solver works like ICP:

1. assemble the cloud with the current geometry;
2. segment planes from it: Open3D RANSAC ``segment_plane`` on a fixed random subset, the
   largest first, each cut to its largest connected blob and refined by PCA; lines, slivers and
   thick slabs of clutter are dropped, pieces of one plane merged, points near two planes (corners)
   left out. The distance threshold shrinks over the first iterations (``thresholds_m``); after
   that the planes found are tracked (re-fitted and re-gathered around their previous points,
   as ICP keeps its correspondences) so the iteration settles;
3. ``scipy.optimize.least_squares`` over the geometry parameters, each plane re-fitted by PCA
   inside the cost (variable projection), residual = point-to-plane distance (m), at most
   ``points_per_plane`` points per plane;

until the points in the cost stop changing. Parameters, relative to the initial geometry:

- ``offset_u_m``, ``offset_v_m``: the optical centre's offset perpendicular to the axis (m) along
  ``u``, ``v`` (:func:`axis_basis`: for axis x these are mount y and z). The offset along the
  axis moves the whole cloud rigidly: planarity cannot see it and it stays as given.
- ``zero_offset_rad``: the servo's zero (rad). It turns the whole cloud about the axis, so only an
  outside reference fixes it: ``up_mount``, the floor's normal (up) in the mount frame (a levelled
  mount: z). The largest near-horizontal plane below the mount is the floor, and its normal is
  held to ``up_mount`` instead of being fitted. Without ``up_mount`` the zero offset is kept.
- ``tilt_u_rad``, ``tilt_v_rad`` (with ``estimate_tilt``): small rotation of the scanner about
  ``u``, ``v`` through its optical centre. A rotation about the axis is the zero offset again.

Uncertainty (1-sigma): from the Jacobian at the solution, ``s^2 (J^T J)^-1`` with
``s^2 = SSR / (m - n - 3 planes)``, and from a delete-a-group jackknife over contiguous blocks of
servo steps (what one part of the sweep says against the rest); the larger is reported per
parameter, as elsewhere in the studio. The result also carries the scanner's pose in the mount frame at
servo reading zero as the studio's one transform result (:class:`~backend.core.result.TransformResult`,
kind ``sweep``), its covariance propagated from the parameters' and NaN where the sweep cannot see it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from backend.calib.sweep.checks import sweep_verdict
from backend.core.errors import InputError
from backend.core.result import (
    ProgressCallback,
    SolveResult,
    TransformResult,
    finite_or_none,
    jackknife_std,
    no_progress,
    widen_covariance,
)
from backend.core.sweep_geometry import ScanAtAngle, SweepGeometry, stack_scans
from backend.core.transforms import params_between
from backend.core.uncertainty import sigmas

MIN_STEPS = 10
"""A sweep needs at least this many servo steps."""
MIN_POINTS = 2000
"""... and this many finite points."""
MIN_PLANES = 3
"""Planes needed to pin the offset and tilts."""

PARAM_NAMES = ("offset_u_m", "offset_v_m", "zero_offset_rad", "tilt_u_rad", "tilt_v_rad")
JACOBIAN_STEP = 1e-6
"""Central-difference step (m or rad) of the parameters-to-transform Jacobian."""
DETERMINED_TOLERANCE = 1e-6
"""A transform parameter farther than this (unit vector's distance) from the span the estimated parameters move
the pose in is undetermined (NaN)."""


def axis_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit ``u, v`` perpendicular to the unit ``axis`` with ``(axis, u, v)`` right-handed: for an axis
    along mount x, y or z, ``u, v`` are the next two mount axes (x -> y, z; y -> z, x; z -> x, y)."""
    a = np.asarray(axis, dtype=float)
    helper = np.eye(3)[(int(np.argmax(np.abs(a))) + 1) % 3]
    u = helper - a * (a @ helper)
    u /= np.linalg.norm(u)
    return u, np.cross(a, u)


@dataclass
class SweepCalibrationSettings:
    up_mount: tuple[float, float, float] | None = None
    """Floor normal (up) in the mount frame; needed to estimate the zero offset (None: keep it)."""
    estimate_tilt: bool = True
    """Estimate the scanner's tilt about the two directions perpendicular to the axis."""
    thresholds_m: tuple[float, ...] = (0.08, 0.05, 0.035, 0.03)
    """Plane inlier distance (m) of each outer iteration; the last repeats until converged (it should be
    about three times the range noise)."""
    max_iterations: int = 10
    """Outer iterations (segment, solve) at most."""
    max_planes: int = 14
    sample_points: int = 40000
    """Random subset of the cloud used for segmentation and the cost."""
    points_per_plane: int = 3000
    """At most this many points of each plane enter the cost (so the floor does not swamp the rest)."""
    min_plane_points: int = 250
    """Fewer inliers (of the subset) end the plane search."""
    min_plane_extent_m: float = 0.25
    """A plane must spread at least this far (m, 1-sigma) in both in-plane directions."""
    ransac_iterations: int = 500
    max_rejections: int = 8
    """Candidate planes rejected (lines, slivers, slabs) before the search ends."""
    cluster_eps_m: float = 0.35
    """Voxel size (m) whose 26-neighbourhood joins a plane's inliers into one surface (the largest is kept)."""
    max_plane_rms_ratio: float = 0.45
    """A plane's RMS residual must stay below this fraction of the inlier threshold: a real plane with
    noise well inside the threshold is thin (about 0.3), a slab of unrelated points is not (0.58)."""
    floor_max_angle_deg: float = 20.0
    """The floor's fitted normal is within this angle (deg) of ``up_mount``."""
    converge_sigma: float = 0.1
    """Converged when, once the planes are tracked, the points in the cost stay the same or no parameter
    moves by more than this many of its 1-sigma (from the Jacobian) between outer iterations."""
    jackknife_groups: int = 8
    """Contiguous blocks of servo steps left out in turn for the spread (0 = off)."""
    seed: int = 0


@dataclass
class SweepCalibrationResult(SolveResult):
    """The calibrated geometry, its parameters' uncertainty, and the scanner's pose at servo zero as the one
    transform result (:attr:`transform`). Not a rig-graph edge: accepting it rewrites the sensor's sweep geometry."""

    kind = "sweep"

    geometry: SweepGeometry
    """The calibrated geometry."""
    initial: SweepGeometry
    """The geometry the solve started from."""
    estimated: list[str]
    """Names (:data:`PARAM_NAMES`) of the parameters estimated, in the order of ``values`` and ``covariance``."""
    values: np.ndarray
    """Estimated change of each parameter from ``initial`` (m or rad)."""
    covariance: np.ndarray
    """Covariance of ``values`` (the reported, larger-per-parameter sigmas with the Jacobian's correlations)."""
    std_jacobian: np.ndarray
    std_spread: np.ndarray | None
    rms_before_m: float
    """RMS point-to-plane residual (m) of the final planes' points with the initial geometry."""
    rms_after_m: float
    """... and with the calibrated geometry."""
    planes: int
    floor_found: bool
    points_used: int
    steps: int
    iterations: int
    u: np.ndarray
    """Unit direction (mount frame) of ``offset_u_m`` and ``tilt_u_rad``."""
    v: np.ndarray
    settings: SweepCalibrationSettings
    transform: TransformResult
    """Kind ``sweep``, method ``planes``: ``T_mount_scanner`` at servo reading zero (m), its 6x6 covariance from
    the parameters' (NaN where the sweep cannot see it: the offset along the axis, and whatever was kept), the
    plane residuals, convergence, verdict, warnings and seconds. Parent ``mount``, child ``scanner``."""
    halves_difference: np.ndarray | None = None
    """The parameters (``estimated`` order, m or rad) solved from the even servo steps minus those from the odd
    ones, on the same planes: the independent cross-check; None when a half has too few points."""
    halves_std: np.ndarray | None = None
    """1-sigma of ``halves_difference`` (the two halves' Jacobian sigmas combined)."""

    @property
    def converged(self) -> bool:
        return self.transform.converged

    @property
    def warnings(self) -> list[str]:
        return self.transform.warnings

    @property
    def seconds(self) -> float:
        return self.transform.seconds

    @property
    def std(self) -> dict[str, list[float | None]]:
        """The transform's 1-sigma: ``trans_m`` (m, mount axes), ``rot_deg`` (deg, about the scanner's axes)."""
        return self.transform.std

    @property
    def parameter_std(self) -> dict[str, float]:
        """1-sigma of each estimated parameter, by its name in :data:`PARAM_NAMES` (m or rad)."""
        s = sigmas(self.covariance)
        return {name: float(x) for name, x in zip(self.estimated, s, strict=True)}

    def summary(self) -> dict[str, Any]:
        """The geometry, the transform's ``std`` (m, deg), each parameter's sigma, flatness, verdict and
        ``transform`` (the :class:`TransformResult` record, parent ``mount``, child ``scanner``)."""
        return {
            "geometry": self.geometry.to_dict(),
            "std": self.std,
            "parameter_std": {name: finite_or_none([x])[0] for name, x in self.parameter_std.items()},
            "rms_before_m": self.rms_before_m,
            "rms_after_m": self.rms_after_m,
            "planes": self.planes,
            "seconds": self.seconds,
            "verdict": None if self.transform.verdict is None else self.transform.verdict.to_dict(),
            "transform": self.transform.to_record(),
        }

    def to_record(self) -> dict[str, Any]:
        record = self.summary()
        record.update(
            kind=self.kind,
            initial=self.initial.to_dict(),
            estimated=list(self.estimated),
            values=self.values.tolist(),
            covariance=[finite_or_none(row) for row in self.covariance],
            std_jacobian=finite_or_none(self.std_jacobian),
            std_spread=finite_or_none(self.std_spread),
            halves_difference=finite_or_none(self.halves_difference),
            halves_std=finite_or_none(self.halves_std),
            u=self.u.tolist(),
            v=self.v.tolist(),
            floor_found=self.floor_found,
            points_used=self.points_used,
            steps=self.steps,
            iterations=self.iterations,
            converged=self.converged,
            settings=asdict(self.settings),
            warnings=list(self.warnings),
        )
        return record


# ---------------------------------------------------------------------------------------------- model

class _Model:
    """Geometry as a function of the estimated parameters (changes from the initial geometry)."""

    def __init__(self, initial: SweepGeometry, estimated: list[str]):
        self.initial = initial
        self.estimated = estimated
        self.u, self.v = axis_basis(initial.axis)

    def geometry(self, x: np.ndarray) -> SweepGeometry:
        full = dict.fromkeys(PARAM_NAMES, 0.0)
        full.update(zip(self.estimated, np.asarray(x, dtype=float), strict=True))
        g = self.initial.copy()
        T = g.T_servo_scanner
        T[:3, 3] = T[:3, 3] + full["offset_u_m"] * self.u + full["offset_v_m"] * self.v
        tilt = Rotation.from_rotvec(full["tilt_u_rad"] * self.u + full["tilt_v_rad"] * self.v).as_matrix()
        T[:3, :3] = tilt @ T[:3, :3]
        g.zero_offset_rad = self.initial.zero_offset_rad + full["zero_offset_rad"]
        return g

    def T_mount_scanner(self, x: np.ndarray) -> np.ndarray:
        """4x4 pose of the scanner in mount at servo reading zero (m) with the parameters ``x``."""
        return self.geometry(x).T_mount_scanner(0.0)


def _transform_covariance(model: _Model, x: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """6x6 covariance (:data:`TRANSFORM_PARAMETERS`: m along mount axes, rad about the scanner's axes) of the
    scanner's pose at servo zero, the parameters' ``covariance`` propagated through a central-difference
    Jacobian. NaN in the row and column of every transform parameter that is no combination of the estimated
    ones: the offset along the servo axis always, a rotation when the servo zero or the tilts were kept."""
    T_hat = model.T_mount_scanner(x)
    J = np.column_stack([(params_between(T_hat, model.T_mount_scanner(x + d))
                          - params_between(T_hat, model.T_mount_scanner(x - d))) / (2 * JACOBIAN_STEP)
                         for d in JACOBIAN_STEP * np.eye(len(x))])
    with np.errstate(invalid="ignore"):  # an undetermined parameter's inf times a zero derivative
        cov = J @ covariance @ J.T
    U, singular, _ = np.linalg.svd(J, full_matrices=False)
    seen = U[:, singular > 1e-9 * singular.max()]
    unseen = np.linalg.norm(np.eye(6) - seen @ seen.T, axis=0) > DETERMINED_TOLERANCE
    cov = np.where(np.isfinite(cov), cov, np.nan)
    cov[unseen, :] = np.nan
    cov[:, unseen] = np.nan
    return cov


def _plane_residuals(points: np.ndarray, plane_of: np.ndarray, n_planes: int, fixed_normal: dict[int, np.ndarray]
                     ) -> np.ndarray:
    """Distance (m) of each point to its plane, each plane fitted by PCA (or with its normal fixed)."""
    counts = np.maximum(np.bincount(plane_of, minlength=n_planes), 1).astype(float)
    centroid = np.column_stack([np.bincount(plane_of, points[:, k], minlength=n_planes)
                                for k in range(3)]) / counts[:, None]
    d = points - centroid[plane_of]
    cov = np.zeros((n_planes, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            cov[:, i, j] = cov[:, j, i] = np.bincount(plane_of, d[:, i] * d[:, j], minlength=n_planes)
    normals = np.linalg.eigh(cov)[1][:, :, 0]
    for k, n in fixed_normal.items():
        normals[k] = n
    return np.einsum("ij,ij->i", d, normals[plane_of])


@dataclass
class _Planes:
    index: np.ndarray
    """Indices (into the full sweep) of the points in the cost."""
    plane_of: np.ndarray
    """Plane number of each."""
    count: int
    floor: int | None
    members: list[np.ndarray] = field(default_factory=list)
    """All members (indices into the full sweep, within the segmentation subset) of each plane."""


def _largest_component(points: np.ndarray, voxel_m: float) -> np.ndarray:
    """Mask of the points in the largest 26-connected blob of ``voxel_m`` (m) voxels."""
    if len(points) == 0:
        return np.zeros(0, bool)
    cells = np.floor((points - points.min(axis=0)) / voxel_m).astype(np.int64)
    shape = cells.max(axis=0) + 1
    if int(np.prod(shape)) > 20_000_000:  # absurdly spread: skip the check
        return np.ones(len(points), bool)
    grid = np.zeros(shape, bool)
    grid[cells[:, 0], cells[:, 1], cells[:, 2]] = True
    labels, n = ndimage.label(grid, structure=np.ones((3, 3, 3), bool))
    if n <= 1:
        return np.ones(len(points), bool)
    point_label = labels[cells[:, 0], cells[:, 1], cells[:, 2]]
    return point_label == np.argmax(np.bincount(point_label)[1:]) + 1


def _fit(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroid, unit normal and ascending eigenvalues (m^2) of a PCA plane fit."""
    c = points.mean(axis=0)
    w, vecs = np.linalg.eigh(np.cov((points - c).T))
    return c, vecs[:, 0], w


def _discover(points: np.ndarray, subset: np.ndarray, threshold_m: float,
              settings: SweepCalibrationSettings) -> list[np.ndarray]:
    """RANSAC planes, largest first, on ``points[subset]``: members (indices) of each."""
    import open3d as o3d

    o3d.utility.random.seed(int(settings.seed))
    remaining = subset.copy()
    chosen: list[np.ndarray] = []
    fits: list[tuple[np.ndarray, np.ndarray]] = []
    failures = 0
    while (len(chosen) < settings.max_planes and len(remaining) >= settings.min_plane_points
           and failures < settings.max_rejections):
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points[remaining]))
        _, inliers = pcd.segment_plane(distance_threshold=threshold_m, ransac_n=3,
                                       num_iterations=settings.ransac_iterations)
        inliers = np.asarray(inliers, dtype=np.int64)
        if len(inliers) < settings.min_plane_points:
            break
        members = remaining[inliers]
        # one connected surface: the largest blob; the rest may belong to other planes
        members = members[_largest_component(points[members], settings.cluster_eps_m)]
        c, n, w = _fit(points[members])
        dist = (points[members] - c) @ n
        inside = np.abs(dist) < threshold_m
        members = members[inside]
        remaining = np.setdiff1d(remaining, members, assume_unique=True)
        if len(members) == 0:
            failures += 1
            continue
        thick = math.sqrt(np.mean(dist[inside] ** 2)) > settings.max_plane_rms_ratio * threshold_m
        if (len(members) < settings.min_plane_points or math.sqrt(max(w[1], 0.0)) < settings.min_plane_extent_m
                or thick):
            failures += 1  # a line (one scan, a pole), a sliver or a slab through clutter: drop it, look on
            continue
        same = [k for k, (c2, n2) in enumerate(fits)
                if abs(n2 @ n) > math.cos(math.radians(3.0)) and abs((c - c2) @ n2) < threshold_m]
        if same:  # another piece of a plane already found (split by an occlusion): one plane
            k = same[0]
            chosen[k] = np.concatenate([chosen[k], members])
            fits[k] = _fit(points[chosen[k]])[:2]
            continue
        chosen.append(members)
        fits.append((c, n))
    return chosen


def _voxel_keys(points: np.ndarray, voxel_m: float) -> np.ndarray:
    cells = np.floor(points / voxel_m).astype(np.int64) + (1 << 20)
    return (cells[:, 0] << 42) | (cells[:, 1] << 21) | cells[:, 2]


def _track(points: np.ndarray, subset: np.ndarray, previous: list[np.ndarray], threshold_m: float,
           settings: SweepCalibrationSettings) -> list[np.ndarray]:
    """The same planes after the geometry moved: each refitted to its previous members' new positions,
    members = subset points within the threshold and next to (one voxel of) the previous members."""
    voxel = settings.cluster_eps_m
    offsets = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)], np.int64)
    shifts = (offsets[:, 0] << 42) + (offsets[:, 1] << 21) + offsets[:, 2]
    subset_keys = _voxel_keys(points[subset], voxel)
    out = []
    for members in previous:
        c, n, _ = _fit(points[members])
        near = np.abs((points[subset] - c) @ n) < threshold_m
        around = np.unique((_voxel_keys(points[members], voxel)[:, None] + shifts[None, :]).ravel())
        out.append(subset[near & np.isin(subset_keys, around)])
    return out


def _finish(points: np.ndarray, chosen: list[np.ndarray], threshold_m: float, up: np.ndarray | None,
            settings: SweepCalibrationSettings) -> _Planes:
    """Drop ambiguous points and small planes, find the floor, pick each plane's points for the cost."""
    chosen = [m for m in chosen if len(m) >= 3]
    fits = [_fit(points[m])[:2] for m in chosen]
    if len(chosen) > 1:
        # points near two planes (corners, where a plane's extension cuts another) would bias both: drop them
        P = np.array([n for _, n in fits])
        D = np.einsum("ij,ij->i", P, np.array([c for c, _ in fits]))
        cost_members = []
        for k, members in enumerate(chosen):
            dist = np.abs(points[members] @ P.T - D)
            dist[:, k] = np.inf
            cost_members.append(members[dist.min(axis=1) >= threshold_m])
    else:
        cost_members = list(chosen)
    keep = [k for k, m in enumerate(cost_members) if len(m) >= settings.min_plane_points // 2]
    chosen = [chosen[k] for k in keep]
    cost_members = [cost_members[k] for k in keep]
    fits = [fits[k] for k in keep]
    floor = None
    if up is not None:
        best = 0
        for k, (members, (c, n)) in enumerate(zip(cost_members, fits, strict=True)):
            horizontal = abs(n @ up) > math.cos(math.radians(settings.floor_max_angle_deg))
            if horizontal and c @ up < -0.1 and len(members) > best:
                floor, best = k, len(members)
    index, plane_of = [], []
    for k, members in enumerate(cost_members):
        # a fixed pseudo-random priority per point, so that a few members more or less change little
        priority = (members * 2654435761) % 4294967291
        take = members if len(members) <= settings.points_per_plane else members[
            np.argsort(priority, kind="stable")[:settings.points_per_plane]]
        index.append(np.sort(take))
        plane_of.append(np.full(len(take), k))
    if not chosen:
        return _Planes(np.zeros(0, np.int64), np.zeros(0, np.int64), 0, None, [])
    return _Planes(np.concatenate(index), np.concatenate(plane_of), len(chosen), floor, chosen)


def _jacobian_covariance(J: np.ndarray, r: np.ndarray, n_planes: int) -> np.ndarray:
    """``s^2 (J^T J)^-1`` with ``s^2 = SSR / (m - n - 3 planes)``; inf where undetermined."""
    n = J.shape[1]
    s2 = float(r @ r) / max(len(r) - n - 3 * n_planes, 1)
    H = J.T @ J
    d = np.sqrt(np.clip(np.diag(H), 1e-300, None))
    Hs = H / np.outer(d, d)
    if not np.isfinite(Hs).all() or np.linalg.cond(Hs) > 1e12:
        return np.full((n, n), np.inf)
    return s2 * np.linalg.inv(Hs) / np.outer(d, d)


def _jacobian_std(J: np.ndarray, r: np.ndarray, n_planes: int) -> np.ndarray:
    return sigmas(_jacobian_covariance(J, r, n_planes))


def _check(scans: Sequence[ScanAtAngle]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if len(scans) < MIN_STEPS:
        raise InputError(f"a sweep of {len(scans)} servo steps is too short to calibrate; "
                         f"at least {MIN_STEPS} are needed", "scans")
    try:
        pts, ang, _ = stack_scans(scans)
    except (ValueError, TypeError) as exc:
        raise InputError(f"expected (servo_angle_rad, points (N, 3), intensity) per step: {exc}", "scans") from None
    finite = np.isfinite(pts).all(axis=1) & np.isfinite(ang)
    step = np.repeat(np.arange(len(scans)), [len(np.asarray(s[1]).reshape(-1, 3)) for s in scans])
    pts, ang, step = pts[finite], ang[finite], step[finite]
    if len(pts) < MIN_POINTS:
        raise InputError(f"only {len(pts)} finite points in the sweep; at least {MIN_POINTS} are needed", "scans")
    if len(np.unique(step)) < MIN_STEPS:
        raise InputError(f"only {len(np.unique(step))} servo steps have points; at least {MIN_STEPS} are needed",
                         "scans")
    return pts, ang, step


def calibrate_sweep(scans: Sequence[ScanAtAngle], initial: SweepGeometry | None = None,
                    settings: SweepCalibrationSettings | None = None,
                    progress: ProgressCallback = no_progress) -> SweepCalibrationResult:
    """Calibrate a swept scanner's geometry from one sweep of a scene with planes.

    Args:
        scans: per servo step ``(servo angle read (rad), points (N, 3) in the scanner frame (m),
            intensity or None)`` (:meth:`backend.devices.dynamixel_servo.SweptScanner.scans_of`).
        initial: the starting geometry (its axis and its offset along the axis are kept).
        settings: see :class:`SweepCalibrationSettings`; set ``up_mount`` to estimate the zero offset.

    Raises :class:`InputError` for fewer than :data:`MIN_STEPS` steps, :data:`MIN_POINTS` points or
    :data:`MIN_PLANES` planes.
    """
    started = time.monotonic()
    settings = settings or SweepCalibrationSettings()
    initial = (initial or SweepGeometry()).copy()
    pts, ang, step = _check(scans)
    warnings: list[str] = []
    up = None
    if settings.up_mount is not None:
        up = np.asarray(settings.up_mount, dtype=float).reshape(3)
        if not np.isfinite(up).all() or np.linalg.norm(up) < 1e-9:
            raise InputError(f"up_mount must be a non-zero vector, got {up.tolist()}", "up_mount")
        up = up / np.linalg.norm(up)
        if abs(up @ initial.axis) > math.cos(math.radians(30)):
            warnings.append("the floor normal is nearly parallel to the servo axis: the zero offset is weakly "
                            "determined")
    estimated = ["offset_u_m", "offset_v_m"]
    if up is not None:
        estimated.append("zero_offset_rad")
    else:
        warnings.append("no up_mount (floor normal) given: the zero offset cannot be seen in a planar scene and "
                        "was kept")
    if settings.estimate_tilt:
        estimated += ["tilt_u_rad", "tilt_v_rad"]
    model = _Model(initial, estimated)
    rng = np.random.default_rng(settings.seed)
    subset = np.sort(rng.choice(len(pts), min(settings.sample_points, len(pts)), replace=False))

    def residuals(x: np.ndarray, planes: _Planes, keep: np.ndarray | None = None) -> np.ndarray:
        idx = planes.index if keep is None else planes.index[keep]
        plane_of = planes.plane_of if keep is None else planes.plane_of[keep]
        g = model.geometry(x)
        fixed = {planes.floor: up} if planes.floor is not None and up is not None else {}
        return _plane_residuals(g.transform(pts[idx], ang[idx]), plane_of, planes.count, fixed)

    x = np.zeros(len(estimated))
    planes = None
    converged = False
    iterations = 0
    n_thr = len(settings.thresholds_m)
    max_outer = max(int(settings.max_iterations), n_thr + 1)
    for it in range(max_outer):
        iterations = it + 1
        threshold = settings.thresholds_m[min(it, n_thr - 1)]
        progress(0.8 * it / max_outer, f"segmenting planes ({threshold * 100:.1f} cm), iteration {it + 1}")
        current = model.geometry(x).transform(pts, ang)
        if it < n_thr or planes is None:
            found = _discover(current, subset, threshold, settings)
        else:  # the planes are known: follow them, as ICP follows its correspondences
            found = _track(current, subset, planes.members, threshold, settings)
        previous = planes
        planes = _finish(current, found, threshold, up, settings)
        if planes.count < MIN_PLANES:
            raise InputError(f"found only {planes.count} planes in the sweep (at least {MIN_PLANES} needed): "
                             f"scan a scene with a floor and walls, or check the initial geometry", "scans")
        if up is not None and planes.floor is None:
            raise InputError("no floor (a large plane below the mount facing up_mount) found: the zero offset needs "
                             "one; check up_mount", "up_mount")
        sol = least_squares(residuals, x, args=(planes,), x_scale="jac", method="trf")
        step_x = np.abs(sol.x - x)
        x = sol.x
        sigma = _jacobian_std(sol.jac, sol.fun, planes.count)
        same_points = previous is not None and np.array_equal(previous.index, planes.index)
        if it >= n_thr and (same_points or np.all(step_x <= settings.converge_sigma * sigma)):
            converged = True
            break
    assert planes is not None
    if not converged:
        warnings.append(f"not converged after {iterations} iterations")

    # uncertainty: Jacobian at the solution
    r = sol.fun
    cov_j = _jacobian_covariance(sol.jac, r, planes.count)
    if not np.isfinite(cov_j).all():
        warnings.append("the planes do not determine every parameter (singular Jacobian)")
    std_j = sigmas(cov_j)

    # uncertainty: delete-a-group jackknife over contiguous blocks of servo steps
    std_spread = None
    groups = settings.jackknife_groups
    n_steps = int(step.max()) + 1
    if groups >= 3:
        block = np.minimum(step[planes.index] * groups // n_steps, groups - 1)
        estimates = []
        for g in range(groups):
            progress(0.8 + 0.2 * g / groups, f"spread: leaving out servo steps block {g + 1} of {groups}")
            keep = block != g
            if keep.all() or keep.sum() < len(x) + 3 * planes.count + 10:
                continue
            jk = least_squares(residuals, x, args=(planes, keep), x_scale="jac", method="trf")
            estimates.append(jk.x)
        if len(estimates) >= 3:
            std_spread = jackknife_std(np.array(estimates))
    covariance = widen_covariance(cov_j, std_spread)

    # cross-check: the same planes solved from the even and from the odd servo steps alone
    progress(0.98, "cross-check: the even and the odd servo steps alone")
    halves = []
    for parity in (0, 1):
        keep = step[planes.index] % 2 == parity
        if keep.sum() < len(x) + 3 * planes.count + 10:
            break
        half = least_squares(residuals, x, args=(planes, keep), x_scale="jac", method="trf")
        halves.append((half.x, _jacobian_std(half.jac, half.fun, planes.count)))
    halves_difference = halves_std = None
    if len(halves) == 2:
        halves_difference = halves[0][0] - halves[1][0]
        halves_std = np.hypot(halves[0][1], halves[1][1])

    r0 = residuals(np.zeros(len(x)), planes)
    rms_before_m, rms_after_m = float(np.sqrt(np.mean(r0 ** 2))), float(np.sqrt(np.mean(r ** 2)))
    transform = TransformResult(
        kind="sweep", method="planes", parent="mount", child="scanner", T_parent_child=model.T_mount_scanner(x),
        covariance=_transform_covariance(model, x, covariance),
        residuals={"rms_before_m": rms_before_m, "rms_after_m": rms_after_m, "planes": planes.count,
                   "points_used": len(planes.index)},
        diagnostics={"T_init": model.T_mount_scanner(np.zeros(len(x))).tolist(), "servo_axis": initial.axis.tolist(),
                     "estimated": list(estimated)},
        settings=asdict(settings), converged=converged, warnings=warnings, seconds=time.monotonic() - started)
    result = SweepCalibrationResult(
        geometry=model.geometry(x), initial=initial, estimated=estimated, values=x, covariance=covariance,
        std_jacobian=std_j, std_spread=std_spread, rms_before_m=rms_before_m, rms_after_m=rms_after_m,
        planes=planes.count, floor_found=planes.floor is not None, points_used=len(planes.index), steps=n_steps,
        iterations=iterations, u=model.u, v=model.v, settings=settings, transform=transform,
        halves_difference=halves_difference, halves_std=halves_std)
    transform.verdict = sweep_verdict(result)
    progress(1.0, "done")
    return result
