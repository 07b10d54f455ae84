"""Targetless LiDAR-to-camera extrinsic calibration from edges (after Yuan et al. 2021): ``T_camera_lidar``.

"Pixel-level extrinsic self calibration of high resolution LiDAR and camera in targetless
environments" aligns the edges a LiDAR sees with those a camera sees in ordinary scenes.
Each image + cloud pair taken at one moment (the robot may move between pairs; the sensors
are rigid on it) is one :class:`EdgeObservation`. Pipeline:

1. LiDAR edges, per pair, from the points the camera may see at ``T_init`` (its view widened by
   :attr:`LidarCameraEdgesSettings.view_margin_deg`, within ``max_range_m``): plane
   intersections (depth-continuous edges, :mod:`backend.solvers.plane_edges`), as in the
   paper, and, when the cloud has intensities and scan lines, reflectivity steps along the scan
   lines (:mod:`backend.solvers.reflectivity_edges`; not in the paper), which carry single
   spinning-LiDAR frames of roads where few faces meet; thinned to one point per
   :attr:`~LidarCameraEdgesSettings.edge_spacing_m`. Depth *discontinuities* are not used: the
   beam footprint swells the foreground, as the paper shows.
2. Image edges, per pair: Canny pixels, their KD-tree and distance transform
   (:mod:`backend.solvers.image_edges`).
3. Coarse (:mod:`backend.solvers.edge_search`): a grid of rotations about ``T_init``, then joint
   pattern searches over rotation and (pivoted) translation, coarse to fine, maximising over all
   pairs the number of projected LiDAR edge points near an image edge (a triangular kernel on the
   distance transform, as wide as the search step is in pixels).
4. Fine (:mod:`backend.solvers.edge_alignment`): robust least squares of the distance (px) of each
   projected LiDAR edge point to the line fitted to its nearest image edge pixels, jointly over all
   pairs, re-matching each round with a shrinking match radius; analytic Jacobian.
5. Uncertainty: ``sigma^2 (J^T J)^-1`` at the solution
   (:func:`~backend.solvers.result.jacobian_covariance`), widened per parameter to the jackknife
   spread (:func:`~backend.solvers.result.widen_covariance`) over groups of edges (the points of
   an edge share the errors of its plane fits and of its image edge, which per-point noise cannot
   see) and, with three pairs or more, over pairs.

A scene with too few edges is refused with an :class:`InputError` naming the pair and what is
lacking (LiDAR edge points, image edge pixels, matches), as is a set of edges that leaves a
motion unobservable (all edges parallel: the smallest eigenvalue of the scaled ``J^T J``). A
solve that ends with a poor fit is returned with ``converged=False`` and a warning.

Parameters, covariance and sigmas follow :func:`backend.solvers.lidar_lidar.params_between`:
``[t_x, t_y, t_z]`` (m, along the camera's optical axes) and ``[r_x, r_y, r_z]`` (rad; reported in deg)
of a right perturbation ``R @ rotvec(r)``, i.e. about the LiDAR's axes, as ``conventions.md`` asks.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.camera_inverse import visible_radius
from backend.core.errors import InputError
from backend.core.projection import MIN_DEPTH_M, project_cloud
from backend.core.transforms import transform_points
from backend.solvers.edge_alignment import EdgeMatches, FineAlignmentSettings, match_edges, solve_matches
from backend.solvers.edge_search import CoarseSearchSettings, coarse_search
from backend.solvers.image_edges import ImageEdges, ImageEdgeSettings, find_image_edges
from backend.solvers.lidar_lidar import apply_params, check_cloud, check_transform
from backend.solvers.plane_edges import PlaneEdgeSettings, find_plane_edges
from backend.solvers.reflectivity_edges import ReflectivityEdgeSettings, find_reflectivity_edges
from backend.solvers.result import (
    TRANSFORM_PARAMETERS,
    ProgressCallback,
    SolveResult,
    finite_or_none,
    jackknife_std,
    jacobian_covariance,
    no_progress,
    transform_record_fields,
    transform_std,
    widen_covariance,
)

PLANE, REFLECTIVITY = 0, 1
"""Values of :attr:`LidarEdges.kind`: a plane intersection, a reflectivity step."""
INFORMATION_UNITS = (0.01, np.radians(0.1))
"""Steps (m, rad) in which the observability test measures translation and rotation: 1 cm and 0.1 deg."""
MIN_SPREAD_PAIRS = 3
"""With this many pairs or more the jackknife also leaves out pairs."""


@dataclass
class LidarCameraEdgesSettings:
    """How to find edges and align them. Lengths in metres and pixels, angles in degrees."""

    planes: PlaneEdgeSettings = field(default_factory=PlaneEdgeSettings)
    """Plane-intersection (depth-continuous) LiDAR edges."""
    reflectivity: ReflectivityEdgeSettings | None = field(default_factory=ReflectivityEdgeSettings)
    """Reflectivity LiDAR edges, for clouds with intensities (a 4th column); None to use plane edges only."""
    image: ImageEdgeSettings = field(default_factory=ImageEdgeSettings)
    """Canny image edges."""
    edge_spacing_m: float = 0.05
    """LiDAR edge points are thinned to one per cube of this side (m), so that every stretch of edge weighs by
    its length and a dense patch of edges (a printed pattern, foliage) cannot outweigh the scene's lines."""
    max_range_m: float = 50.0
    """LiDAR points further than this from the LiDAR are not used (m): their edges are imprecise."""
    view_margin_deg: float = 8.0
    """The cloud is cut to the camera's view at ``T_init`` widened by this (deg): more than its rotation error."""
    coarse: CoarseSearchSettings = field(default_factory=CoarseSearchSettings)
    """The coarse grid searches (:mod:`backend.solvers.edge_search`): their first grid must cover the initial
    guess's rotation error."""
    fine: FineAlignmentSettings = field(default_factory=FineAlignmentSettings)
    """The fine point-to-line least squares (:mod:`backend.solvers.edge_alignment`)."""
    min_lidar_edge_points: int = 100
    """Fewest LiDAR edge points of a pair in the camera's view at ``T_init``."""
    min_image_edge_pixels: int = 500
    """Fewest edge pixels of a pair's image."""
    min_matched: int = 100
    """Fewest matched edge points over all pairs in the first fine round."""
    min_information: float = 0.01
    """Smallest allowed eigenvalue of ``S J^T J S / M`` in the first fine round (``S``: the
    :data:`INFORMATION_UNITS`, 1 cm and 0.1 deg; ``M``: the matches): the mean squared move (px^2) of a matched
    point across its image line when the parameters step one unit along their worst-determined combination.
    Below it (0.1 px rms) the edges leave that combination unobservable: edges that all run one way give about
    0.005 (the line directions fitted to Canny pixels are off by a few degrees), a varied scene 0.05 or more."""
    max_rms_px: float = 2.0
    """A solution whose rms point-to-line distance exceeds this (px) is a poor fit: ``converged=False``."""
    spread: bool = True
    """Widen the sigmas to the jackknife spread (:func:`_spread`)."""
    spread_cell_px: float = 160.0
    """Side of the image squares (px) whose matched edge points the jackknife leaves out together: one edge or
    a good part of one."""
    spread_groups: int = 10
    """Groups the jackknife deals the squares into."""


@dataclass
class EdgeObservation:
    """One image and the cloud taken at the same moment."""

    image: np.ndarray
    """(H, W) gray or (H, W, 3) BGR uint8 image, at the size the intrinsics are for."""
    points_lidar: np.ndarray
    """(N, 3) LiDAR points in the LiDAR frame (m), or (N, 4) with the return intensity (any units) as the 4th
    column, which adds reflectivity edges; further columns are ignored."""
    name: str = ""
    """How errors name this pair (e.g. ``"frame0.png:frame0.pcd"``); ``"pair i"`` when empty."""


@dataclass
class LidarEdges:
    """A cloud's edge points in the LiDAR frame; row ``i`` of each array is one point."""

    points: np.ndarray
    """(N, 3) edge points (m)."""
    directions: np.ndarray
    """(N, 3) unit direction of the edge through each point; NaN where unknown (reflectivity edges)."""
    kind: np.ndarray
    """(N,) :data:`PLANE` or :data:`REFLECTIVITY`."""

    def __len__(self) -> int:
        return len(self.points)


@dataclass
class PairResiduals:
    """One pair's edges and fit at the solution."""

    name: str
    lidar_edge_points: int
    """LiDAR edge points the camera sees at the solution."""
    plane_edge_points: int
    """Of the LiDAR edge points found in the view at ``T_init``, those on plane intersections."""
    reflectivity_edge_points: int
    """Those on reflectivity steps."""
    image_edge_pixels: int
    matched: int
    """LiDAR edge points matched to an image line at the solution."""
    rms_px: float | None
    """RMS point-to-line distance of the matched points (px); None without matches."""

    def to_record(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class LidarCameraEdgesResult(SolveResult):
    kind = "lidar_camera"
    method = "edges"

    T_camera_lidar: np.ndarray
    """4x4, maps LiDAR points into the camera's optical frame (m)."""
    covariance: np.ndarray
    """6x6 over :data:`~backend.solvers.result.TRANSFORM_PARAMETERS` (translation in camera axes, rotation
    about the LiDAR's axes): the reported (larger-per-parameter) sigmas with the Jacobian's correlations."""
    residuals: dict[str, Any]
    """``edge_rms_px``, ``edge_median_px``, ``edge_p95_px`` (absolute point-to-line distances of the matched
    points, px), ``lidar_edge_points`` (in view at the solution), ``image_edge_pixels``, ``matched`` (all pairs)
    and ``per_pair_rms_px``."""
    pairs: list[PairResiduals]
    """The pairs, in input order."""
    settings: LidarCameraEdgesSettings
    converged: bool
    """False when the solve failed or fits poorly: do not accept this result."""
    seconds: float
    T_init: np.ndarray
    T_coarse: np.ndarray
    """The grid search's estimate, where the fine stage started."""
    std_jacobian: np.ndarray
    """(6,) 1-sigma from ``sigma^2 (J^T J)^-1`` (m, m, m, rad, rad, rad); NaN where undetermined."""
    std_spread: np.ndarray | None
    """(6,) 1-sigma of the jackknife, or None when not computed."""
    spread_source: str | None
    """What the jackknife left out: "edge groups" or "edge groups and pairs"."""
    iterations: int
    """Residual evaluations of :func:`scipy.optimize.least_squares` over all fine rounds."""
    rounds: int
    """Fine association + solve rounds run."""
    warnings: list[str] = field(default_factory=list)

    @property
    def std(self) -> dict[str, list[float | None]]:
        """Reported 1-sigma: ``trans_m`` (m, camera axes), ``rot_deg`` (deg, about the LiDAR's axes)."""
        return transform_std(self.covariance)

    def summary(self) -> dict[str, Any]:
        return {"T_camera_lidar": self.T_camera_lidar.tolist(), "std": self.std, "residuals": dict(self.residuals),
                "seconds": self.seconds}

    def to_record(self) -> dict[str, Any]:
        record = self.summary()
        record.update(
            kind=self.kind,
            method=self.method,
            **transform_record_fields(self.covariance, self.settings, self.converged, self.warnings),
            std_jacobian=finite_or_none(self.std_jacobian),
            std_spread=finite_or_none(self.std_spread),
            spread_source=self.spread_source,
            T_init=self.T_init.tolist(),
            T_coarse=self.T_coarse.tolist(),
            iterations=self.iterations,
            rounds=self.rounds,
            pairs=[p.to_record() for p in self.pairs],
        )
        return record


# ---------------------------------------------------------------- edges of each pair


@dataclass
class _Pair:
    name: str
    lidar: LidarEdges
    image: ImageEdges


def in_view(points_lidar: np.ndarray, T_camera_lidar: np.ndarray, camera: CameraIntrinsics, margin_deg: float,
            max_range_m: float) -> np.ndarray:
    """(N,) bool: which (N, 3) LiDAR points (m) are within ``max_range_m`` of the LiDAR and within the cone of
    ``camera``'s image corners widened by ``margin_deg`` at ``T_camera_lidar``."""
    points_camera = transform_points(T_camera_lidar, points_lidar)
    x, y, z = points_camera.T
    cone = np.tan(min(np.arctan(visible_radius(camera)) + np.radians(margin_deg), np.radians(89.0)))
    near = np.einsum("ij,ij->i", points_lidar, points_lidar) <= max_range_m**2
    return near & (z > MIN_DEPTH_M) & (x * x + y * y <= (cone * z) ** 2)


def find_lidar_edges(points_lidar: np.ndarray, intensity: np.ndarray | None, settings: LidarCameraEdgesSettings
                     ) -> LidarEdges:
    """Plane-intersection and (with ``intensity`` and ``settings.reflectivity``) reflectivity edges of an (N, 3)
    cloud (m, LiDAR frame; ``intensity`` (N,) in any units), thinned to one per ``settings.edge_spacing_m``."""
    planes = find_plane_edges(points_lidar, settings.planes)
    if intensity is None or settings.reflectivity is None:
        reflectivity = np.zeros((0, 3))
    else:
        reflectivity = find_reflectivity_edges(points_lidar, intensity, settings.reflectivity)
    points = np.vstack([planes.points, reflectivity])
    # One point per cell: a dense patch of edges (a printed pattern) would otherwise outweigh the scene's lines.
    _, first = np.unique(np.floor(points / settings.edge_spacing_m).astype(np.int64), axis=0, return_index=True)
    first = np.sort(first)
    return LidarEdges(points[first], np.vstack([planes.directions, np.full(reflectivity.shape, np.nan)])[first],
                      np.repeat([PLANE, REFLECTIVITY], [len(planes), len(reflectivity)])[first])


def _prepare(observation: EdgeObservation, name: str, camera: CameraIntrinsics, T_init: np.ndarray,
             settings: LidarCameraEdgesSettings) -> _Pair:
    """One pair's edges, refusing a pair whose image or cloud is unusable or has too few edges."""
    image = np.asarray(observation.image)
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise InputError(f"expected a uint8 gray (H, W) or BGR (H, W, 3) image, got {image.dtype} of shape "
                         f"{image.shape}", f"{name}: image")
    height, width = image.shape[:2]
    if (width, height) != camera.image_size:
        raise InputError(f"the image is {width}x{height} px but the camera's intrinsics are for "
                         f"{camera.width}x{camera.height}", f"{name}: image")
    edges = find_image_edges(image, settings.image)
    if len(edges) < settings.min_image_edge_pixels:
        raise InputError(
            f"too few edges: the image has {len(edges)} edge pixels (Canny {settings.image.canny_low:g}/"
            f"{settings.image.canny_high:g} in chains of {settings.image.min_chain_px} px or more); at least "
            f"{settings.min_image_edge_pixels} are needed - is it blank, blurred or over-exposed?", f"{name}: image")
    raw = np.asarray(observation.points_lidar, dtype=float)
    points, _ = check_cloud(raw, f"{name}: cloud")
    finite = np.isfinite(raw[:, :3]).all(axis=1)
    intensity = raw[finite, 3] if raw.shape[1] > 3 else None
    seen = in_view(points, T_init, camera, settings.view_margin_deg, settings.max_range_m)
    lidar = find_lidar_edges(points[seen], None if intensity is None else intensity[seen], settings)
    in_image = len(project_cloud(lidar.points, T_init, camera))
    if in_image < settings.min_lidar_edge_points:
        raise InputError(
            f"too few edges: {in_image} LiDAR edge points ({np.count_nonzero(lidar.kind == PLANE)} on plane "
            f"intersections at {settings.planes.min_angle_deg:g}-{settings.planes.max_angle_deg:g} deg, "
            f"{np.count_nonzero(lidar.kind == REFLECTIVITY)} on reflectivity steps) project into the image at "
            f"T_init among {np.count_nonzero(seen)} points within {settings.max_range_m:g} m in view; at least "
            f"{settings.min_lidar_edge_points} are needed - the cloud needs faces meeting at an angle (boxes, "
            "walls, building corners) seen densely, or painted markings in a scan with intensities",
            f"{name}: cloud")
    return _Pair(name, lidar, edges)


# ---------------------------------------------------------------- fine alignment


def _match_all(pairs: list[_Pair], T: np.ndarray, camera: CameraIntrinsics, radius_px: float,
               settings: FineAlignmentSettings) -> tuple[EdgeMatches, list[int]]:
    """Matches of all pairs at ``T``, stacked, and each pair's count of LiDAR edge points in view."""
    found = [match_edges(pair.lidar.points, pair.lidar.directions, pair.image, T, camera, radius_px, settings, i)
             for i, pair in enumerate(pairs)]
    return EdgeMatches.stack([matches for matches, _ in found]), [seen for _, seen in found]


def _check_observable(T: np.ndarray, matches: EdgeMatches, camera: CameraIntrinsics,
                      settings: LidarCameraEdgesSettings, names: list[str]) -> None:
    """Raise :class:`InputError` when the matched edges leave a combination of the parameters unobservable.

    The test is on ``S J^T J S / M`` (``S``: :data:`INFORMATION_UNITS`, ``M`` matches): the mean squared change
    of a matched point's residual (px^2) when the parameters move one unit along a direction, i.e. the geometry
    of the edges rather than their number (which ``min_matched`` tests). With a translation prior the translation
    is held by it, and only the rotation block is tested.
    """
    J = matches.jacobian(T, np.zeros(6), camera) * np.repeat(INFORMATION_UNITS, 3)
    tested = slice(3, 6) if settings.fine.translation_prior_m is not None else slice(0, 6)
    eigenvalues, eigenvectors = np.linalg.eigh((J.T @ J)[tested, tested] / len(matches))
    if eigenvalues[0] < settings.min_information:
        weakest = np.zeros(6)
        weakest[tested] = eigenvectors[:, 0]
        combination = " + ".join(f"{weakest[i]:.2f} {name.rsplit('_', 1)[0]}" for i, name in
                                 enumerate(TRANSFORM_PARAMETERS) if abs(weakest[i]) >= 0.2)
        raise InputError(
            f"too few edges: the matched edges leave {combination} unobservable (t in steps of 1 cm along the "
            f"camera's axes, r in steps of 0.1 deg about the LiDAR's): such a step moves a matched edge point by "
            f"{np.sqrt(max(eigenvalues[0], 0)):.2g} px rms, below {np.sqrt(settings.min_information):.2g} px. Edges "
            "that all run one way (all vertical, say) fix nothing along them - add pairs with edges in other "
            "directions", ", ".join(names))


def _spread(T: np.ndarray, matches: EdgeMatches, camera: CameraIntrinsics, n_pairs: int, t_prior: np.ndarray,
            settings: LidarCameraEdgesSettings, progress: ProgressCallback) -> tuple[np.ndarray | None, str | None]:
    """Jackknife std (6,) of re-solves at fixed matches (:func:`~backend.solvers.result.jackknife_std`), and what
    was left out: groups of edges and, with :data:`MIN_SPREAD_PAIRS` pairs or more, pairs; the larger per parameter.

    The edge groups: each pair's image is cut into :attr:`~LidarCameraEdgesSettings.spread_cell_px` squares,
    dealt at random into :attr:`~LidarCameraEdgesSettings.spread_groups` groups, and a group's matches are left
    out together, since the points of one edge share the errors of its plane fits and of its image edge. A pair's
    image and cloud share their timing and lighting.
    """
    uv = camera.project(transform_points(T, matches.points))
    cells = np.column_stack([matches.pair, np.floor(uv / settings.spread_cell_px)]).astype(np.int64)
    _, cell = np.unique(cells, axis=0, return_inverse=True)
    deal = np.random.default_rng(0).permutation(int(cell.max()) + 1) % settings.spread_groups
    units = {"edge groups": deal[cell.ravel()]}
    if n_pairs >= MIN_SPREAD_PAIRS:
        units["pairs"] = matches.pair
    spreads = []
    for source, unit in units.items():
        left_out = np.unique(unit)
        if len(left_out) < 3:
            continue
        estimates = []
        for k, group in enumerate(left_out):
            progress(0.85 + 0.15 * k / len(left_out), f"spread: solving without one of {len(left_out)} {source}")
            estimates.append(solve_matches(T, matches.subset(unit != group), camera, settings.fine,
                                           settings.fine.loss_scale_px, t_prior).x)
        spreads.append(jackknife_std(np.array(estimates)))
    if not spreads:
        return None, None
    return np.max(spreads, axis=0), " and ".join(units)


# ---------------------------------------------------------------- the solve


def _rms(values: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(values**2))) if len(values) else None


def _statistics(T: np.ndarray, matches: EdgeMatches, pairs: list[_Pair], in_view_counts: list[int],
                camera: CameraIntrinsics) -> tuple[dict[str, Any], list[PairResiduals]]:
    """The ``residuals`` dict of :class:`LidarCameraEdgesResult` and each pair's fit at ``T`` (None without matches)."""
    d = np.abs(matches.residuals(T, camera))
    per_pair = [PairResiduals(pair.name, seen, int(np.count_nonzero(pair.lidar.kind == PLANE)),
                              int(np.count_nonzero(pair.lidar.kind == REFLECTIVITY)), len(pair.image),
                              int(np.count_nonzero(matches.pair == i)), _rms(d[matches.pair == i]))
                for i, (pair, seen) in enumerate(zip(pairs, in_view_counts, strict=True))]
    median, p95 = np.percentile(d, [50, 95]) if len(d) else (None, None)
    residuals = {
        "edge_rms_px": _rms(d),
        "edge_median_px": None if median is None else float(median),
        "edge_p95_px": None if p95 is None else float(p95),
        "lidar_edge_points": int(sum(in_view_counts)),
        "image_edge_pixels": int(sum(len(p.image) for p in pairs)),
        "matched": len(d),
        "per_pair_rms_px": [p.rms_px for p in per_pair],
    }
    return residuals, per_pair


def solve_edges(camera: CameraIntrinsics, pairs: Sequence[EdgeObservation], T_init: np.ndarray,
                settings: LidarCameraEdgesSettings | None = None,
                progress: ProgressCallback = no_progress) -> LidarCameraEdgesResult:
    """Estimate ``T_camera_lidar`` (maps LiDAR points into the camera's optical frame, m) from edges.

    ``pairs`` are images and clouds taken at the same moments (any number; the robot may move between
    them); ``T_init`` is the initial ``T_camera_lidar``, within the coarse search's reach of the truth
    (:class:`~backend.solvers.edge_search.CoarseSearchSettings`: 6 deg per axis and about 10 cm). Raises
    :class:`InputError` for no pairs, a bad image, cloud or transform, too few LiDAR edge points or image
    edge pixels in a pair (named), too few matches, or edges that leave a motion unobservable. A solve
    whose least squares fails or whose rms distance exceeds ``settings.max_rms_px`` is returned with
    ``converged=False`` and a warning.
    """
    settings = settings or LidarCameraEdgesSettings()
    started = time.perf_counter()
    if not pairs:
        raise InputError("no image and cloud pairs given; at least one is needed", "pairs")
    T_init, _ = check_transform(T_init, "T_init")
    names = [o.name or f"pair {i + 1}" for i, o in enumerate(pairs)]
    prepared = []
    for i, (observation, name) in enumerate(zip(pairs, names, strict=True)):
        progress(0.1 * i / len(pairs), f"finding edges in {name}")
        prepared.append(_prepare(observation, name, camera, T_init, settings))

    T_coarse, warnings = coarse_search(T_init, [p.lidar.points for p in prepared],
                                       [p.image.distance_px for p in prepared], camera, settings.coarse,
                                       lambda fraction, message: progress(0.1 + 0.4 * fraction, message))
    fine, t_prior = settings.fine, T_init[:3, 3]
    T, result, iterations, converged = T_coarse, None, 0, True
    for round_index in range(fine.max_rounds):
        progress(0.5 + 0.35 * round_index / fine.max_rounds, f"fine alignment: round {round_index + 1}")
        radius = fine.match_radius_px[min(round_index, len(fine.match_radius_px) - 1)]
        matches, _ = _match_all(prepared, T, camera, radius, fine)
        if round_index == 0:
            if len(matches) < settings.min_matched:
                counts = ", ".join(f"{name}: {np.count_nonzero(matches.pair == i)}" for i, name in enumerate(names))
                raise InputError(
                    f"too few edges: {len(matches)} LiDAR edge points match an image edge line within {radius:g} px "
                    f"after the coarse search ({counts}); at least {settings.min_matched} are needed - the two "
                    "sensors may not see the same edges, or the initial guess is too far off", ", ".join(names))
            _check_observable(T, matches, camera, settings, names)
        result = solve_matches(T, matches, camera, fine, max(fine.loss_scale_px, fine.loss_scale_share * radius),
                               t_prior)
        iterations += int(result.nfev)
        T = apply_params(T, result.x)
        if result.status <= 0:
            warnings.append(f"fine round {round_index + 1}: least squares stopped without converging "
                            f"({result.message}); not accepted")
            converged = False
            break
        if round_index + 1 >= len(fine.match_radius_px) and (
                np.linalg.norm(result.x[:3]) < fine.step_tolerance[0]
                and np.degrees(np.linalg.norm(result.x[3:])) < fine.step_tolerance[1]):
            break

    assert result is not None  # max_rounds >= 1
    # The covariance is taken at the last linearisation, about the final estimate (the last step is tiny).
    cov_j = jacobian_covariance(result)
    matches, in_view_counts = _match_all(prepared, T, camera, fine.match_radius_px[-1], fine)
    residuals, per_pair = _statistics(T, matches, prepared, in_view_counts, camera)
    rms = residuals["edge_rms_px"]
    if rms is None or rms > settings.max_rms_px:
        warnings.append(f"poor fit: rms edge distance {'undefined (no matches)' if rms is None else f'{rms:.2f} px'} "
                        f"> {settings.max_rms_px:g} px; not accepted")
        converged = False
    std_spread, spread_source = None, None
    if settings.spread and converged:
        std_spread, spread_source = _spread(T, matches, camera, len(prepared), t_prior, settings, progress)
    progress(1.0, "done")
    return LidarCameraEdgesResult(
        T_camera_lidar=T,
        covariance=widen_covariance(cov_j, std_spread),
        residuals=residuals,
        pairs=per_pair,
        settings=settings,
        converged=converged,
        seconds=time.perf_counter() - started,
        T_init=T_init,
        T_coarse=T_coarse,
        std_jacobian=np.sqrt(np.clip(np.diag(cov_j), 0, None)),
        std_spread=std_spread,
        spread_source=spread_source,
        iterations=iterations,
        rounds=round_index + 1,
        warnings=warnings,
    )
