"""Targetless LiDAR-to-camera extrinsic calibration from edges (after Yuan et al. 2021): ``T_camera_lidar``.

"Pixel-level extrinsic self calibration of high resolution LiDAR and camera in targetless
environments" aligns the edges a LiDAR sees with those a camera sees in ordinary scenes.
Each image + cloud pair taken at one moment (the robot may move between pairs; the sensors
are rigid on it) is one :class:`EdgeObservation`. Pipeline:

1. LiDAR edges, per pair, from the points the camera may see at ``T_init`` (its view widened by
   :attr:`LidarCameraEdgesSettings.view_margin_deg`, within ``max_range_m``): plane
   intersections (depth-continuous edges, :mod:`backend.calib.lidar_camera.plane_edges`), as in the
   paper, and, when the cloud has intensities and scan lines, reflectivity steps along the scan
   lines (:mod:`backend.calib.lidar_camera.reflectivity_edges`; not in the paper), which carry single
   spinning-LiDAR frames of roads where few faces meet; thinned to one point per
   :attr:`~LidarCameraEdgesSettings.edge_spacing_m`, without the reflectivity edges of printed patterns
   (:func:`in_texture`: a checkerboard fits again shifted by a square). Depth *discontinuities* are not used: the
   beam footprint swells the foreground, as the paper shows.
2. Image edges, per pair: Canny pixels, their KD-tree and distance transform
   (:mod:`backend.calib.lidar_camera.image_edges`).
3. Coarse (:mod:`backend.calib.lidar_camera.edge_search`): a grid of rotations about ``T_init``, then joint
   pattern searches over rotation and (pivoted) translation, coarse to fine, maximising over all
   pairs the number of projected LiDAR edge points near an image edge (a triangular kernel on the
   distance transform, as wide as the search step is in pixels).
4. Fine (:mod:`backend.calib.lidar_camera.edge_alignment`): robust least squares of the distance (px) of each
   projected LiDAR edge point to the line fitted to its nearest image edge pixels, jointly over all
   pairs, re-matching each round with a shrinking match radius; analytic Jacobian. Its pixel lengths are
   scaled to the camera's focal length (:func:`scaled_to`): the LiDAR's errors are angles.
5. Uncertainty: ``sigma^2 (J^T J)^-1`` at the solution
   (:func:`~backend.core.result.jacobian_covariance`), widened per parameter to the jackknife
   spread (:func:`~backend.core.result.widen_covariance`) over groups of edges (the points of
   an edge share the errors of its plane fits and of its image edge, which per-point noise cannot
   see) and, with pairs from three places or more, over places. With two places or more, the pairs of the places of
   even and of odd index are also re-solved apart (:func:`_halves`): the verdict's cross-check between independent
   captures. Pairs taken in one place (:mod:`~backend.calib.lidar_camera.places`: the rig stood still while a board
   or a person moved) share that scene's edges and their errors, so they are one unit of both.
6. Multi-start: the coarse search keeps its best distinct results
   (:attr:`~backend.calib.lidar_camera.edge_search.CoarseSearchSettings.candidates`), each is aligned finely,
   and the one with the most matched edge points at the final radius is the solution. Another
   that is a distinct alignment yet fits about as well (:func:`_competes`: a repeating pattern in
   view, or edges too few to tell) widens the sigmas to cover it (the multi-start spread,
   :func:`_multistart`) with a warning, or, when it is further off than
   :attr:`LidarCameraEdgesSettings.max_ambiguity`, makes the result ambiguous (``converged=False``).
   All are kept in the result's ``diagnostics["candidates"]``.

A scene with too few edges is refused with an :class:`InputError` naming the pair and what is
lacking (LiDAR edge points, image edge pixels, matches), as is a set of edges that leaves a
motion unobservable (all edges parallel: the smallest eigenvalue of the scaled ``J^T J``). A
solve that ends with a poor fit is returned with ``converged=False`` and a warning.

Parameters, covariance and sigmas follow :func:`backend.core.transforms.params_between`:
``[t_x, t_y, t_z]`` (m, along the camera's optical axes) and ``[r_x, r_y, r_z]`` (rad; reported in deg)
of a right perturbation ``R @ rotvec(r)``, i.e. about the LiDAR's axes, as ``conventions.md`` asks.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import numpy as np
from scipy.optimize import OptimizeResult
from scipy.spatial import cKDTree

from backend.calib.lidar_camera.edge_alignment import EdgeMatches, FineAlignmentSettings, match_edges, solve_matches
from backend.calib.lidar_camera.edge_search import CoarseSearchSettings, coarse_search
from backend.calib.lidar_camera.held_translation import (
    AMBIGUOUS,
    HELD_PRIOR_M,
    held_covariance,
    mark_held,
    translation_undetermined,
)
from backend.calib.lidar_camera.image_edges import ImageEdges, ImageEdgeSettings, find_image_edges
from backend.calib.lidar_camera.places import named_places, place_of_pairs
from backend.calib.lidar_camera.plane_edges import PlaneEdgeSettings, find_plane_edges
from backend.calib.lidar_camera.reflectivity_edges import ReflectivityEdgeSettings, find_reflectivity_edges
from backend.core.camera import CameraIntrinsics, check_camera_image
from backend.core.camera_inverse import visible_radius
from backend.core.clouds import check_cloud
from backend.core.errors import InputError
from backend.core.projection import MIN_DEPTH_M, project_cloud
from backend.core.result import (
    TRANSFORM_PARAMETERS,
    ProgressCallback,
    TransformResult,
    finite_or_none,
    jackknife_std,
    jacobian_covariance,
    no_progress,
    widen_covariance,
)
from backend.core.transforms import apply_params, check_transform, params_between, transform_points
from backend.core.uncertainty import sigmas

PLANE, REFLECTIVITY = 0, 1
"""Values of :attr:`LidarEdges.kind`: a plane intersection, a reflectivity step."""
INFORMATION_UNITS = (0.01, np.radians(0.1))
"""Steps (m, rad) in which the observability test measures translation and rotation: 1 cm and 0.1 deg."""
MIN_SPREAD_PLACES = 3
"""With pairs from this many places or more the jackknife also leaves out places."""
MIN_HALVES_PLACES = 2
"""With pairs from this many places or more the places are split into two halves solved apart (the cross-check)."""
AMBIGUOUS_ADVICE = " (a repeating pattern in view, or edges all far away that leave the translation free); not accepted"


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
    texture_radius_m: float = 0.4
    """Radius (m) of the ball in which :func:`in_texture` counts reflectivity edge points."""
    texture_max_lines: float = 2.0
    """Reflectivity edge points with more neighbours in that ball than this many straight edges through it would
    leave (:func:`in_texture`) are dropped as a printed pattern (a checkerboard) or texture: a periodic print fits
    again when shifted by one period, and its many edge points pull the search to a shifted copy. With the
    defaults the limit is 32: the 66 points a 0.1 deg, 128-beam scan leaves on the demo checkerboard at 2.6 m have
    61-66 each, the road markings of the OpenCalib frame at most 8."""
    max_range_m: float = 50.0
    """LiDAR points further than this from the LiDAR are not used (m): their edges are imprecise."""
    view_margin_deg: float = 8.0
    """The cloud is cut to the camera's view at ``T_init`` widened by this (deg): more than its rotation error."""
    coarse: CoarseSearchSettings = field(default_factory=CoarseSearchSettings)
    """The coarse grid searches (:mod:`backend.calib.lidar_camera.edge_search`): their first grid must cover the initial
    guess's rotation error."""
    fine: FineAlignmentSettings = field(default_factory=FineAlignmentSettings)
    """The fine point-to-line least squares (:mod:`backend.calib.lidar_camera.edge_alignment`)."""
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
    focal_px: float = 1000.0
    """The fine alignment's pixel lengths (its match radii and loss scale, and ``max_rms_px``) are for a camera of
    this focal length (px); on a longer one they are scaled by ``f / focal_px`` (:func:`scaled_to`), since the
    LiDAR's own errors are angular: a 0.2 deg azimuth step is 3.5 px at f = 1000 px and 7.4 px at the OpenCalib
    camera's 2117 px, where a 3 px final radius drops about half of the true matches and the fits of the
    remaining ~100 wander along the yaw-translation ridge (0.2-0.5 deg apart between starts)."""
    spread: bool = True
    """Widen the sigmas to the jackknife spread (:func:`_spread`)."""
    spread_cell_px: float = 160.0
    """Side of the image squares (px) whose matched edge points the jackknife leaves out together: one edge or
    a good part of one."""
    spread_groups: int = 10
    """Groups the jackknife deals the squares into."""
    distinct_sigmas: float = 3.0
    """Another start's solution is another alignment when it differs from the best by more than this many of the
    best's sigmas (Jacobian and jackknife) in some parameter; nearer, it is the same one found twice."""
    tie_z: float = 2.0
    """Another alignment fits about as well as the best, and competes with it, when its count of matches at the
    final radius ``M`` is within this many standard deviations of the best's ``M_best``:
    ``M_best - M <= tie_z sqrt(M_best + M)``, the spread of the difference of two independent (Poisson) counts of
    those sizes. The matches along one edge come and go together, so the real spread is larger: the test errs
    toward calling an alignment a competitor, i.e. toward the wider sigmas."""
    probe_deg: float | None = 0.5
    """The fine alignment also starts from the best coarse start's solution turned by this (deg) either way about
    each LiDAR axis, to find alignments nearer than the coarse search's starts are apart (the finer peaks of a
    repeating pattern, a flat optimum of few edges); None for none."""
    guess_translation_sigma_m: float | None = 0.05
    """1-sigma (m, per axis) of the initial guess's translation: a tape measure's. When no translation prior is given
    and the scene cannot determine the translation (alignments far apart fit about equally well: edges all far away, a
    repeating pattern; or the edges pin it less well than this), the rotation is solved with the translation held at
    the guess, which is reported with this sigma (:mod:`~backend.calib.lidar_camera.held_translation`); None leaves
    such a result ambiguous (not converged). Edges that all run one way are refused either way: they leave the rotation
    loose as well."""
    max_ambiguity: tuple[float, float] = (0.05, 0.5)
    """Competing alignments further from the best than this on some parameter (m, deg) make the result ambiguous:
    ``converged=False``. Nearer, the sigmas are widened to cover them (the multi-start spread). These are the
    coarse search's first translation step and its middle rotation step: alignments that far apart are separate
    peaks of the score (a pattern's shifted copies), of which the starts find some and not others, so that sigmas
    widened to the ones found need not reach the truth (with the demo checkerboard's print kept: competitors found
    up to 76 mm away, the truth 52 mm and 0.4 deg from the solution and 3.3 of those sigmas off in t_z)."""


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
class CandidateFit:
    """The fine alignment from one start of the coarse search, on the measure all are compared by."""

    T_start: np.ndarray
    """4x4, where the fine alignment started: a result of the coarse search, or a probe about the first one's
    solution (:attr:`~LidarCameraEdgesSettings.probe_deg`)."""
    T_camera_lidar: np.ndarray
    """4x4, where the fine alignment ended."""
    matched: int
    """LiDAR edge points matched to an image line within the final match radius at ``T_camera_lidar``: the
    measure the starts are compared by."""
    rms_px: float | None
    """RMS point-to-line distance of those matches (px)."""
    converged: bool
    offset: np.ndarray
    """(6,) ``T_camera_lidar`` about the solution's, in the result's parameters (m, camera axes; rad, LiDAR axes)."""
    competing: bool
    """Another alignment that fits about as well as the solution (:func:`_competes`)."""

    def to_record(self) -> dict[str, Any]:
        return {"T_start": self.T_start.tolist(), "T_camera_lidar": self.T_camera_lidar.tolist(),
                "matched": self.matched, "rms_px": self.rms_px, "converged": self.converged,
                "offset_m": finite_or_none(self.offset[:3]), "offset_deg": finite_or_none(np.degrees(self.offset[3:])),
                "competing": self.competing}


# ---------------------------------------------------------------- edges of each pair


@dataclass
class _Pair:
    name: str
    lidar: LidarEdges
    image: ImageEdges
    place: int = 0
    """Index of the place the pair was taken in (:func:`~backend.calib.lidar_camera.places.place_of_pairs`)."""


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
    cloud (m, LiDAR frame; ``intensity`` (N,) in any units), thinned to one per ``settings.edge_spacing_m``,
    without the reflectivity edges of printed patterns (:func:`in_texture`)."""
    planes = find_plane_edges(points_lidar, settings.planes)
    if intensity is None or settings.reflectivity is None:
        reflectivity = np.zeros((0, 3))
    else:
        reflectivity = find_reflectivity_edges(points_lidar, intensity, settings.reflectivity)
    points = np.vstack([planes.points, reflectivity])
    # One point per cell: a dense patch of edges (a printed pattern) would otherwise outweigh the scene's lines.
    _, first = np.unique(np.floor(points / settings.edge_spacing_m).astype(np.int64), axis=0, return_index=True)
    first = np.sort(first)
    edges = LidarEdges(points[first], np.vstack([planes.directions, np.full(reflectivity.shape, np.nan)])[first],
                       np.repeat([PLANE, REFLECTIVITY], [len(planes), len(reflectivity)])[first])
    keep = edges.kind == PLANE
    keep[~keep] = ~in_texture(edges.points[~keep], settings)
    return LidarEdges(edges.points[keep], edges.directions[keep], edges.kind[keep])


def in_texture(points: np.ndarray, settings: LidarCameraEdgesSettings) -> np.ndarray:
    """(N,) bool: which of the (N, 3) thinned reflectivity edge points (m) lie in a printed pattern or texture.

    Such a point has more of them within :attr:`~LidarCameraEdgesSettings.texture_radius_m` (``r``) than
    :attr:`~LidarCameraEdgesSettings.texture_max_lines` straight edges through the ball's centre would leave after
    thinning (``2 r / edge_spacing_m`` each): the edges fill an area instead of running along lines.
    """
    if len(points) == 0:
        return np.zeros(0, bool)
    radius = settings.texture_radius_m
    neighbours = cKDTree(points).query_ball_point(points, radius, return_length=True)
    return neighbours > settings.texture_max_lines * 2 * radius / settings.edge_spacing_m


def _prepare(observation: EdgeObservation, name: str, camera: CameraIntrinsics, T_init: np.ndarray,
             settings: LidarCameraEdgesSettings) -> _Pair:
    """One pair's edges, refusing a pair whose image or cloud is unusable or has too few edges."""
    image = check_camera_image(observation.image, camera, f"{name}: image")
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


def _spread(T: np.ndarray, matches: EdgeMatches, camera: CameraIntrinsics, place: np.ndarray, t_prior: np.ndarray,
            settings: LidarCameraEdgesSettings, progress: ProgressCallback) -> tuple[np.ndarray | None, str | None]:
    """Jackknife std (6,) of re-solves at fixed matches (:func:`~backend.core.result.jackknife_std`), and what
    was left out: groups of edges and, with pairs from :data:`MIN_SPREAD_PLACES` places or more (``place``: each
    pair's), places; the larger per parameter.

    The edge groups: the image is cut into :attr:`~LidarCameraEdgesSettings.spread_cell_px` squares, dealt at
    random into :attr:`~LidarCameraEdgesSettings.spread_groups` groups, and a group's matches are left out together,
    in all pairs at once, since the points of one edge share the errors of its plane fits and of its image edge,
    and pairs taken while the robot stood still (only a board moved, say) see the same edges in the same squares.
    When it moved, the groups are merely larger. A pair's image and cloud share their timing and lighting.
    """
    uv = camera.project(transform_points(T, matches.points))
    cells = np.floor(uv / settings.spread_cell_px).astype(np.int64)
    _, cell = np.unique(cells, axis=0, return_inverse=True)
    deal = np.random.default_rng(0).permutation(int(cell.max()) + 1) % settings.spread_groups
    units = {"edge groups": deal[cell.ravel()]}
    if place.max() + 1 >= MIN_SPREAD_PLACES:
        units["places"] = place[matches.pair]
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


def _halves(T: np.ndarray, matches: EdgeMatches, camera: CameraIntrinsics, place: np.ndarray, t_prior: np.ndarray,
            settings: LidarCameraEdgesSettings) -> np.ndarray | None:
    """(6,) the result's ``diagnostics["halves_offset"]``: the pairs of the places (``place``: each pair's) of even and
    of odd index re-solved apart at fixed matches from ``T``, the second's solution about the first's; None with
    pairs from fewer than :data:`MIN_HALVES_PLACES` places."""
    if place.max() + 1 < MIN_HALVES_PLACES:
        return None
    first = place[matches.pair] % 2 == 0
    solved = [apply_params(T, solve_matches(T, matches.subset(half), camera, settings.fine,
                                            settings.fine.loss_scale_px, t_prior).x) for half in (first, ~first)]
    return params_between(*solved)


@dataclass
class _Fine:
    """One fine alignment, from one start."""

    T_start: np.ndarray
    T: np.ndarray
    result: OptimizeResult
    """The last least-squares round's, linearised about (nearly) ``T``."""
    iterations: int
    rounds: int
    converged: bool
    warnings: list[str]
    matches: EdgeMatches
    """At ``T`` within the final match radius."""
    in_view_counts: list[int]
    rms_px: float | None


def _fine_align(pairs: list[_Pair], T_start: np.ndarray, camera: CameraIntrinsics, settings: LidarCameraEdgesSettings,
                t_prior: np.ndarray, names: list[str], progress: Callable[[float, str], None]) -> _Fine:
    """Match and solve in rounds of shrinking radius from ``T_start``; refuses (:class:`InputError`) too few first
    matches or unobservable edges; not converged when a least squares fails or the rms exceeds ``max_rms_px``."""
    fine = settings.fine
    T, result, iterations, converged, warnings = T_start, None, 0, True, []
    for round_index in range(fine.max_rounds):
        progress(round_index / fine.max_rounds, f"round {round_index + 1}")
        radius = fine.match_radius_px[min(round_index, len(fine.match_radius_px) - 1)]
        matches, _ = _match_all(pairs, T, camera, radius, fine)
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
    matches, in_view_counts = _match_all(pairs, T, camera, fine.match_radius_px[-1], fine)
    rms = _rms(matches.residuals(T, camera))
    if rms is None or rms > settings.max_rms_px:
        warnings.append(f"poor fit: rms edge distance {'undefined (no matches)' if rms is None else f'{rms:.2f} px'} "
                        f"> {settings.max_rms_px:g} px; not accepted")
        converged = False
    return _Fine(T_start, T, result, iterations, round_index + 1, converged, warnings, matches, in_view_counts, rms)


def _fine_from_starts(pairs: list[_Pair], starts: np.ndarray, camera: CameraIntrinsics,
                      settings: LidarCameraEdgesSettings, t_prior: np.ndarray, names: list[str],
                      progress: ProgressCallback) -> list[_Fine]:
    """The fine alignment from each of the (K, 4, 4) starts, best coarse score first, then from the first one's
    solution turned by :attr:`~LidarCameraEdgesSettings.probe_deg`. The first start's refusals stand; a later
    start refused (too few matches: too far off) is dropped."""
    probes = [] if settings.probe_deg is None else np.radians(settings.probe_deg) * np.vstack([np.eye(3), -np.eye(3)])
    total = len(starts) + len(probes)

    def fit(k: int, T_start: np.ndarray) -> _Fine:
        return _fine_align(pairs, T_start, camera, settings, t_prior, names, lambda fraction, message: progress(
            0.5 + 0.35 * (k + fraction) / total, f"fine alignment from start {k + 1} of {total}: {message}"))

    fits = [fit(0, starts[0])]
    later = list(starts[1:]) + [apply_params(fits[0].T, np.r_[np.zeros(3), turn]) for turn in probes]
    for k, T_start in enumerate(later, start=1):
        with contextlib.suppress(InputError):
            fits.append(fit(k, T_start))
    return fits


def _competes(best: _Fine, other: _Fine, offset: np.ndarray, std: np.ndarray,
              settings: LidarCameraEdgesSettings) -> bool:
    """Whether ``other``, ``offset`` (6,) from ``best`` (m, rad), is another alignment that fits about as well:
    further than :attr:`~LidarCameraEdgesSettings.distinct_sigmas` of the (6,) ``std`` on some parameter, and with
    as many matches within :attr:`~LidarCameraEdgesSettings.tie_z` (a converged one only)."""
    m_best, m_other = len(best.matches), len(other.matches)
    return bool(other.converged and np.any(np.abs(offset) > settings.distinct_sigmas * std)
                and m_best - m_other <= settings.tie_z * np.sqrt(m_best + m_other))


def _multistart(best: _Fine, fits: list[_Fine], std: np.ndarray, settings: LidarCameraEdgesSettings
                ) -> tuple[list[CandidateFit], np.ndarray | None, str | None]:
    """Each fit as a :class:`CandidateFit` about ``best``, the multi-start spread (6,) (m, rad; None without
    competitors) and a warning: "ambiguous" (not accepted) beyond ``max_ambiguity``, else the widening."""
    candidates = []
    for fit in [best] + [f for f in fits if f is not best]:
        offset = params_between(best.T, fit.T)
        candidates.append(CandidateFit(fit.T_start, fit.T, len(fit.matches), fit.rms_px, fit.converged, offset,
                                       fit is not best and _competes(best, fit, offset, std, settings)))
    competing = [c for c in candidates if c.competing]
    if not competing:
        return candidates, None, None
    spread = np.max(np.abs([c.offset for c in competing]), axis=0)
    counts = ", ".join(str(c.matched) for c in competing)
    described = (f"{len(competing) + 1} alignments fit about equally well ({len(best.matches)} matched edge points "
                 f"at the solution, {counts} at the others), up to {1000 * spread[:3].max():.0f} mm and "
                 f"{np.degrees(spread[3:].max()):.2f} deg apart")
    limit_m, limit_deg = settings.max_ambiguity
    if spread[:3].max() > limit_m or np.degrees(spread[3:].max()) > limit_deg:
        return candidates, spread, (f"{AMBIGUOUS}: {described}, beyond {1000 * limit_m:.0f} mm or {limit_deg:g} deg"
                                    f"{AMBIGUOUS_ADVICE}")
    return candidates, spread, f"multi-start spread: {described}; the sigmas are widened to cover them"


# ---------------------------------------------------------------- the solve


def _rms(values: np.ndarray) -> float | None:
    return float(np.sqrt(np.mean(values**2))) if len(values) else None


def _statistics(T: np.ndarray, matches: EdgeMatches, pairs: list[_Pair], in_view_counts: list[int],
                camera: CameraIntrinsics) -> tuple[dict[str, Any], list[PairResiduals]]:
    """The result's ``residuals`` and each pair's fit at ``T`` (None without matches)."""
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


def scaled_to(camera: CameraIntrinsics, settings: LidarCameraEdgesSettings) -> LidarCameraEdgesSettings:
    """``settings`` with the fine alignment's pixel lengths scaled to ``camera``'s focal length
    (:attr:`~LidarCameraEdgesSettings.focal_px`; never scaled down)."""
    scale = max(1.0, float(np.mean(np.diag(camera.K)[:2])) / settings.focal_px)
    fine = replace(settings.fine, match_radius_px=tuple(scale * r for r in settings.fine.match_radius_px),
                   loss_scale_px=scale * settings.fine.loss_scale_px)
    return replace(settings, fine=fine, max_rms_px=scale * settings.max_rms_px)


def solve_edges(camera: CameraIntrinsics, pairs: Sequence[EdgeObservation], T_init: np.ndarray,
                settings: LidarCameraEdgesSettings | None = None,
                progress: ProgressCallback = no_progress) -> TransformResult:
    """Estimate ``T_camera_lidar`` (maps LiDAR points into the camera's optical frame, m) from edges.

    ``pairs`` are images and clouds taken at the same moments (any number; the robot may move between
    them); ``T_init`` is the initial ``T_camera_lidar``, within the coarse search's reach of the truth
    (:class:`~backend.calib.lidar_camera.edge_search.CoarseSearchSettings`: 6 deg per axis and about 10 cm). Raises
    :class:`InputError` for no pairs, a bad image, cloud or transform, too few LiDAR edge points or image
    edge pixels in a pair (named), too few matches, or edges that leave a motion unobservable. A solve
    whose least squares fails, whose rms distance exceeds ``settings.max_rms_px`` or whose competing alignments
    lie further apart than ``settings.max_ambiguity`` is returned with ``converged=False`` and a warning.

    Returns a :class:`~backend.core.result.TransformResult` (kind ``lidar_camera``, method ``edges``, parent
    ``camera``, child ``lidar``): ``T_parent_child`` is ``T_camera_lidar``; its covariance (order
    :data:`~backend.core.result.TRANSFORM_PARAMETERS`) holds the reported (larger-per-parameter) sigmas with the
    Jacobian's correlations. ``residuals``: ``edge_rms_px``, ``edge_median_px``, ``edge_p95_px`` (absolute
    point-to-line distances of the matched points, px), ``lidar_edge_points`` (in view at the solution),
    ``image_edge_pixels``, ``matched`` (all pairs) and ``per_pair_rms_px``. ``diagnostics`` (6-vectors in m, m, m,
    rad, rad, rad; None where undetermined): ``std_jacobian`` (``sigma^2 (J^T J)^-1``), ``std_spread`` (the
    jackknife's, or None) and ``spread_source`` (what it left out: "edge groups" or "edge groups and places"),
    ``halves_offset`` (the solution from the places of even index about the one from the others, :func:`_halves`:
    the cross-check of two halves of the data; None with pairs from one place or when not converged), ``places``
    (the pairs' names grouped by the place they were taken in), ``std_multistart`` (per
    parameter the largest ``|offset|`` of a competing alignment; None when none competes), ``candidates`` (each
    start's :class:`CandidateFit`, the solution's first), ``T_init``, ``T_coarse`` (where the solution's fine
    alignment started), ``iterations`` (residual evaluations of its fine rounds), ``rounds`` and ``pairs`` (each
    pair's :class:`PairResiduals`, in input order).
    """
    settings = scaled_to(camera, settings or LidarCameraEdgesSettings())
    started = time.perf_counter()
    if not pairs:
        raise InputError("no image and cloud pairs given; at least one is needed", "pairs")
    T_init, _ = check_transform(T_init, "T_init")
    names = [o.name or f"pair {i + 1}" for i, o in enumerate(pairs)]
    prepared = []
    for i, (observation, name) in enumerate(zip(pairs, names, strict=True)):
        progress(0.1 * i / len(pairs), f"finding edges in {name}")
        prepared.append(_prepare(observation, name, camera, T_init, settings))
    for pair, place in zip(prepared, place_of_pairs([np.asarray(o.points_lidar) for o in pairs]), strict=True):
        pair.place = int(place)
    may_hold = settings.fine.translation_prior_m is None and settings.guess_translation_sigma_m is not None
    free_share = 0.6 if may_hold else 1.0
    result, _ = _solve_prepared(prepared, camera, T_init, settings, names,
                                lambda fraction, message: progress(0.1 + (free_share - 0.1) * fraction, message))
    why = (translation_undetermined(result, settings.guess_translation_sigma_m, "the edges", AMBIGUOUS_ADVICE)
           if may_hold else None)
    if why is not None:
        result = _solve_held(prepared, camera, T_init, settings, names, why,
                             lambda fraction, message: progress(0.6 + 0.4 * fraction,
                                                                f"translation held at the guess: {message}"))
    progress(1.0, "done")
    result.seconds = time.perf_counter() - started
    return result


def _solve_prepared(prepared: list[_Pair], camera: CameraIntrinsics, T_init: np.ndarray,
                    settings: LidarCameraEdgesSettings, names: list[str], progress: ProgressCallback
                    ) -> tuple[TransformResult, _Fine]:
    """The coarse search, the fine alignments from its starts, the uncertainty and the cross-check of the pairs'
    edges (progress from 0 to 1: the coarse search to 0.5, :func:`_fine_from_starts` and :func:`_spread` on); the
    result and the best fine alignment."""
    starts, warnings = coarse_search(T_init, [p.lidar.points for p in prepared],
                                     [p.image.distance_px for p in prepared], camera, settings.coarse,
                                     lambda fraction, message: progress(0.5 * fraction, message))
    t_prior = T_init[:3, 3]
    place = np.array([p.place for p in prepared])
    fits = _fine_from_starts(prepared, starts, camera, settings, t_prior, names, progress)
    best = max(fits, key=lambda f: (f.converged, len(f.matches), -(f.rms_px or np.inf)))
    # The covariance is taken at the last linearisation, about the final estimate (the last step is tiny).
    cov_j = jacobian_covariance(best.result)
    residuals, per_pair = _statistics(best.T, best.matches, prepared, best.in_view_counts, camera)
    converged, warnings = best.converged, warnings + best.warnings
    std_spread, spread_source = None, None
    if settings.spread and converged:
        std_spread, spread_source = _spread(best.T, best.matches, camera, place, t_prior, settings, progress)
    covariance = widen_covariance(cov_j, std_spread)
    candidates, std_multistart, warning = _multistart(best, fits, sigmas(covariance), settings)
    if warning is not None:
        warnings.append(warning)
        converged = converged and not warning.startswith(AMBIGUOUS)
    halves_offset = _halves(best.T, best.matches, camera, place, t_prior, settings) if converged else None
    result = TransformResult(
        kind="lidar_camera", method="edges", parent="camera", child="lidar",
        T_parent_child=best.T,
        covariance=widen_covariance(covariance, std_multistart),
        residuals=residuals,
        diagnostics={"std_jacobian": finite_or_none(sigmas(cov_j)),
                     "std_spread": finite_or_none(std_spread), "spread_source": spread_source,
                     "halves_offset": finite_or_none(halves_offset), "std_multistart": finite_or_none(std_multistart),
                     "candidates": [c.to_record() for c in candidates], "T_init": T_init.tolist(),
                     "T_coarse": best.T_start.tolist(), "iterations": best.iterations, "rounds": best.rounds,
                     "pairs": [p.to_record() for p in per_pair],
                     "places": named_places(place, names)},
        settings=asdict(settings),
        converged=converged,
        warnings=warnings,
    )
    return result, best


def _solve_held(prepared: list[_Pair], camera: CameraIntrinsics, T_init: np.ndarray,
                settings: LidarCameraEdgesSettings, names: list[str], why: str, progress: ProgressCallback
                ) -> TransformResult:
    """The rotation solved with the translation held at ``T_init``'s (:data:`HELD_PRIOR_M`), its covariance that of
    the guess's translation sigma (:func:`~backend.calib.lidar_camera.held_translation.held_covariance`), and ``why``
    the scene could not determine it in the warning and ``diagnostics["translation_held"]``."""
    sigma_m = settings.guess_translation_sigma_m
    assert sigma_m is not None  # only held when the guess has a sigma
    held = replace(settings, fine=replace(settings.fine, translation_prior_m=HELD_PRIOR_M),
                   coarse=replace(settings.coarse, max_translation_m=HELD_PRIOR_M))
    result, best = _solve_prepared(prepared, camera, T_init, held, names, progress)
    # The edges' information: the robust-loss Jacobian without the prior's three last rows, scaled by the residual
    # variance as jacobian_covariance does.
    J = best.result.jac[:-3]
    covariance, alone = held_covariance(J.T @ J / (2 * best.result.cost / max(len(J) - 6, 1)), sigma_m)
    result.covariance = widen_covariance(covariance, result.std_vector)
    mark_held(result, sigma_m, why, alone, "the edges",
              "Add pairs of other scenes, nearer edges in several directions, to determine it")
    return result
