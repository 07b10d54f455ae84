"""Targetless LiDAR-to-camera extrinsic calibration from LiDAR intensity against image grey values: ``T_camera_lidar``.

Where a LiDAR return is bright (lane paint, signs, light walls) the camera tends to see something bright or
dark too: the two are statistically dependent when the cloud is drawn at the right place, and less so when it
is drawn off. The solve maximises that dependence, as koide3's direct_visual_lidar_calibration does (its
``NIDCost`` and ``CostCalculatorNID``) after Pandey et al. 2012 ("Automatic targetless extrinsic calibration of a
3D lidar and camera by maximizing mutual information"). It needs no edges, so scenes whose depth edges are few or
far (a road) still calibrate. Each image + cloud pair taken at one moment is one :class:`IntensityObservation`;
several pairs are summed. Pipeline:

1. Per pair (:func:`_prepare`): the image in grey, histogram-equalised (as koide3), as float in [0, 1),
   Gaussian-blurred for the coarse and the fine stage; the cloud cut to the camera's view at ``T_init`` (its
   cone widened by :attr:`~LidarCameraIntensitySettings.view_margin_deg`, within ``max_range_m``), without the
   points a nearer surface hides at ``T_init`` (koide3's view culling; :func:`~backend.core.projection.project_cloud`
   with its block z-buffer), and its intensities rank-equalised to [0, 1) (as koide3).
2. Cost: the normalised information distance ``NID = (H(I, L) - MI) / H(I, L)`` (0: one determines the other,
   1: independent) between the image value ``I`` at each projected point (bilinear) and its intensity ``L``, from a
   :attr:`~LidarCameraIntensitySettings.bins`-square joint histogram with linear (two-bin) soft binning of both,
   so that the cost changes smoothly with the transform (koide3 smooths its image side with B-splines for BFGS).
   Pairs add as ``sum_i w_i NID_i`` with ``w_i = N_i H_i / n_i`` (:func:`_weight` gives ``N_i H_i``), which makes
   the sum a negative log-likelihood up to a constant: ``N H(I | L) = N (H(I, L) - H(L))`` is the image values'
   coding cost given the intensities, and near the optimum it moves as ``N H(I, L) NID`` (``H(L)`` is fixed).
   ``N_i`` counts the image cells of :attr:`~LidarCameraIntensitySettings.cell_px` with a point (points in one cell
   share their pixels' errors, so they are not independent); ``n_i`` the pairs taken in the pair's place
   (:mod:`~backend.calib.lidar_camera.places`: a rig standing still sees one scene, whose reflectors mislead every
   pair alike, so its pairs count once).
3. Coarse (:func:`_coarse`): a grid of rotations about ``T_init`` (``coarse_step_deg`` steps, ``coarse_steps``
   either way per axis) on the coarse-blurred image with every ``coarse_point_stride``-th point; the ``refined``
   best turned by a compass search; ``candidates`` well-separated starts from those (then from the raw grid). Near
   the truth the cost is a narrow cone (on the real road frame at 2117 px about 0.5 deg wide) beside broad wrong
   bowls, so each start is screened by a short Nelder-Mead run and only the ``fine_starts`` best go on.
4. Fine (:func:`_fine`): Nelder-Mead over all six parameters from each screened start on the fine-blurred image
   (as koide3's ``NID_NELDER_MEAD``), restarted once from its end with a smaller simplex; with a translation prior
   the objective adds ``0.5 |(t - t_init) / sigma|^2``; the search stays within the grid's reach (one step more)
   and ``max_translation_m`` of ``T_init``. The end that is lowest is the solution; another that ends within
   :attr:`~LidarCameraIntensitySettings.tie_nid` of it yet further than ``distinct`` away makes the result
   ambiguous (``converged=False``). Then ``restarts`` runs about the solution (their spread widens the sigmas).
5. Uncertainty (:func:`_curvature`): the cost sampled about the solution (along each axis at 1 and 2 steps, and
   across each pair of axes, 85 points with steps ``curvature_step``) and fitted with a quadratic; its Hessian is
   the Fisher information of the likelihood of step 2, ``cov = H^-1``. The samples also hold the joint histograms
   of :attr:`~LidarCameraIntensitySettings.spread_groups` groups of image squares (``spread_cell_px``, dealt at
   random) and of each pair; since histograms add, each leave-one-group-out (and, with three places or more,
   leave-one-place-out) cost is known at every sample too, so each subset's optimum is its own quadratic's, and
   their jackknife spread (:func:`~backend.core.result.jackknife_std`) widens the curvature's sigmas per
   parameter (:func:`~backend.core.result.widen_covariance`): an image region's lighting or a misleading
   reflector moves the optimum in a way per-point noise cannot show.
6. Checks (:func:`_solve_prepared`): a solution at the edge of the search (:func:`_at_search_edge`: the cost still
   falling there) or beside another alignment that fits as well (ambiguous) is not accepted. Without a translation
   prior, a scene that leaves the translation undetermined (ambiguous, pinned less well than the guess's
   :attr:`~LidarCameraIntensitySettings.guess_translation_sigma_m`, or pulled to the search's edge) is solved again
   with the translation held at the guess (:mod:`~backend.calib.lidar_camera.held_translation`), as the edges method
   does.

Refusals (:class:`InputError`, naming the pair): a cloud with no intensity channel; too few points in view; an
image or a set of intensities with (nearly) one value; a cost that is flat: the mutual information at the
solution below :attr:`~LidarCameraIntensitySettings.min_mutual_information` (the intensities say nothing about the
image), or a rotation the curvature leaves undetermined beyond ``max_flat_sigma``.

Parameters, covariance and sigmas follow :func:`backend.core.transforms.params_between` (the order
:data:`~backend.core.result.TRANSFORM_PARAMETERS`): ``[t_x, t_y, t_z]`` (m, along the camera's optical axes)
and ``[r_x, r_y, r_z]`` (rad; reported in deg) of a right perturbation ``R @ rotvec(r)``, i.e. about the LiDAR's
axes, as ``conventions.md`` asks.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, replace
from typing import Any

import cv2
import numpy as np
from scipy.optimize import minimize

from backend.calib.lidar_camera.edges import in_view
from backend.calib.lidar_camera.held_translation import (
    HELD_PRIOR_M,
    held_covariance,
    mark_held,
    translation_undetermined,
)
from backend.calib.lidar_camera.places import named_places, place_of_pairs
from backend.core.camera import CameraIntrinsics, check_camera_image
from backend.core.clouds import check_cloud
from backend.core.errors import InputError
from backend.core.projection import MIN_DEPTH_M, project_cloud
from backend.core.result import (
    TRANSFORM_PARAMETERS,
    ProgressCallback,
    TransformResult,
    finite_or_none,
    jackknife_std,
    no_progress,
    widen_covariance,
)
from backend.core.transforms import apply_params, check_transform, params_between, transform_points
from backend.core.uncertainty import sigmas

NOT_ACCEPTED = "; not accepted"
"""How the warning of a result that must not be accepted ends."""
MIN_SPREAD_PLACES = 3
"""With pairs from this many places or more the jackknife also leaves out places (the cross-check)."""


@dataclass
class LidarCameraIntensitySettings:
    """How to compare intensities with the image and search the transform. Lengths in m and px, angles in deg."""

    bins: int = 16
    """Histogram bins per side of the joint histogram (koide3's default)."""
    max_range_m: float = 100.0
    """LiDAR points further than this from the LiDAR are not used (m)."""
    view_margin_deg: float = 8.0
    """The cloud is cut to the camera's view at ``T_init`` widened by this (deg): more than its rotation error."""
    occlusion_px: int = 4
    """Block size (px) of the z-buffer that drops points hidden by nearer ones at ``T_init``; 0 to keep all."""
    coarse_blur_px: float = 4.0
    """Gaussian sigma (px) of the image blur in the coarse search: a wider basin."""
    fine_blur_px: float = 1.0
    """Gaussian sigma (px) of the image blur in the fine search and the uncertainty."""
    coarse_step_deg: float = 1.5
    """Step of the coarse rotation grid (deg): within the fine search's basin (about 1 deg on a real road scene)."""
    coarse_steps: int = 3
    """Grid points either way per rotation axis: the grid reaches ``coarse_steps * coarse_step_deg`` (4.5 deg)."""
    coarse_point_stride: int = 2
    """The coarse search uses every this-many-th point."""
    max_translation_m: float = 0.2
    """The search stays within this of ``T_init``'s translation (m, per axis), as koide3's BFGS does."""
    refined: int = 12
    """Best grid points turned by a compass search (:func:`_compass`) before the fine search's starts are chosen."""
    candidates: int = 8
    """Starts screened by a short Nelder-Mead run (``screen_evaluations``, every ``coarse_point_stride``-th point):
    the best of the refined grid points, then of the raw ones."""
    screen_evaluations: int = 200
    """Cost evaluations of each screening run."""
    fine_starts: int = 3
    """The best screened ends that the full fine search continues from."""
    candidate_separation: int = 2
    """A refined grid point starts a fine search only when it is more than this many grid steps (on some axis) from
    every better one: a wrong alignment can be a broad bowl whose many grid points would otherwise take every
    start."""
    simplex_m: float = 0.02
    """Initial Nelder-Mead simplex step in translation (m)."""
    simplex_deg: float = 0.6
    """Initial Nelder-Mead simplex step in rotation (deg): about the coarse grid's half step."""
    max_evaluations: int = 1500
    """Cost evaluations per Nelder-Mead run at most."""
    translation_prior_m: float | None = None
    """1-sigma (m, per axis) of the initial translation taken as a measurement; None for none. Far scenes (a road)
    fix the rotation well and the translation hardly: this holds it."""
    cell_px: float = 32.0
    """Side (px) of the image cells that count as independent in the likelihood's weight (:func:`_weight`)."""
    curvature_step: tuple[float, float] = (0.02, 0.2)
    """Steps (m, deg) of the samples the cost's quadratic is fitted to: wide enough to rise above the cost's
    sampling noise, inside its basin."""
    restarts: int = 2
    """Nelder-Mead runs restarted about the solution (half a simplex step off in a random direction): along the
    cost's flat valleys a run ends anywhere in its small-scale noise, and the ends' spread, which the curvature at
    one end cannot see, widens the sigmas (the lowest end is the solution)."""
    spread: bool = True
    """Widen the sigmas to the jackknife spread over image regions (and pairs)."""
    spread_cell_px: float = 160.0
    """Side (px) of the image squares whose points the jackknife leaves out together."""
    spread_groups: int = 10
    """Groups the jackknife deals the squares into."""
    tie_nid: float = 0.001
    """Another candidate whose mean NID ends within this of the solution's fits about as well (the cost's sampling
    noise on a real road frame is about 3e-4; wrong alignments there end 3e-3 higher)."""
    distinct: tuple[float, float] = (0.05, 0.5)
    """A candidate further than this (m, deg) on some parameter from the solution is another alignment."""
    min_points: int = 500
    """Fewest LiDAR points of a pair that project into the image at ``T_init``."""
    min_entropy_nats: float = 1.0
    """Fewest nats of entropy of a pair's image values (or its intensities) at the points: below it they are
    (nearly) one value, and nothing can be compared (one value, shared by two soft bins, gives up to ln 2 = 0.69;
    16 equal bins give 2.77)."""
    min_mutual_information: float = 0.02
    """Least mutual information (nats, mean over pairs) at the solution: below it the intensities tell nothing
    about the image (a real road frame gives about 0.2)."""
    max_flat_sigma: tuple[float, float] = (0.5, 1.0)
    """The curvature's 1-sigma (m, deg) beyond which a parameter counts as undetermined (a flat cost): a rotation
    that flat is refused; a translation that flat is held at the guess (``guess_translation_sigma_m``), or refused
    when that is None and no translation prior holds it."""
    guess_translation_sigma_m: float | None = 0.05
    """1-sigma (m, per axis) of the initial guess's translation: a tape measure's. When no translation prior is given
    and the scene cannot determine the translation (alignments far apart fit about equally well, or the intensities
    pin it less well than this), the rotation is solved with the translation held at the guess, which is reported
    with this sigma (:mod:`~backend.calib.lidar_camera.held_translation`); None leaves such a result ambiguous (not
    converged) or refused as flat."""


@dataclass
class IntensityObservation:
    """One image and the cloud, with its return intensities, taken at the same moment."""

    image: np.ndarray
    """(H, W) gray or (H, W, 3) BGR uint8 image, at the size the intrinsics are for."""
    points_lidar: np.ndarray
    """(N, 3) LiDAR points in the LiDAR frame (m)."""
    intensity: np.ndarray | None
    """(N,) return intensity of each point (any units); None when the cloud has none (refused)."""
    name: str = ""
    """How errors name this pair (e.g. ``"frame0.png:frame0.pcd"``); ``"pair i"`` when empty."""


@dataclass
class IntensityPairResiduals:
    """One pair's fit at the solution."""

    name: str
    points_in_view: int
    """LiDAR points kept in the camera's view at ``T_init`` (hidden ones dropped)."""
    points_in_image: int
    """Of those, the points that project into the image at the solution."""
    nid: float
    """Normalised information distance at the solution (0 best, 1 independent)."""
    nid_init: float
    """The same at ``T_init``."""
    mutual_information_nats: float

    def to_record(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class IntensityCandidate:
    """The fine search from one coarse grid point."""

    T_start: np.ndarray
    T_camera_lidar: np.ndarray
    nid: float
    """Mean NID over the pairs at the end."""
    offset: np.ndarray
    """(6,) the end about the solution's, in the result's parameters (m, camera axes; rad, LiDAR axes)."""
    competing: bool
    """Another alignment that fits about as well as the solution."""

    def to_record(self) -> dict[str, Any]:
        return {"T_start": self.T_start.tolist(), "T_camera_lidar": self.T_camera_lidar.tolist(), "nid": self.nid,
                "offset_m": finite_or_none(self.offset[:3]), "offset_deg": finite_or_none(np.degrees(self.offset[3:])),
                "competing": self.competing}


# ---------------------------------------------------------------- the cost


def _soft_bins(values: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Linear soft binning of values in [0, 1): the lower of the two bins each value shares (int64) and the upper's
    weight, with bin centres at ``(k + 0.5) / bins``."""
    x = np.clip(np.asarray(values, dtype=np.float64) * bins - 0.5, 0.0, bins - 1 - 1e-9)
    lower = np.floor(x).astype(np.int64)
    return lower, x - lower


def _entropy(p: np.ndarray, axis: int | tuple[int, ...]) -> np.ndarray:
    """Shannon entropy (nats) of the distributions ``p`` sums to 1 along ``axis``."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return -np.sum(np.where(p > 0, p * np.log(p), 0.0), axis=axis)


def nid_and_mi(joint: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalised information distance and mutual information (nats) of (..., bins, bins) joint histograms (any
    positive weights; image values along the second-last axis, intensities along the last)."""
    total = joint.sum(axis=(-2, -1), keepdims=True)
    p = joint / np.where(total > 0, total, 1.0)
    h_joint = _entropy(p, (-2, -1))
    mi = _entropy(p.sum(axis=-1), -1) + _entropy(p.sum(axis=-2), -1) - h_joint
    with np.errstate(divide="ignore", invalid="ignore"):
        nid = np.where(h_joint > 0, (h_joint - mi) / h_joint, 1.0)
    return nid, mi


@dataclass
class _Pair:
    """One pair, prepared: its images, kept points and their binned intensities."""

    name: str
    coarse_image: np.ndarray
    """(H, W) float32 equalised grey in [0, 1), blurred by ``coarse_blur_px``."""
    fine_image: np.ndarray
    """The same blurred by ``fine_blur_px``."""
    points: np.ndarray
    """(N, 3) LiDAR points kept (m)."""
    intensity_bin: np.ndarray
    """(N,) lower soft bin of each point's equalised intensity."""
    intensity_weight: np.ndarray
    """(N,) weight of the upper bin."""

    def joint(self, T: np.ndarray, camera: CameraIntrinsics, fine: bool, bins: int, stride: int = 1,
              group: np.ndarray | None = None, groups: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """(groups, bins, bins) joint histograms of image value and intensity at ``T`` (``group``: (N,) group of
        each point, or None for one) and the (M,) rows of the points that land on the image."""
        points = self.points[::stride]
        camera_points = transform_points(T, points)
        ahead = np.flatnonzero(camera_points[:, 2] > MIN_DEPTH_M)
        uv = camera.project(camera_points[ahead])
        # Bilinear sampling needs the 2x2 pixels around: keep points whose neighbourhood lies on the image.
        inside = (uv[:, 0] >= 0) & (uv[:, 0] <= camera.width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= camera.height - 1)
        rows = ahead[inside]
        uv = uv[inside].astype(np.float32)
        image = self.fine_image if fine else self.coarse_image
        values = cv2.remap(image, uv[:, :1], uv[:, 1:], cv2.INTER_LINEAR).ravel()
        image_bin, image_weight = _soft_bins(values, bins)
        point_rows = rows * stride
        lidar_bin, lidar_weight = self.intensity_bin[point_rows], self.intensity_weight[point_rows]
        offset = 0 if group is None else group[point_rows] * bins * bins
        joint = np.zeros(groups * bins * bins)
        for di, wi in ((0, 1 - image_weight), (1, image_weight)):
            for dl, wl in ((0, 1 - lidar_weight), (1, lidar_weight)):
                joint += np.bincount(offset + (image_bin + di) * bins + lidar_bin + dl, wi * wl,
                                     minlength=groups * bins * bins)
        return joint.reshape(groups, bins, bins), point_rows


def _weight(pair: _Pair, T: np.ndarray, camera: CameraIntrinsics, settings: LidarCameraIntensitySettings) -> float:
    """The pair's weight ``N H(I, L)`` at ``T`` (see the module's step 2): ``N`` the image cells of ``cell_px`` that
    hold a point, ``H`` the joint entropy (nats)."""
    joint, rows = pair.joint(T, camera, True, settings.bins)
    uv = camera.project(transform_points(T, pair.points[rows]))
    cells = len(np.unique(np.floor(uv / settings.cell_px).astype(np.int64), axis=0))
    p = joint[0] / joint[0].sum()
    return float(cells * _entropy(p, (0, 1)))


class _Objective:
    """``sum_i w_i NID_i`` over the pairs at a transform, plus the translation prior; counts its evaluations."""

    def __init__(self, pairs: list[_Pair], weights: np.ndarray, camera: CameraIntrinsics,
                 settings: LidarCameraIntensitySettings, T_init: np.ndarray) -> None:
        self.pairs, self.weights, self.camera, self.settings = pairs, weights, camera, settings
        self.T_init, self.t_init = T_init, T_init[:3, 3]
        self.evaluations = 0

    def prior(self, T: np.ndarray) -> float:
        sigma = self.settings.translation_prior_m
        return 0.0 if sigma is None else float(0.5 * np.sum(((T[:3, 3] - self.t_init) / sigma) ** 2))

    def nids(self, T: np.ndarray, fine: bool = True, stride: int = 1) -> np.ndarray:
        """(pairs,) NID of each pair at ``T``."""
        self.evaluations += 1
        joints = [p.joint(T, self.camera, fine, self.settings.bins, stride)[0][0] for p in self.pairs]
        return nid_and_mi(np.array(joints))[0]

    def __call__(self, T: np.ndarray, fine: bool = True, stride: int = 1) -> float:
        """The objective; infinite outside the search's reach of ``T_init`` (:meth:`in_reach`)."""
        if not self.in_reach(T):
            return np.inf
        return float(self.weights @ self.nids(T, fine, stride)) + self.prior(T)

    def reach(self) -> np.ndarray:
        """(6,) how far the search goes from ``T_init`` per parameter (m, m, m, rad, rad, rad): the coarse grid's
        reach widened by one grid step (per rotation axis) and ``max_translation_m``. Beyond, the cost's other basins
        (a road scene has them some 8 deg off) are nearer than the truth can be, given how far off the initial guess
        may be."""
        rotation = np.radians((self.settings.coarse_steps + 1) * self.settings.coarse_step_deg)
        return np.r_[np.full(3, self.settings.max_translation_m), np.full(3, rotation)]

    def in_reach(self, T: np.ndarray) -> bool:
        """Whether ``T`` lies within :meth:`reach` of ``T_init`` on every parameter."""
        return bool(np.all(np.abs(params_between(self.T_init, T)) <= self.reach()))


# ---------------------------------------------------------------- preparing a pair


def _equalised_grey(image: np.ndarray, name: str, camera: CameraIntrinsics) -> np.ndarray:
    """The image as histogram-equalised grey, float32 in [0, 1); refuses a bad image."""
    image = check_camera_image(image, camera, f"{name}: image")
    grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    return cv2.equalizeHist(grey).astype(np.float32) / 256.0


def _rank_equalised(values: np.ndarray) -> np.ndarray:
    """Values mapped to their rank, in [0, 1): an equalised histogram (ties share their mean rank)."""
    order = np.argsort(values, kind="stable")
    sorted_values = values[order]
    _, first, counts = np.unique(sorted_values, return_index=True, return_counts=True)
    mean_rank = first + 0.5 * counts  # ties take the middle of their run of ranks
    ranks = np.empty(len(values))
    ranks[order] = np.repeat(mean_rank, counts)
    return ranks / len(values)


def _prepare(observation: IntensityObservation, name: str, camera: CameraIntrinsics, T_init: np.ndarray,
             settings: LidarCameraIntensitySettings) -> _Pair:
    """One pair's images and points, refusing a pair without intensities, with too few points or with one value."""
    if observation.intensity is None:
        raise InputError("the cloud has no intensity channel; the intensity method needs one - use --method edges",
                         f"{name}: cloud")
    grey = _equalised_grey(observation.image, name, camera)
    raw = np.asarray(observation.points_lidar, dtype=float)
    intensity = np.asarray(observation.intensity, dtype=float).ravel()
    if raw.ndim != 2 or len(intensity) != len(raw):
        raise InputError(f"expected one intensity per point, got {len(intensity)} for {len(raw)} points",
                         f"{name}: cloud")
    points, _ = check_cloud(raw, f"{name}: cloud")
    intensity = intensity[np.isfinite(raw[:, :3]).all(axis=1)]
    keep = in_view(points, T_init, camera, settings.view_margin_deg, settings.max_range_m) & np.isfinite(intensity)
    points, intensity = points[keep], intensity[keep]
    in_image = project_cloud(points, T_init, camera).index
    if settings.occlusion_px > 0:  # koide3's view culling: drop what a nearer surface hides at T_init
        hidden = np.setdiff1d(in_image, project_cloud(points, T_init, camera, occlusion_px=settings.occlusion_px).index)
        visible = np.ones(len(points), bool)
        visible[hidden] = False
        points, intensity = points[visible], intensity[visible]
        in_image = len(in_image) - len(hidden)
    else:
        in_image = len(in_image)
    if in_image < settings.min_points:
        raise InputError(f"too few points: {in_image} LiDAR points within {settings.max_range_m:g} m project into "
                         f"the image at T_init; at least {settings.min_points} are needed - is the initial guess "
                         "facing the scene the camera sees?", f"{name}: cloud")
    equalised = _rank_equalised(intensity)
    intensity_bin, intensity_weight = _soft_bins(equalised, settings.bins)
    pair = _Pair(name, cv2.GaussianBlur(grey, (0, 0), settings.coarse_blur_px),
                 cv2.GaussianBlur(grey, (0, 0), settings.fine_blur_px), points, intensity_bin, intensity_weight)
    joint = pair.joint(T_init, camera, True, settings.bins)[0][0]
    p = joint / joint.sum()
    for axis, what, lacking in ((1, "image", "is it blank or over-exposed?"),
                                (0, "cloud", "the LiDAR's intensities are all about one value")):
        entropy = float(_entropy(p.sum(axis=axis), 0))
        if entropy < settings.min_entropy_nats:
            raise InputError(
                f"flat cost: the {'grey values of the image' if what == 'image' else 'intensities'} at the LiDAR "
                f"points hold {entropy:.2f} nats, below {settings.min_entropy_nats:g}: there is nothing to match - "
                f"{lacking}", f"{name}: {what}")
    return pair


# ---------------------------------------------------------------- search


def _coarse(objective: _Objective, T_init: np.ndarray, settings: LidarCameraIntensitySettings,
            progress: ProgressCallback) -> list[np.ndarray]:
    """The ``candidates`` starts for the fine search (4x4 each): the ``refined`` best rotations of the grid about
    ``T_init`` on the coarse images, each turned by a compass search (:func:`_compass`) on the fine images, and of
    those the best, each further than ``candidate_separation`` grid steps (on some axis) from a better one; then, if
    fewer, the best grid points so separated.

    The refinement is what finds the truth: near it the cost is a cone about a coarse step wide (at 2117 px, 1 deg is
    37 px), so the grid point beside it scores worse than the floor of a broad wrong basin; one compass search later
    it scores better (on the real road frame the truth's basin ends at NID 0.955, the wrong ones at 0.962 or more)."""
    steps = np.arange(-settings.coarse_steps, settings.coarse_steps + 1)
    grid = np.array(list(itertools.product(steps, steps, steps)))
    step = np.radians(settings.coarse_step_deg)
    costs = np.empty(len(grid))
    for k, cell in enumerate(grid):
        if k % 50 == 0:
            progress(0.6 * k / len(grid), f"coarse grid: {k} of {len(grid)} rotations")
        costs[k] = objective(apply_params(T_init, np.r_[np.zeros(3), step * cell]), fine=False,
                             stride=settings.coarse_point_stride)
    refined = []
    for n, k in enumerate(np.argsort(costs)[:settings.refined]):
        progress(0.6 + 0.4 * n / settings.refined, f"coarse: turning start {n + 1} of {settings.refined}")
        T, cost = _compass(objective, apply_params(T_init, np.r_[np.zeros(3), step * grid[k]]), step / 2,
                           settings.coarse_point_stride)
        refined.append((cost, T))
    refined.sort(key=lambda item: item[0])
    # The refined ends first; when they gather in fewer basins than there are starts, the raw grid points fill in
    # (a compass search can also slide from beside the truth's narrow cone into a broad wrong bowl).
    raw = [apply_params(T_init, np.r_[np.zeros(3), step * grid[k]]) for k in np.argsort(costs)]
    chosen: list[np.ndarray] = []
    for T in [T for _, T in refined] + raw:
        if all(np.abs(params_between(T, other)[3:]).max() > settings.candidate_separation * step for other in chosen):
            chosen.append(T)
        if len(chosen) == settings.candidates:
            break
    return chosen


def _compass(objective: _Objective, T: np.ndarray, step_rad: float, stride: int,
             min_step_rad: float = np.radians(0.1)) -> tuple[np.ndarray, float]:
    """A compass (pattern) search over the rotation from ``T`` on the fine images with every ``stride``-th point:
    try +-``step_rad`` about each LiDAR axis, move to the best improvement, halve the step when none improves, down
    to ``min_step_rad``. Returns the end and its cost."""
    cost = objective(T, stride=stride)
    while step_rad >= min_step_rad:
        trials = [apply_params(T, np.r_[np.zeros(3), step_rad * sign * np.eye(3)[axis]])
                  for axis in range(3) for sign in (-1.0, 1.0)]
        trial_costs = [objective(trial, stride=stride) for trial in trials]
        best = int(np.argmin(trial_costs))
        if trial_costs[best] < cost:
            T, cost = trials[best], trial_costs[best]
        else:
            step_rad /= 2
    return T, cost


def _simplex_step(settings: LidarCameraIntensitySettings) -> np.ndarray:
    """(6,) the initial Nelder-Mead simplex's step per parameter (m, m, m, rad, rad, rad)."""
    return np.r_[np.full(3, settings.simplex_m), np.full(3, np.radians(settings.simplex_deg))]


def _fine(objective: _Objective, T_start: np.ndarray, settings: LidarCameraIntensitySettings, stride: int = 1,
          max_evaluations: int | None = None, shrinks: tuple[float, ...] = (1.0, 0.5)) -> np.ndarray:
    """Nelder-Mead over the six parameters from ``T_start`` on the fine images with every ``stride``-th point, run
    once per simplex size in ``shrinks`` (restarted with half the simplex: a collapsed simplex stalls); the end as a
    4x4."""
    scale = _simplex_step(settings)
    T = T_start
    for shrink in shrinks:
        simplex = np.vstack([np.zeros(6), shrink * np.eye(6)])
        found = minimize(lambda x, T0=T: objective(apply_params(T0, x * scale), stride=stride), np.zeros(6),
                         method="Nelder-Mead", options={"initial_simplex": simplex, "xatol": 0.02, "fatol": 1e-3,
                                                        "maxfev": max_evaluations or settings.max_evaluations})
        T = apply_params(T, found.x * scale)
    return T


AT_EDGE_SHARE = 0.9
"""A parameter at this share of the search's reach or more lies at its edge: Nelder-Mead pressed outward by a cost
still falling there ends along the edge, not on it (on the real VLP-16 street frames at 0.94-0.97 of it), and an
optimum this far from the guess lies beyond what the guess allows anyway (the coarse grid reaches 0.75 of it)."""


def _at_search_edge(objective: _Objective, T: np.ndarray) -> list[str]:
    """The parameters on which the solution ``T`` lies at the edge of the search's reach of ``T_init``
    (:meth:`_Objective.reach`, :data:`AT_EDGE_SHARE`): there the cost was still falling when the search stopped, so the
    solution is no optimum and the curvature's sigmas describe nothing. Each as ``"r_y -3.0 of 3 deg"``."""
    offset, reach = params_between(objective.T_init, T), objective.reach()
    edges = []
    for i in np.flatnonzero(np.abs(offset) >= AT_EDGE_SHARE * reach):
        scale, unit = (100.0, "cm") if i < 3 else (np.degrees(1.0), "deg")
        name = TRANSFORM_PARAMETERS[i].removesuffix("_m").removesuffix("_rad")
        edges.append(f"{name} {scale * offset[i]:+.1f} of {scale * reach[i]:g} {unit}")
    return edges


# ---------------------------------------------------------------- uncertainty


def _sample_offsets() -> np.ndarray:
    """(85, 6) sample points in steps: the centre, +-1 and +-2 along each axis, +-1 +-1 across each pair of axes."""
    samples = [np.zeros(6)]
    for i in range(6):
        for s in (-2, -1, 1, 2):
            samples.append(s * np.eye(6)[i])
    for i, j in itertools.combinations(range(6), 2):
        for si, sj in itertools.product((-1, 1), repeat=2):
            samples.append(si * np.eye(6)[i] + sj * np.eye(6)[j])
    return np.array(samples)


AXIS_STEPS = np.array([-2.0, -1.0, 1.0, 2.0])
"""Steps of :func:`_sample_offsets` along each axis, in its order."""
MIN_CORRELATION_EIGENVALUE = 0.05
"""The curvature's correlations are shrunk toward none until their smallest eigenvalue is at least this."""


def _local_quadratic(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gradient (6,) and positive semi-definite Hessian (6, 6) at 0, in steps, of the cost at the
    :func:`_sample_offsets` (``values`` (85,)).

    Each axis's gradient and curvature are its own least-squares parabola through the centre and its four samples;
    each pair's cross term the mixed difference ``(f(++) + f(--) - f(+-) - f(-+)) / 4``. A full quadratic fitted to
    all samples at once does worse here: near its optimum the NID is closer to a cone than a bowl, and the cross
    samples then pull the diagonal negative. Cross terms that would make the Hessian indefinite are shrunk toward
    zero (:data:`MIN_CORRELATION_EIGENVALUE`); an axis without positive curvature is undetermined (0 on its row).
    """
    x = np.r_[0.0, AXIS_STEPS]
    design = np.column_stack([np.ones(5), x, x * x])
    axis_values = np.column_stack([np.full(6, values[0]), values[1:25].reshape(6, 4)])
    coefficients = np.linalg.lstsq(design, axis_values.T, rcond=None)[0]  # (3, 6)
    gradient, diagonal = coefficients[1], 2 * coefficients[2]
    hessian = np.diag(diagonal)
    cross = values[25:].reshape(15, 4)  # (--, -+, +-, ++) for each pair of axes
    for (i, j), (mm, mp, pm, pp) in zip(itertools.combinations(range(6), 2), cross, strict=True):
        hessian[i, j] = hessian[j, i] = (pp + mm - pm - mp) / 4
    determined = diagonal > 0
    hessian[~determined, :] = hessian[:, ~determined] = 0.0
    scale = np.sqrt(np.where(determined, diagonal, 1.0))
    correlation = hessian / np.outer(scale, scale)
    off = correlation - np.diag(np.diag(correlation))
    d = np.diag(np.diag(correlation))
    for shrink in np.linspace(1.0, 0.0, 21):
        blended = d + shrink * off
        if np.linalg.eigvalsh(blended[np.ix_(determined, determined)]).min(initial=1.0) >= MIN_CORRELATION_EIGENVALUE:
            break
    return gradient, np.outer(scale, scale) * blended


def _minimum(gradient: np.ndarray, hessian: np.ndarray) -> np.ndarray:
    """The minimum ``-H^-1 g`` (6,) of a quadratic, with undetermined directions (no positive curvature) held at 0."""
    eigenvalues, eigenvectors = np.linalg.eigh(hessian)
    inverse = np.where(eigenvalues > 1e-12, 1.0 / np.where(eigenvalues > 1e-12, eigenvalues, 1.0), 0.0)
    return -eigenvectors @ (inverse * (eigenvectors.T @ gradient))


@dataclass
class _Curvature:
    covariance: np.ndarray
    """6x6 (m, rad) from the fitted Hessian; inf on the diagonal where undetermined."""
    std_regions: np.ndarray | None
    """(6,) leave-one-image-region-out jackknife std, or None."""
    std_places: np.ndarray | None
    """(6,) leave-one-place-out jackknife std, or None (fewer than :data:`MIN_SPREAD_PLACES` places)."""
    information: np.ndarray
    """6x6 (m, rad) the data's own: the Hessian of the cost without the translation prior."""


def _curvature(objective: _Objective, T: np.ndarray, camera: CameraIntrinsics, settings: LidarCameraIntensitySettings,
               place: np.ndarray, progress: ProgressCallback) -> _Curvature:
    """The cost's quadratic about ``T`` and its jackknife (module step 5); ``place`` (pairs,) is each pair's place."""
    step = np.r_[np.full(3, settings.curvature_step[0]), np.full(3, np.radians(settings.curvature_step[1]))]
    offsets = _sample_offsets()
    groups = settings.spread_groups
    rng = np.random.default_rng(0)
    point_groups = []
    for pair in objective.pairs:  # each point's image square at the solution, the squares dealt into groups
        uv = camera.project(transform_points(T, pair.points))
        with np.errstate(invalid="ignore"):
            cells = np.nan_to_num(np.floor(uv / settings.spread_cell_px), nan=-1.0).astype(np.int64)
        _, cell = np.unique(cells, axis=0, return_inverse=True)
        point_groups.append(rng.permutation(int(cell.max()) + 1)[cell.ravel()] % groups)
    n_pairs = len(objective.pairs)
    joints = np.empty((len(offsets), n_pairs, groups, settings.bins, settings.bins))
    priors = np.empty(len(offsets))
    for k, offset in enumerate(offsets):
        if k % 10 == 0:
            progress(k / len(offsets), f"curvature: sample {k} of {len(offsets)}")
        T_k = apply_params(T, offset * step)
        priors[k] = objective.prior(T_k)
        objective.evaluations += 1
        for i, pair in enumerate(objective.pairs):
            joints[k, i] = pair.joint(T_k, camera, True, settings.bins, group=point_groups[i], groups=groups)[0]
    weights = objective.weights

    def values(joint_sum: np.ndarray, pair_weights: np.ndarray) -> np.ndarray:
        """Objective at every sample from (samples, pairs, bins, bins) histograms."""
        return nid_and_mi(joint_sum)[0] @ pair_weights + priors

    full = joints.sum(axis=2)
    full_values = values(full, weights)
    _, hessian = _local_quadratic(full_values)
    information = _local_quadratic(full_values - priors)[1] / np.outer(step, step)
    determined = np.diag(hessian) > 0
    covariance = np.diag(np.full(6, np.inf))  # parameters = step * x, so cov = S cov_x S
    covariance[np.ix_(determined, determined)] = (np.outer(step, step)[np.ix_(determined, determined)]
                                                  * np.linalg.inv(hessian[np.ix_(determined, determined)]))
    if not settings.spread:
        return _Curvature(covariance, None, None, information)
    subsets = {"image regions": [(full - joints[:, :, g], weights) for g in range(groups)]}
    n_places = int(place.max()) + 1
    if n_places >= MIN_SPREAD_PLACES:
        subsets["places"] = [(full, np.where(place == k, 0.0, weights)) for k in range(n_places)]
    spreads = {}
    for source, subset in subsets.items():
        estimates = [step * np.clip(_minimum(*_local_quadratic(values(joint_sum, w))), -AXIS_STEPS[-1], AXIS_STEPS[-1])
                     for joint_sum, w in subset]  # the quadratic holds only as far as it was sampled
        spreads[source] = jackknife_std(np.array(estimates))
    return _Curvature(covariance, spreads["image regions"], spreads.get("places"), information)


def _check_flat(covariance: np.ndarray, mean_mi: float, settings: LidarCameraIntensitySettings,
                names: list[str]) -> None:
    """Refuse a flat cost: too little mutual information, or a parameter the curvature leaves undetermined (the
    translation only when neither a translation prior nor the guess's sigma can hold it)."""
    where = ", ".join(names)
    if mean_mi < settings.min_mutual_information:
        raise InputError(
            f"flat cost: the LiDAR intensities and the image grey values share {mean_mi:.3f} nats of information at "
            f"the best alignment, below {settings.min_mutual_information:g}: the intensities tell nothing about the "
            "image - the scene needs surfaces whose reflectivity the camera also sees (markings, signs, light and "
            "dark walls), or use --method edges", where)
    std = sigmas(covariance)
    limit_m, limit_deg = settings.max_flat_sigma
    flat = [f"r_{axis} (sigma {np.degrees(s):.2g} deg)" for axis, s in zip("xyz", std[3:], strict=True)
            if not np.degrees(s) <= limit_deg]
    if settings.translation_prior_m is None and settings.guess_translation_sigma_m is None:
        flat = [f"t_{axis} (sigma {s:.2g} m)" for axis, s in zip("xyz", std[:3], strict=True)
                if not s <= limit_m] + flat
    if flat:
        raise InputError(
            f"flat cost: the NID hardly changes along {', '.join(flat)} (beyond {limit_m:g} m or {limit_deg:g} deg): "
            "the intensities in view do not pin the transform - add pairs with more varied reflectivity in view"
            + ("" if settings.translation_prior_m is not None else
               ", or hold the measured translation with --translation-prior"), where)


# ---------------------------------------------------------------- the solve


def solve_intensity(camera: CameraIntrinsics, pairs: Sequence[IntensityObservation], T_init: np.ndarray,
                    settings: LidarCameraIntensitySettings | None = None,
                    progress: ProgressCallback = no_progress) -> TransformResult:
    """Estimate ``T_camera_lidar`` (maps LiDAR points into the camera's optical frame, m) from LiDAR intensities
    against image grey values (minimum NID).

    ``pairs`` are images and clouds with intensities taken at the same moments (any number); ``T_init`` is the
    initial ``T_camera_lidar``, within the coarse grid's reach of the truth (4.5 deg per axis with the defaults; the
    translation within a few cm). Raises :class:`InputError` for no pairs, a bad image, cloud or transform, a cloud
    without intensities, too few points in view, a flat cost (see the module). A solve that ends ambiguous (another
    alignment fits as well) or at the search's edge is returned with ``converged=False`` and a warning; without a
    translation prior, one whose translation is undetermined is solved again with it held at the guess (module step
    6; ``diagnostics["translation_held"]``).

    Returns a :class:`~backend.core.result.TransformResult` (kind ``lidar_camera``, method ``intensity``, parent
    ``camera``, child ``lidar``): ``T_parent_child`` is ``T_camera_lidar``; its covariance holds the reported
    (larger-per-parameter) sigmas with the curvature's correlations. ``residuals``: ``nid`` and ``nid_init`` (mean
    over pairs), ``mutual_information_nats`` (mean), ``points_in_image`` (all pairs) and ``per_pair_nid``.
    ``diagnostics`` (6-vectors in m, m, m, rad, rad, rad; None where undetermined or not computed):
    ``std_curvature`` (the cost's curvature), ``std_groups`` (over the scenes' parts: the larger of the
    leave-one-image-region-out jackknife and the restarts' spread), ``std_places`` (the leave-one-place-out jackknife,
    with pairs from :data:`MIN_SPREAD_PLACES` places or more), ``std_spread`` (the largest of those two per
    parameter), ``spread_source`` ("image regions" (and "places": what the jackknife left out) and "restarts"),
    ``places`` (the pairs' names, grouped by the place they were taken in), ``candidates``
    (the fine search from each coarse grid point as :class:`IntensityCandidate`, the solution's first), ``T_init``,
    ``T_coarse`` (the grid point the solution's search started from), ``evaluations`` (of the cost) and ``pairs``
    (each pair's :class:`IntensityPairResiduals`).
    """
    settings = settings or LidarCameraIntensitySettings()
    started = time.perf_counter()
    if not pairs:
        raise InputError("no image and cloud pairs given; at least one is needed", "pairs")
    T_init, _ = check_transform(T_init, "T_init")
    names = [o.name or f"pair {i + 1}" for i, o in enumerate(pairs)]
    prepared = []
    for i, (observation, name) in enumerate(zip(pairs, names, strict=True)):
        progress(0.05 * i / len(pairs), f"preparing {name}")
        prepared.append(_prepare(observation, name, camera, T_init, settings))
    place = place_of_pairs([np.asarray(o.points_lidar) for o in pairs])
    may_hold = settings.translation_prior_m is None and settings.guess_translation_sigma_m is not None
    free_share = 0.6 if may_hold else 1.0
    result, _, at_edge = _solve_prepared(prepared, place, camera, T_init, settings, names,
                                         lambda f, m: progress(0.05 + (free_share - 0.05) * f, m))
    why = None
    if may_hold and at_edge and all(axis.startswith("t_") for axis in at_edge):
        why = f"the intensities pull the translation to the search's edge ({', '.join(at_edge)})"
    elif may_hold and not at_edge:
        why = translation_undetermined(result, settings.guess_translation_sigma_m, "the intensities", NOT_ACCEPTED)
    if why is not None:
        result = _solve_held(prepared, place, camera, T_init, settings, names, why,
                             lambda f, m: progress(0.6 + 0.4 * f, f"translation held at the guess: {m}"))
    progress(1.0, "done")
    result.seconds = time.perf_counter() - started
    return result


def _solve_held(prepared: list[_Pair], place: np.ndarray, camera: CameraIntrinsics, T_init: np.ndarray,
                settings: LidarCameraIntensitySettings, names: list[str], why: str, progress: ProgressCallback
                ) -> TransformResult:
    """The rotation solved with the translation held at ``T_init``'s (:data:`HELD_PRIOR_M`), its covariance that of
    the guess's translation sigma (:func:`~backend.calib.lidar_camera.held_translation.held_covariance`, from the
    curvature without the prior), and ``why`` the scene could not determine it in the warning and
    ``diagnostics["translation_held"]``."""
    sigma_m = settings.guess_translation_sigma_m
    assert sigma_m is not None  # only held when the guess has a sigma
    result, information, _ = _solve_prepared(prepared, place, camera, T_init,
                                             replace(settings, translation_prior_m=HELD_PRIOR_M), names, progress)
    covariance, alone = held_covariance(information, sigma_m)
    result.covariance = widen_covariance(covariance, result.std_vector)
    mark_held(result, sigma_m, why, alone, "the intensities",
              "Add pairs taken in other places, with reflective surfaces near and in several directions, to determine "
              "it")
    return result


def _solve_prepared(prepared: list[_Pair], place: np.ndarray, camera: CameraIntrinsics, T_init: np.ndarray,
                    settings: LidarCameraIntensitySettings, names: list[str], progress: ProgressCallback
                    ) -> tuple[TransformResult, np.ndarray, list[str]]:
    """The search, the uncertainty and the checks of the module's steps 3-5 over the prepared pairs (``place``: each
    one's place): the result, the data's information (6x6, m and rad: the curvature without the translation prior)
    and the parameters at the search's edge (:func:`_at_search_edge`)."""
    place_share = 1.0 / np.bincount(place)[place]  # a place's pairs count once
    weights = place_share * np.array([_weight(p, T_init, camera, settings) for p in prepared])
    objective = _Objective(prepared, weights, camera, settings, T_init)
    starts = _coarse(objective, T_init, settings, lambda fraction, message: progress(0.3 * fraction, message))
    screened = []
    for k, T_start in enumerate(starts):
        progress(0.3 + 0.2 * k / len(starts), f"screening start {k + 1} of {len(starts)}")
        T_end = _fine(objective, T_start, settings, settings.coarse_point_stride, settings.screen_evaluations, (1.0,))
        screened.append((objective(T_end, stride=settings.coarse_point_stride), k, T_end))
    screened.sort(key=lambda item: item[0])
    starts = [starts[k] for _, k, _ in screened[:settings.fine_starts]]
    ends = []
    for k, (_, _, T_start) in enumerate(screened[:settings.fine_starts]):
        progress(0.5 + 0.2 * k / settings.fine_starts, f"fine search from start {k + 1} of {settings.fine_starts}")
        ends.append(_fine(objective, T_start, settings))
    mean_nids = [float(np.mean(objective.nids(T))) for T in ends]
    best = int(np.argmin([objective(T) for T in ends]))
    T = ends[best]
    # The weights at the solution, where the likelihood's scale is meant (they were taken at T_init for the search).
    objective.weights = place_share * np.array([_weight(p, T, camera, settings) for p in prepared])
    restarts = [T]
    rng = np.random.default_rng(1)
    for k in range(settings.restarts):
        progress(0.7 + 0.2 * k / settings.restarts, f"restart {k + 1} of {settings.restarts} about the solution")
        kick = rng.choice([-1.0, 1.0], 6) * _simplex_step(settings) / 2
        restarts.append(_fine(objective, apply_params(T, kick), settings))
    T = min(restarts, key=objective)
    std_restarts = jackknife_std(np.array([params_between(T, T_k) for T_k in restarts])) if settings.restarts else None
    curvature = _curvature(objective, T, camera, settings, place, lambda f, m: progress(0.9 + 0.1 * f, m))
    joints = np.array([p.joint(T, camera, True, settings.bins)[0][0] for p in prepared])
    nid, mi = nid_and_mi(joints)
    _check_flat(curvature.covariance, float(mi.mean()), settings, names)
    groups = [g for g in (curvature.std_regions, std_restarts) if g is not None]
    std_groups = np.max(groups, axis=0) if groups else None
    spreads = [g for g in (std_groups, curvature.std_places) if g is not None]
    spread = np.max(spreads, axis=0) if spreads else None
    parts = {"image regions": curvature.std_regions, "places": curvature.std_places, "restarts": std_restarts}
    source = " and ".join(name for name, part in parts.items() if part is not None) or None
    covariance = widen_covariance(curvature.covariance, spread)
    warnings: list[str] = []
    converged = True
    limit_m, limit_deg = settings.distinct
    candidates = []
    for k, T_end in enumerate(ends):
        offset = params_between(T, T_end)
        far = np.abs(offset[:3]).max() > limit_m or np.degrees(np.abs(offset[3:]).max()) > limit_deg
        competing = k != best and far and mean_nids[k] - mean_nids[best] <= settings.tie_nid
        candidates.append(IntensityCandidate(starts[k], T_end, mean_nids[k], offset, competing))
    candidates.insert(0, candidates.pop(best))
    at_edge = _at_search_edge(objective, T)
    if at_edge:
        warnings.append(f"the best alignment lies at the edge of the search ({', '.join(at_edge)} from the initial "
                        "guess), where the cost was still falling: the intensities favour an alignment beyond the "
                        "search - the initial guess is further off than the search allows, or the intensities in view "
                        f"do not determine the transform (try --method edges){NOT_ACCEPTED}")
        converged = False
    competing = [c for c in candidates if c.competing]
    if competing:
        apart = np.max(np.abs([c.offset for c in competing]), axis=0)
        warnings.append(f"ambiguous: {len(competing) + 1} alignments fit about equally well (mean NID "
                        f"{mean_nids[best]:.4f} at the solution, {', '.join(f'{c.nid:.4f}' for c in competing)} at "
                        f"the others), up to {1000 * apart[:3].max():.0f} mm and {np.degrees(apart[3:].max()):.2f} "
                        f"deg apart{NOT_ACCEPTED}")
        converged = False
    nid_init = nid_and_mi(np.array([p.joint(T_init, camera, True, settings.bins)[0][0] for p in prepared]))[0]
    per_pair = [IntensityPairResiduals(p.name, len(p.points), int(joints[i].sum().round()), float(nid[i]),
                                       float(nid_init[i]), float(mi[i])) for i, p in enumerate(prepared)]
    result = TransformResult(
        kind="lidar_camera", method="intensity", parent="camera", child="lidar",
        T_parent_child=T,
        covariance=covariance,
        residuals={"nid": float(nid.mean()), "nid_init": float(nid_init.mean()),
                   "mutual_information_nats": float(mi.mean()),
                   "points_in_image": int(sum(p.points_in_image for p in per_pair)),
                   "per_pair_nid": [p.nid for p in per_pair]},
        diagnostics={"std_curvature": finite_or_none(sigmas(curvature.covariance)),
                     "std_spread": finite_or_none(spread), "std_groups": finite_or_none(std_groups),
                     "std_places": finite_or_none(curvature.std_places), "spread_source": source,
                     "places": named_places(place, names),
                     "candidates": [c.to_record() for c in candidates], "T_init": T_init.tolist(),
                     "T_coarse": starts[best].tolist(), "evaluations": objective.evaluations,
                     "pairs": [p.to_record() for p in per_pair]},
        settings=asdict(settings),
        converged=converged,
        warnings=warnings,
    )
    return result, curvature.information, at_edge
