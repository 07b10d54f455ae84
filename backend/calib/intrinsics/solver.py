"""Camera intrinsic calibration with honest uncertainties, judged as mrcal judges a lens.

OpenCV does the solve (``calibrateCamera`` for ``pinhole-radtan``,
``fisheye.calibrate`` for ``fisheye-equidistant``); the ``photogrammetric`` model, which OpenCV cannot fit, is
solved by :mod:`backend.calib.intrinsics.photogrammetric` from OpenCV's solve, and mrcal's splined model by
:mod:`backend.calib.intrinsics.splined` (:func:`_splined_calibrate`, its regularization in the covariance as mrcal
has it). A board's bow (mrcal's
``calobject_warp``) is then solved with the lens and the poses (:mod:`backend.calib.intrinsics.flex`), or held at
zero and said why. OpenCV reports per-parameter standard deviations but not their covariance, so we rebuild the
full problem's Jacobian from OpenCV's own analytic projection Jacobians (``projectPoints``) and
compute ``cov = sigma^2 (J^T J)^-1`` over intrinsics, every view's pose and the flex,
with ``sigma^2`` the residual variance (``SSR / (2N - P)``). That gives the
standard deviations, the correlation matrix (e.g. k1-k2) and the projection
uncertainty across the image, all from one documented noise model:
independent, isotropic Gaussian corner noise. The projection uncertainty is mrcal's: the camera free to turn
against the boards, the poses marginalised (:func:`_noise_model_projection`).

Checkerboard views come with several corner sets (``findChessboardCornersSB``'s and the
same refined by :func:`~backend.calib.board.detection.refine_corners` with a few window
sizes); the solve uses the set that fits the model best on these views (``corners`` in
the result).
Single corners far beyond the corner noise are rejected first, round by round, as mrcal does
(:func:`_reject_corners`); the result lists them per view, and a view that would lose more than a quarter of its
corners is dropped whole and named.
Every result carries a :class:`~backend.core.verdict.Verdict` (:func:`~backend.calib.intrinsics.checks.
intrinsics_verdict`): the worst projection sigma where the views' boards reach against
:data:`~backend.core.verdict.PROJECTION_TOLERANCE_PX`, and, as the independent cross-check, two calibrations from
the two halves of the views compared across the image (:mod:`backend.calib.intrinsics.crossval`): halves that
differ by more than their sigmas are model error, and the verdict names the fixes. A leave-one-view-out jackknife
is reported beside the sigmas as a further cross-check (:func:`_jackknife_report`), not as them.
"""


from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal, NamedTuple

import cv2
import numpy as np

from backend.calib.board.coverage import view_parameters
from backend.calib.board.detection import Detection
from backend.calib.board.pose import board_pose
from backend.calib.intrinsics import photogrammetric, splined
from backend.calib.intrinsics.checks import intrinsics_verdict
from backend.calib.intrinsics.crossval import grid_pixels, projection_difference
from backend.calib.intrinsics.flex import FLEX_MAX_STD_M, Prior, flex_columns, flex_unsupported, refine_with_flex
from backend.calib.intrinsics.projection import project_board
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics, CameraModelName
from backend.core.errors import InputError
from backend.core.markers import marker_centres
from backend.core.result import ProgressCallback, SolveResult, jackknife_std, no_progress
from backend.core.splined import SplineGrid
from backend.core.transforms import from_rvec_tvec, skew, to_rvec_tvec
from backend.core.uncertainty import sigmas
from backend.core.verdict import Verdict

MIN_VIEWS = 3
MIN_VIEW_SPREAD = 0.1
"""Smallest summed spread of the ROS view parameters (x, y, size, skew) before all views count as alike."""
MAX_RELATIVE_FOCAL_STD = 0.05
"""A focal length less certain than this fraction means the views cannot pin down the camera."""
UNCERTAINTY_GRID = (16, 9)
CORNER_OUTLIER_SIGMAS = 4.29
"""A corner is an outlier when its residual is longer than this many per-axis sigmas of the corner noise: a 2D
Gaussian residual is that long once in 10,000 corners (chi-squared, 2 degrees of freedom), so a clean set loses none;
mrcal rejected none of the shared real sets' corners either (``benchmarks/intrinsics_vs_mrcal.py``). The sigma is
the larger of every residual's RMS per axis and the view's own robust one (its median residual length over 1.1774,
the median of a 2D Gaussian's): a view seen steeply or blurred is noisier as a whole, which is not a corner's fault
(the view-level outlier flag speaks for it), while a corner off its own view's noise is."""
MEDIAN_RESIDUAL_SIGMAS = float(np.sqrt(2.0 * np.log(2.0)))
"""The median length of a 2D Gaussian residual, in per-axis sigmas (1.1774)."""
MAX_REJECTED_SHARE = 0.25
"""A view that would lose more than this share of its corners is dropped whole, and named: then the view (a wrong
board pose, a smeared image), not a few corners, is bad."""
MAX_REJECTION_ROUNDS = 5
"""Solve-and-reject rounds at most; each round's noise estimate no longer carries the corners rejected before."""
KNOTS_RANGE = (4, 40)
"""The knots a splined model may have across and down: a cubic spline needs 4; 40 x 40 is 3,200 spline values."""
TERM_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
SEED_RADIUS = 0.7
"""Views whose corners all lie within this fraction of the half-diagonal from the image centre seed a second
solve (:func:`_calibrate`): near the centre distortion is mild, so their solve starts near the lens."""
SETTLED_RMS_PX = 0.1
"""A plain solve that fits its views this well (px RMS) is at the corner detector's noise floor and is kept without
the seeded second solve: the wrong minima seen fitted at 0.15-0.72 px, where the true lens fitted at 0.04 px."""


@dataclass
class IntrinsicsSettings:
    """What to estimate. Defaults: k1, k2, p1, p2 (no k3, no skew), free aspect."""

    model: CameraModelName | Literal["auto"] = "pinhole-radtan"
    """``auto``: the services compare the candidate models on held-out views first
    (:mod:`backend.calib.intrinsics.models`) and solve with the recommended one."""
    auto_for: Literal["any", "camera_info", "kalibr"] = "any"
    """With ``model="auto"``: recommend only a model this export carries
    (:data:`backend.calib.intrinsics.models.EXPORT_MODELS`); ``any``: every output model."""
    estimate_k3: bool = False
    """pinhole-radtan only: estimate k3 (else fixed at 0)."""
    estimate_tangential: bool = True
    """pinhole-radtan only: estimate p1, p2 (else fixed at 0)."""
    fix_aspect: bool = False
    """Keep fx / fy at 1 (square pixels)."""
    board_flex: bool = True
    """Solve the board's bow (mrcal's ``calobject_warp``, :mod:`backend.calib.intrinsics.flex`) with the lens; it is
    held at zero, and the result says why, for a test field, the photogrammetric model, or views that do not
    determine it."""
    reject_corners: bool = True
    """Leave out single corners whose residual is far beyond the corner noise, as mrcal does (:func:`_reject_corners`:
    a view losing more than :data:`MAX_REJECTED_SHARE` is dropped whole)."""
    drop_outliers: bool = False
    """Re-solve without views flagged as outliers."""
    outlier_factor: float = 3.0
    """A view is an outlier when its RMS exceeds this many times the median view RMS."""
    jackknife: bool = True
    """Also estimate sigmas by leaving out one view at a time, reported beside the noise model's as a cross-check
    (:func:`_jackknife_report`)."""
    cross_validate: bool = True
    """Also calibrate each half of the views and compare them (:func:`_cross_validate`), the verdict's cross-check."""
    pixel_size_um: float | None = None
    """The sensor's pixel pitch (um): the photogrammetric model's parameters are then reported in mm too."""
    spline_knots: tuple[int, int] | None = None
    """splined-stereographic only: the knots across and down (None: chosen from the views, :func:`~backend.calib.
    intrinsics.splined.choose_grid`; a solve's settings carry the knots it used)."""
    spline_fov_x_deg: float | None = None
    """splined-stereographic only: the field of view across (deg) the knots span (None: the image's plus a margin)."""

    @property
    def spline(self) -> SplineGrid | None:
        """The splined model's grid these settings name (None until both the knots and the field are set)."""
        if self.model != "splined-stereographic" or self.spline_knots is None or self.spline_fov_x_deg is None:
            return None
        return SplineGrid(*self.spline_knots, self.spline_fov_x_deg)

    def camera(self, size: tuple[int, int], K: np.ndarray, dist: np.ndarray) -> CameraIntrinsics:
        """The camera of a solve in these settings' model at ``size`` (width, height px)."""
        return CameraIntrinsics(self.model, size[0], size[1], K, dist, self.spline)


class Solve(NamedTuple):
    """One solve of a lens from board views: OpenCV's layout, and the board as solved."""

    K: np.ndarray
    dist: np.ndarray
    rvecs: list[np.ndarray]
    """Each view's board-to-camera rotation vector (3, 1)."""
    tvecs: list[np.ndarray]
    """Each view's board-to-camera translation (3, 1, m)."""
    board: BoardSpec
    """The board with its solved flex (``warp_m``), or as given when the flex was not solved."""


@dataclass
class View:
    """One image's board detection, named by its image."""

    name: str
    detection: Detection


@dataclass
class ViewResidual:
    """Per-view outcome of a solve."""

    name: str
    used: bool
    outlier: bool
    rms_px: float
    ids: np.ndarray
    residuals_px: np.ndarray
    """(N, 2) detected minus projected corner position (px)."""
    T_camera_board: np.ndarray | None
    rejected: RejectedCorners | None = None
    """The view's corners rejected as outliers, if any."""

    def to_record(self) -> dict:
        return {
            "image": self.name,
            "used": self.used,
            "outlier": self.outlier,
            "rms_px": self.rms_px,
            "ids": self.ids.tolist(),
            "residuals_px": np.round(self.residuals_px, 5).tolist(),
            "T_camera_board": None if self.T_camera_board is None else self.T_camera_board.tolist(),
            "rejected": None if self.rejected is None else self.rejected.to_record(),
        }


@dataclass
class RejectedCorners:
    """One view's corners rejected as outliers (:func:`_reject_corners`): where they were and how far off."""

    ids: np.ndarray
    corners_px: np.ndarray
    """(N, 2) their detected positions (px)."""
    residuals_px: np.ndarray
    """(N, 2) detected minus projected (px) in the round that rejected each."""
    view_dropped: bool
    """More than :data:`MAX_REJECTED_SHARE` of the view's corners were outliers: the whole view was left out."""

    def to_record(self) -> dict:
        return {"ids": self.ids.tolist(), "corners_px": np.round(self.corners_px, 3).tolist(),
                "residuals_px": np.round(self.residuals_px, 4).tolist(), "view_dropped": self.view_dropped}


@dataclass
class IntrinsicsResult(SolveResult):
    kind = "intrinsics"

    camera: CameraIntrinsics
    board: BoardSpec
    settings: IntrinsicsSettings
    rms_px: float
    views: list[ViewResidual]
    std: dict[str, Any]
    """1-sigma of fx, fy, cx, cy (px) and of each dist coefficient (0 where fixed)."""
    correlation_names: list[str]
    correlation: np.ndarray
    projection_uncertainty: dict[str, Any]
    seconds: float
    corners: dict[str, Any]
    """Which corner set was solved with (``sb`` or a refinement such as ``refined-0.3``) and each set's RMS (px)
    on these views."""
    cross_validation: dict[str, Any]
    """:func:`_cross_validate`'s outcome: ``status`` ``consistent``, ``inconsistent`` or ``not made`` (and why)."""
    verdict: Verdict
    warnings: list[str] = field(default_factory=list)
    model_comparison: dict[str, Any] | None = None
    """With ``model="auto"``: the held-out comparison of the candidate models and the recommendation."""
    photogrammetric: dict[str, Any] | None = None
    """With the ``photogrammetric`` model: :func:`backend.calib.intrinsics.photogrammetric.report`."""
    splined: dict[str, Any] | None = None
    """With the ``splined-stereographic`` model: :func:`backend.calib.intrinsics.splined.knots_report`."""
    jackknife: dict[str, Any] | None = None
    """The views' jackknife beside the noise model's sigmas (:func:`_jackknife_report`), a cross-check; None when
    switched off."""
    board_flex: dict[str, Any] = field(default_factory=lambda: {"status": "not solved", "warp_mm": [0.0, 0.0],
                                                                "std_mm": None, "detail": "not asked"})
    """The board's bow (:func:`_flex_report`); ``board`` carries it as ``warp_m``."""

    def summary(self) -> dict[str, Any]:
        unc = self.projection_uncertainty
        return {
            "camera": self.camera.to_dict(),
            "rms_px": self.rms_px,
            "views": [{"image": v.name, "rms_px": v.rms_px, "used": v.used,
                       "rejected_corners": 0 if v.rejected is None else len(v.rejected.ids)} for v in self.views],
            "rejected_corners": sum(len(v.rejected.ids) for v in self.views if v.rejected is not None),
            "views_dropped": [v.name for v in self.views if v.rejected is not None and v.rejected.view_dropped],
            "std": self.std,
            "correlation": {"names": self.correlation_names, "matrix": self.correlation.tolist()},
            "projection_sigma_px": {"max": unc["max_px"], "mean": unc["mean_px"], "centre": unc["centre_px"]},
            "corners": self.corners,
            "board_flex": self.board_flex,
            "jackknife": self.jackknife,
            "cross_validation": {k: v for k, v in self.cross_validation.items()
                                 if k not in ("difference_px", "expected_px")},
            "model_comparison": self.model_comparison,
            **({"photogrammetric": self.photogrammetric} if self.photogrammetric else {}),
            **({"splined": self.splined} if self.splined else {}),
            "verdict": self.verdict.to_dict(),
            "seconds": self.seconds,
        }

    def to_record(self) -> dict[str, Any]:
        record = self.summary()
        record.update(
            kind=self.kind,
            board=str(self.board),
            settings=asdict(self.settings),
            views=[v.to_record() for v in self.views],
            projection_uncertainty=self.projection_uncertainty,
            cross_validation=self.cross_validation,
            warnings=self.warnings,
        )
        return record


def _check_views(views: list[View], board: BoardSpec) -> None:
    """Reject too few or all-alike views before solving, naming what to do."""
    if len(views) < MIN_VIEWS:
        names = ", ".join(v.name for v in views) or "none"
        raise InputError(
            f"only {len(views)} usable view(s) ({names}); at least {MIN_VIEWS} are needed - "
            "capture more images with the whole board visible at different positions and tilts",
            "views",
        )
    params = np.array([view_parameters(v.detection, board) for v in views])
    spread = float((params.max(axis=0) - params.min(axis=0)).sum())
    if spread < MIN_VIEW_SPREAD:
        raise InputError(
            f"all {len(views)} views show the board in nearly the same place, size and angle "
            f"(spread {spread:.3f} < {MIN_VIEW_SPREAD}); move and tilt the board between captures",
            "views",
        )


def _calibrate(views: list[View], board: BoardSpec, size: tuple[int, int], settings: IntrinsicsSettings,
               guess: CameraIntrinsics | None = None) -> Solve:
    """The solve of ``views`` in ``settings.model``, from ``guess`` if given, with the board's flex when
    ``settings.board_flex`` and the target can bow (:func:`~backend.calib.intrinsics.flex.refine_with_flex`, from
    OpenCV's solve with ``board`` as given; its ``warp_m`` is the flex's start)."""
    if settings.model == "splined-stereographic":
        return _splined_calibrate(views, board, size, settings, guess)
    solve = _opencv_calibrate(views, board, size, settings, guess)
    if not settings.board_flex or flex_unsupported(board, settings.model):
        return solve
    camera = settings.camera(size, solve.K, solve.dist)
    return Solve(*refine_with_flex(camera, _free_intrinsics(camera, settings), board, [v.detection for v in views],
                                   solve.rvecs, solve.tvecs))


def _splined_calibrate(views: list[View], board: BoardSpec, size: tuple[int, int], settings: IntrinsicsSettings,
                       guess: CameraIntrinsics | None = None) -> Solve:
    """mrcal's splined model (:mod:`backend.calib.intrinsics.splined`) solved from ``guess`` (the views posed by it),
    or else from the views' OpenCV solve in :func:`_opencv_settings` (its flex and poses too), over the control
    points, every view's pose and, when ``settings`` solve it, the board's flex, with mrcal's regularization."""
    detections = [v.detection for v in views]
    if guess is None:
        K, dist, rvecs, tvecs, board = _calibrate(views, board, size, _opencv_settings(settings))
        guess = splined.start_camera(CameraIntrinsics("pinhole-radtan", size[0], size[1], K, dist), settings.spline,
                                     _measurements(detections))
    else:
        poses = [board_pose(guess, board, d) for d in detections]
        if any(T is None for T in poses):
            raise InputError("a view's board could not be posed from the starting camera", "views")
        rvecs, tvecs = zip(*(to_rvec_tvec(T) for T in poses), strict=True)
    return Solve(*refine_with_flex(guess, _free_intrinsics(guess, settings), board, detections, rvecs, tvecs,
                                   solve_flex=_solves_flex(board, settings), prior=_prior(guess, detections)))


def _opencv_settings(settings: IntrinsicsSettings) -> IntrinsicsSettings:
    """The OpenCV solve a splined solve starts from: k1-k3 and tangential, ``settings``' aspect and flex."""
    return replace(settings, model="pinhole-radtan", estimate_k3=True, estimate_tangential=True, jackknife=False,
                   cross_validate=False, spline_knots=None, spline_fov_x_deg=None)


def _measurements(detections: list[Detection]) -> int:
    """The corner coordinates (x and y each) ``detections`` measure."""
    return 2 * sum(len(d.ids) for d in detections)


def _prior(camera: CameraIntrinsics, detections: list[Detection]) -> Prior | None:
    """The splined model's regularization for a solve of ``detections`` (:func:`~backend.calib.intrinsics.splined.
    regularization`); None for the other models."""
    if camera.spline is None:
        return None
    n_measurements = _measurements(detections)
    return lambda model: splined.regularization(model, n_measurements)


def _resolved_spline(views: list[View], board: BoardSpec, size: tuple[int, int],
                     settings: IntrinsicsSettings) -> IntrinsicsSettings:
    """``settings`` with the splined model's knots and field of view set: as given, or chosen from the views'
    OpenCV solve (:func:`~backend.calib.intrinsics.splined.choose_grid`). Refuses a test field, and knots the views'
    corners cannot measure (:func:`~backend.calib.intrinsics.splined.check_measurements`). Other models' settings
    are returned as they are."""
    if settings.model != "splined-stereographic":
        return settings
    if not isinstance(board, BoardSpec):
        raise InputError("the splined model is solved from board views, not a surveyed test field: solve the "
                         "test field with the photogrammetric model", "model")
    knots, fov = settings.spline_knots, settings.spline_fov_x_deg
    if knots is not None and not all(KNOTS_RANGE[0] <= k <= KNOTS_RANGE[1] for k in knots):
        raise InputError(f"spline_knots is {tuple(knots)}; expected the knots across and down, each "
                         f"{KNOTS_RANGE[0]} to {KNOTS_RANGE[1]}", "spline_knots")
    if fov is not None and not 0 < fov < 360:
        raise InputError(f"spline_fov_x_deg is {fov}; expected the field of view across in degrees, between 0 and 360",
                         "spline_fov_x_deg")
    n_measurements = _measurements([v.detection for v in views])
    if settings.spline is None:
        K, dist, *_ = _opencv_calibrate(views, board, size, _opencv_settings(settings))
        grid = splined.choose_grid(CameraIntrinsics("pinhole-radtan", size[0], size[1], K, dist), n_measurements,
                                   settings.spline_knots, settings.spline_fov_x_deg)
        settings = replace(settings, spline_knots=(grid.nx, grid.ny), spline_fov_x_deg=grid.fov_x_deg)
    splined.check_measurements(settings.spline, len(views), [v.detection.corners_px for v in views], size)
    return settings


def _opencv_calibrate(views: list[View], board: BoardSpec, size: tuple[int, int], settings: IntrinsicsSettings,
                      guess: CameraIntrinsics | None = None) -> Solve:
    """The solve of ``views`` in ``settings.model`` with ``board`` held as given, from ``guess`` if given.

    Without a guess, OpenCV starts from a distortion-free camera, and with a strong lens and boards in the
    image corners it can settle in a wrong minimum (the demo's wide lens: 0.72 px RMS and fx 3 px off, where
    the true lens fits to 0.04 px). So the views near the centre (:data:`SEED_RADIUS`) are solved first and
    all views are solved again from there, as mrcal seeds its solves from the image centre's points; the
    solve that fits all views better is kept. A plain solve within :data:`SETTLED_RMS_PX` is kept at once.
    Raises the plain solve's :class:`InputError` when neither runs. The photogrammetric model starts from
    this solve of OpenCV's model (:func:`_photogrammetric_calibrate`).
    """
    if settings.model == "photogrammetric":
        return Solve(*_photogrammetric_calibrate(views, board, size, guess), board)
    if guess is not None:
        return _opencv_solve(views, board, size, settings, guess)
    scored, failure = [], None  # (RMS over all views in px, solve) of each solve that ran
    try:
        plain = _opencv_solve(views, board, size, settings)
        scored.append((_solve_rms(views, size, settings, plain), plain))
    except InputError as exc:  # OpenCV's fisheye start can fail on a view the seeded solve gets past
        failure = exc
    if scored and scored[0][0] <= SETTLED_RMS_PX:
        return plain
    centre = np.array(size, float) / 2
    inner = [v for v in views
             if np.linalg.norm(v.detection.corners_px - centre, axis=1).max() < SEED_RADIUS * np.linalg.norm(centre)]
    if MIN_VIEWS <= len(inner) < len(views):
        try:
            K, dist, *_ = _opencv_solve(inner, board, size, settings)
            seeded = _opencv_solve(views, board, size, settings, settings.camera(size, K, dist))
            scored.append((_solve_rms(views, size, settings, seeded), seeded))
        except (InputError, cv2.error):  # the inner views alone do not pin the lens down
            pass
    if not scored:
        raise failure
    return min(scored, key=lambda rms_solve: rms_solve[0])[1]


def _photogrammetric_calibrate(views: list[View], board: BoardSpec, size: tuple[int, int],
                               guess: CameraIntrinsics | None):
    """The photogrammetric bundle adjustment of ``views``, from ``guess`` or else from OpenCV's five-coefficient
    solve with ``fx = fy`` (the model with ``A1 = A2 = 0``); returns (K, dist, rvecs, tvecs)."""
    if guess is None:
        K, dist, rvecs, tvecs, _ = _opencv_calibrate(views, board, size,
                                                     IntrinsicsSettings(estimate_k3=True, fix_aspect=True))
        guess = photogrammetric.start_from_opencv(K, dist, size)
    else:
        poses = [board_pose(guess, board, v.detection) for v in views]
        if any(T is None for T in poses):
            raise InputError("a view's board could not be posed from the starting camera", "views")
        rvecs, tvecs = zip(*(to_rvec_tvec(T) for T in poses), strict=True)
    return photogrammetric.bundle_adjust(guess, [v.detection.object_points(board) for v in views],
                                         [v.detection.corners_px for v in views], list(rvecs), list(tvecs))


def _solve_residuals(views: list[View], size: tuple[int, int], settings: IntrinsicsSettings,
                     solve: Solve) -> list[np.ndarray]:
    """Each view's (N, 2) detected minus projected corners (px) under a ``solve`` in ``settings``' model."""
    camera = settings.camera(size, solve.K, solve.dist)
    return [v.detection.corners_px - project_board(camera, v.detection.object_points(solve.board), r, t)[0]
            for v, r, t in zip(views, solve.rvecs, solve.tvecs, strict=True)]


def _solve_rms(views: list[View], size: tuple[int, int], settings: IntrinsicsSettings, solve: Solve) -> float:
    """Reprojection RMS (px) of ``views`` under a ``solve`` in ``settings``' model."""
    residuals = np.concatenate(_solve_residuals(views, size, settings, solve))
    return float(np.sqrt(np.mean(np.sum(residuals**2, axis=1))))


def _kept_corners(detection: Detection, keep: np.ndarray) -> Detection:
    """``detection`` with only the corners where ``keep`` (N,) is true (their refinements and markers too)."""
    return replace(detection, corners_px=detection.corners_px[keep], ids=detection.ids[keep],
                   refined={name: corners[keep] for name, corners in detection.refined.items()},
                   marker_corners_px=None if detection.marker_corners_px is None else detection.marker_corners_px[keep])


def _picked_and_rejected(views: list[View], board: BoardSpec, size: tuple[int, int], settings: IntrinsicsSettings,
                         progress: ProgressCallback
                         ) -> tuple[list[View], list[View], dict[str, RejectedCorners], Solve, dict[str, Any]]:
    """The views in the corner set that fits best (:func:`_pick_corners`, through the lens for a test field) and
    :func:`_reject_corners`' outcome on them: the views (every one, in the chosen set), those kept, what was
    rejected, the solve and the corner choice. A view dropped whole does not vote for the corner set either: when
    any is dropped, the set is chosen again without it and, if that choice differs, the rest is solved again in it,
    as if the dropped view had not been taken."""
    picked, corners = _pick_corners(views, board, size, settings)
    picked = _through_the_lens(picked, board, size, settings)
    progress(0.1, f"solving {settings.model} from {len(picked)} views")
    kept, rejected, solve = _reject_corners(picked, board, size, settings, progress)
    dropped = {name for name, report in rejected.items() if report.view_dropped}
    if not dropped:
        return picked, kept, rejected, solve, corners
    again, corners_again = _pick_corners([v for v in views if v.name not in dropped], board, size, settings)
    if corners_again["chosen"] == corners["chosen"]:
        return picked, kept, rejected, solve, corners
    again = _through_the_lens(again, board, size, settings)
    kept, rejected_again, solve = _reject_corners(again, board, size, settings, progress)
    by_name = {v.name: v for v in again}
    return ([by_name.get(v.name, v) for v in picked], kept,
            {name: report for name, report in rejected.items() if name in dropped} | rejected_again, solve,
            corners_again | {"why": corners_again["why"] + f", chosen again without the dropped {sorted(dropped)}"})


def _reject_corners(views: list[View], board: BoardSpec, size: tuple[int, int], settings: IntrinsicsSettings,
                    progress: ProgressCallback) -> tuple[list[View], dict[str, RejectedCorners], Solve]:
    """mrcal's outlier rejection, corner by corner: solve, drop every corner whose residual is longer than
    :data:`CORNER_OUTLIER_SIGMAS` per-axis sigmas of the noise (all residuals', or its view's own where that is
    larger), solve again, until none is (at most
    :data:`MAX_REJECTION_ROUNDS`). A view that would lose more than :data:`MAX_REJECTED_SHARE` of its corners is
    dropped whole instead. Returns the views kept (with their outlier corners taken out), what was rejected of each
    view that lost any, and the last solve of the views kept."""
    detected = {v.name: len(v.detection.ids) for v in views}
    rejected: dict[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = {}
    dropped: set[str] = set()
    for round_index in range(MAX_REJECTION_ROUNDS if settings.reject_corners else 0):
        _check_views(views, board)
        solve = _calibrate(views, board, size, settings)
        residuals = _solve_residuals(views, size, settings, solve)
        noise_px = np.sqrt(np.mean(np.concatenate(residuals) ** 2))
        lengths = [np.linalg.norm(r, axis=1) for r in residuals]
        outliers = [length > CORNER_OUTLIER_SIGMAS * max(noise_px, np.median(length) / MEDIAN_RESIDUAL_SIGMAS)
                    for length in lengths]
        if not any(o.any() for o in outliers):
            break
        progress(0.1, f"rejecting outlier corners (round {round_index + 1}): {sum(map(np.sum, outliers))} beyond "
                      f"{CORNER_OUTLIER_SIGMAS * noise_px:.2f} px or their view's noise")
        kept = []
        for view, residual, outlier in zip(views, residuals, outliers, strict=True):
            if outlier.any():
                rejected.setdefault(view.name, []).append(
                    (view.detection.ids[outlier], view.detection.corners_px[outlier], residual[outlier]))
                if sum(len(ids) for ids, _, _ in rejected[view.name]) > MAX_REJECTED_SHARE * detected[view.name]:
                    dropped.add(view.name)
                    continue
                view = View(view.name, _kept_corners(view.detection, ~outlier))
            kept.append(view)
        views = kept
    else:
        _check_views(views, board)
        solve = _calibrate(views, board, size, settings)
    report = {name: RejectedCorners(np.concatenate([ids for ids, _, _ in parts]),
                                    np.vstack([px for _, px, _ in parts]), np.vstack([r for _, _, r in parts]),
                                    name in dropped)
              for name, parts in rejected.items()}
    return views, report, solve


def _opencv_solve(views: list[View], board: BoardSpec, size: tuple[int, int], settings: IntrinsicsSettings,
                  guess: CameraIntrinsics | None = None) -> Solve:
    """One run of OpenCV's solver with ``board`` as given, from ``guess`` if given (else from :func:`planar_start`
    for a target that is not planar)."""
    object_points = [v.detection.object_points(board).astype(np.float64).reshape(-1, 1, 3) for v in views]
    image_points = [v.detection.corners_px.reshape(-1, 1, 2) for v in views]
    if guess is None and (K_start := planar_start(views, board, size)) is not None:
        guess = CameraIntrinsics(settings.model, size[0], size[1], K_start)
    if settings.model == "fisheye-equidistant":
        flags = cv2.fisheye.CALIB_RECOMPUTE_EXTRINSIC | cv2.fisheye.CALIB_FIX_SKEW
        flags |= cv2.fisheye.CALIB_USE_INTRINSIC_GUESS if guess else 0
        try:
            _, K, dist, rvecs, tvecs = cv2.fisheye.calibrate(
                object_points, image_points, size, guess.K.copy() if guess else None,
                guess.dist[:4].copy() if guess else None, flags=flags, criteria=TERM_CRITERIA)
        except cv2.error as exc:
            raise InputError(f"the fisheye solve failed ({exc.err}); check the board spec and add varied views",
                             "views") from None
        return Solve(K, dist.ravel(), rvecs, tvecs, board)
    flags = cv2.CALIB_FIX_K3 * (not settings.estimate_k3) | cv2.CALIB_ZERO_TANGENT_DIST * (
        not settings.estimate_tangential) | cv2.CALIB_FIX_ASPECT_RATIO * settings.fix_aspect
    flags |= cv2.CALIB_USE_INTRINSIC_GUESS if guess else 0
    _, K, dist, rvecs, tvecs = cv2.calibrateCamera([p.astype(np.float32) for p in object_points],
                                                   [p.astype(np.float32) for p in image_points], size,
                                                   guess.K.copy() if guess else np.eye(3),
                                                   guess.dist.copy() if guess else None,
                                                   flags=flags, criteria=TERM_CRITERIA)
    return Solve(K, dist.ravel()[:5], rvecs, tvecs, board)


def planar_start(views: list[View], board: BoardSpec, size: tuple[int, int]) -> np.ndarray | None:
    """A start K for OpenCV's solve of a target whose points are not on one plane (a surveyed test field), or None
    for a planar one. OpenCV initialises only planar targets by itself, so the points are flattened onto the
    target's best-fitting plane (``board.plane_xy``) and that distortion-free solve's K is the start."""
    if not np.any(board.object_points[:, 2]):
        return None
    flat = np.column_stack([board.plane_xy, np.zeros(len(board.plane_xy))]).astype(np.float32)
    _, K, _, _, _ = cv2.calibrateCamera([flat[v.detection.ids] for v in views],
                                        [v.detection.corners_px.astype(np.float32) for v in views], size, None, None,
                                        flags=cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3
                                        | cv2.CALIB_ZERO_TANGENT_DIST, criteria=TERM_CRITERIA)
    return K


def _free_intrinsics(camera: CameraIntrinsics, settings: IntrinsicsSettings) -> np.ndarray:
    """Matrix A (n_all x n_free) mapping free intrinsic parameters to [fx, fy, cx, cy, dist...].

    The photogrammetric model has one principal distance: ``fy`` moves with ``fx`` as with ``fix_aspect``. The
    splined model holds ``fx, fy, cx, cy`` as mrcal does: the spline takes up what they would.
    """
    names = ["fx", "fy", "cx", "cy", *camera.dist_names]
    tied = (settings.fix_aspect or camera.model == "photogrammetric") and camera.spline is None
    fixed = {"fx", "fy", "cx", "cy"} if camera.spline is not None else set()
    if camera.model == "pinhole-radtan":
        fixed |= set() if settings.estimate_k3 else {"k3"}
        fixed |= set() if settings.estimate_tangential else {"p1", "p2"}
    columns = []
    for i, name in enumerate(names):
        if name in fixed or (name == "fy" and tied):
            continue
        column = np.zeros(len(names))
        column[i] = 1.0
        if name == "fx" and tied:
            column[1] = camera.K[1, 1] / camera.K[0, 0]  # fy moves with fx at the fixed ratio
        columns.append(column)
    return np.column_stack(columns)


def _covariance(camera: CameraIntrinsics, views: list[View], board: BoardSpec, rvecs, tvecs, used: np.ndarray,
                A: np.ndarray, flex: bool = False
                ) -> tuple[list[tuple[np.ndarray, np.ndarray]], np.ndarray, np.ndarray]:
    """Residuals and pose of every view, the covariance of [fx, fy, cx, cy, dist...], and the covariance over
    the free intrinsics (``A``'s columns), every used view's ``rvec`` and ``tvec`` and, with ``flex``, the board's
    flex along x and y (m; the last two, :func:`~backend.calib.intrinsics.flex.flex_columns`).

    ``rvecs``/``tvecs`` are OpenCV's poses of the used views; excluded views get a
    pose by PnP so their residuals can still be shown. The splined model's regularization (:func:`_prior`) enters as
    mrcal's does. Covariance units are px^2
    for fx, fy, cx, cy and the distortion coefficients' units squared (unitless in OpenCV's models).
    """
    n_free = A.shape[1]
    n_used = int(np.count_nonzero(used))
    blocks, rows_r, residuals = [], [], []
    k = 0
    for view, is_used in zip(views, used, strict=True):
        obj = view.detection.object_points(board)
        if is_used:
            rvec, tvec = rvecs[k], tvecs[k]
            k += 1
        else:  # an excluded view still gets a pose for its residuals (PnP with the solved model)
            rvec, tvec = to_rvec_tvec(board_pose(camera, board, view.detection))
        uv, J = project_board(camera, obj, rvec, tvec)
        residuals.append((view.detection.corners_px - uv, from_rvec_tvec(rvec, tvec)))
        if is_used:
            blocks.append((J, flex_columns(J, rvec, board.warp_basis[view.detection.ids]) if flex else None))
            rows_r.append((view.detection.corners_px - uv).ravel())
    n_rows = sum(J.shape[0] for J, _ in blocks)
    jac = np.zeros((n_rows, n_free + 6 * n_used + 2 * flex))
    row = 0
    for i, (J, J_flex) in enumerate(blocks):
        jac[row:row + len(J), :n_free] = J[:, 6:] @ A
        jac[row:row + len(J), n_free + 6 * i: n_free + 6 * i + 6] = J[:, :6]
        if flex:
            jac[row:row + len(J), -2:] = J_flex
        row += len(J)
    r = np.concatenate(rows_r)
    dof = max(len(r) - jac.shape[1], 1)
    sigma2 = float(r @ r / dof)
    prior = _prior(camera, [v.detection for v, u in zip(views, used, strict=True) if u])
    prior_rows = np.zeros((0, jac.shape[1]))
    if prior is not None:
        J_prior = prior(camera)[1] @ A
        prior_rows = np.zeros((len(J_prior), jac.shape[1]))
        prior_rows[:, :n_free] = J_prior
    # Scale columns to unit norm first: focal lengths (~1e3 px) and k3 (~1e-1) differ by
    # orders of magnitude, and the scaled normal matrix inverts to full precision.
    scale = 1.0 / np.maximum(np.linalg.norm(np.vstack([jac, prior_rows]), axis=0), 1e-300)
    normal = (jac * scale).T @ (jac * scale)
    if prior is None:
        cov_all = sigma2 * scale[:, None] * np.linalg.pinv(normal, hermitian=True) * scale[None, :]
    else:  # mrcal's: the prior shapes the solution, but only the corners carry noise (N^-1 J_c^T J_c N^-1)
        inverse = np.linalg.pinv(normal + (prior_rows * scale).T @ (prior_rows * scale), hermitian=True)
        cov_all = sigma2 * scale[:, None] * (inverse @ normal @ inverse) * scale[None, :]
    cov_all = 0.5 * (cov_all + cov_all.T)
    return residuals, A @ cov_all[:n_free, :n_free] @ A.T, cov_all


def _jackknife_std(views: list[View], board: BoardSpec, camera: CameraIntrinsics, settings: IntrinsicsSettings,
                   progress: ProgressCallback) -> np.ndarray:
    """Leave-one-view-out jackknife standard deviation of [fx, fy, cx, cy, dist...].

    Views, not corners, are the independent units: lighting, blur and board
    flatness shift all corners of a view together, which the i.i.d. corner-noise
    covariance cannot see (:func:`~backend.core.result.jackknife_std`). ``board`` is held as the full solve left it
    (its flex too): the jackknife spreads the lens, and solving the bow again for every view left out made the
    demo's 48-view solve four times slower.
    """
    estimates, held = [], replace(settings, board_flex=False)
    for i in range(len(views)):
        progress(0.6 + 0.3 * i / len(views), f"jackknife: re-solving without view {i + 1} of {len(views)}")
        K, dist, *_ = _calibrate(views[:i] + views[i + 1:], board, camera.image_size, held, camera)
        estimates.append(np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], dist.ravel()])
    return jackknife_std(np.array(estimates))


def _far_point_jacobians(camera: CameraIntrinsics) -> np.ndarray:
    """(cells, 2, 6 + intrinsics) Jacobian of projecting the far point each :data:`UNCERTAINTY_GRID` cell sees, in
    :func:`~backend.calib.intrinsics.projection.project_board`'s column order: a turn of the point about the
    camera's origin (3), a shift (3), the intrinsics."""
    xy = camera.undistort_points(grid_pixels(camera.width, camera.height, UNCERTAINTY_GRID))
    _, J = project_board(camera, np.column_stack([xy, np.ones(len(xy))]), np.zeros(3), np.zeros(3))
    return J.reshape(len(xy), 2, -1)


def _sigma_grid(J: np.ndarray, cov: np.ndarray) -> dict[str, Any]:
    """The worst-direction 1-sigma (px) of each grid cell's projection, ``J`` (cells, 2, P) of parameters with
    covariance ``cov`` (P, P), over the grid, its mean, worst and centre."""
    cols, rows = UNCERTAINTY_GRID
    cov_uv = J @ cov @ J.transpose(0, 2, 1)
    worst = np.sqrt(np.clip(np.linalg.eigvalsh(cov_uv)[:, -1], 0, None)).reshape(rows, cols)
    return {"grid": [cols, rows], "sigma_px": np.round(worst, 5).tolist(), "mean_px": float(worst.mean()),
            "max_px": float(worst.max()), "centre_px": float(worst[rows // 2, cols // 2]), "range": "infinity"}


def _projection_uncertainty(camera: CameraIntrinsics, cov_intrinsics: np.ndarray) -> dict[str, Any]:
    """1-sigma (worst direction) error in pixels of projecting a far-away point, across the image.

    Only the intrinsics' uncertainty is propagated (points at infinity, so the board
    poses drop out), like mrcal's ``show-projection-uncertainty`` at infinite range.
    """
    return _sigma_grid(_far_point_jacobians(camera)[:, :, 6:], cov_intrinsics)


def _left_jacobian(rvec: np.ndarray) -> np.ndarray:
    """SO(3)'s left Jacobian at the rotation vector ``rvec`` (rad): a change ``d`` of the rotation vector turns the
    rotation by ``J_l(rvec) d`` (rad) about the axes it maps into, ``R(rvec + d) = exp(J_l d) R(rvec)``."""
    phi = np.asarray(rvec, float).ravel()
    theta = float(np.linalg.norm(phi))
    K = skew(phi[None])[0]
    if theta < 1e-8:
        return np.eye(3) + 0.5 * K
    return np.eye(3) + (1.0 - np.cos(theta)) / theta**2 * K + (theta - np.sin(theta)) / theta**3 * (K @ K)


def _noise_model_projection(camera: CameraIntrinsics, cov_all: np.ndarray, A: np.ndarray, rvecs,
                            corners_px: list[np.ndarray]) -> dict[str, Any]:
    """mrcal's projection uncertainty at infinity: the 1-sigma (worst direction, px) of where a far point seen at
    each grid cell projects, with the point tied to the boards, not to the camera.

    The camera's frame is defined by nothing but the boards' poses, so a perturbed solve may turn the camera
    against them; a far point fixed to the boards then turns with their mean rotation: ``v' = v + mean_i(dphi_i) x
    v`` with ``dphi_i = J_l(rvec_i) drvec_i`` each used view's change of rotation in the camera's axes
    (:func:`_left_jacobian`). With the intrinsics' change, the projection's Jacobian spans the free intrinsics and
    every used view's rotation, and ``cov_all`` (:func:`_covariance`, the poses marginalised by taking its block)
    propagates through it. The principal point's sigma, which such a turn takes up, then no longer counts against
    the centre, as it does when the intrinsics alone are propagated (:func:`_projection_uncertainty`).

    This is the result's projection sigma (``max_px`` over the whole image), and ``covered`` says which cells
    the views' boards reach (:func:`_covered_cells`, from each used view's ``corners_px``), with the worst sigma
    within them (``max_covered_px``, the one the verdict weighs) and beyond them (``max_uncovered_px``, None when
    every cell is reached).
    """
    J = _far_point_jacobians(camera)
    n_free = A.shape[1]
    full = np.zeros((len(J), 2, cov_all.shape[0]))
    full[:, :, :n_free] = J[:, :, 6:] @ A
    for i, rvec in enumerate(rvecs):  # J[..., :3]: d(projection)/d(a turn of the point about the camera's origin)
        full[:, :, n_free + 6 * i: n_free + 6 * i + 3] = J[:, :, :3] @ _left_jacobian(rvec) / len(rvecs)
    grid = _sigma_grid(full, cov_all)
    covered = _covered_cells(camera, corners_px)
    sigma = np.asarray(grid["sigma_px"])
    beyond = ("held by the splined model's regularization, not measured: the sigma there understates the error"
              if camera.spline is not None else "extrapolated")
    return grid | {"method": "noise model, the camera free to turn against the boards (mrcal's)",
                   "beyond_reach": beyond,
                   "covered": covered.tolist(), "covered_share": float(covered.mean()),
                   "max_covered_px": float(sigma[covered].max()) if covered.any() else None,
                   "max_uncovered_px": float(sigma[~covered].max()) if not covered.all() else None}


def _covered_cells(camera: CameraIntrinsics, corners_px: list[np.ndarray]) -> np.ndarray:
    """(rows, cols) of :data:`UNCERTAINTY_GRID`: whether a cell's centre lies within some view's board, the convex
    hull of its (N, 2) corners (px)."""
    pixels = grid_pixels(camera.width, camera.height, UNCERTAINTY_GRID).astype(np.float32)
    covered = np.zeros(len(pixels), bool)
    for corners in corners_px:
        hull = cv2.convexHull(np.asarray(corners, np.float32))
        covered |= np.array([cv2.pointPolygonTest(hull, (float(u), float(v)), False) >= 0 for u, v in pixels])
    cols, rows = UNCERTAINTY_GRID
    return covered.reshape(rows, cols)


def _jackknife_report(camera: CameraIntrinsics, cov: np.ndarray, std_jackknife: np.ndarray,
                      estimated: np.ndarray) -> dict[str, Any]:
    """The leave-one-view-out spread of ``[fx, fy, cx, cy, dist...]`` beside the noise model's (``cov``), a
    cross-check: ``std`` per parameter, ``ratio`` its largest over the noise model's, and the worst projection
    sigma either gives (the intrinsics alone, the noise model's correlations kept). Views, not corners, are the
    jackknife's units, so a ratio well above 1 says the corner errors are shared within views (a bowed board not
    modelled, blur, a lens the model cannot follow): the cross-validation then tells model error from chance."""
    d = np.where(estimated, sigmas(cov), 1.0)
    cov_jackknife = np.outer(std_jackknife, std_jackknife) * cov / np.outer(d, d)
    ratio = np.where(estimated, std_jackknife / d, 0.0)
    return {"std": std_jackknife.tolist(), "ratio": float(ratio.max()),
            "projection_max_px": _projection_uncertainty(camera, cov_jackknife)["max_px"],
            "noise_model_projection_max_px": _projection_uncertainty(camera, cov)["max_px"],
            "method": "leave one view out; the intrinsics alone propagated to a far point"}


def worst_projection_sigma_px(camera: CameraIntrinsics, cov_intrinsics: np.ndarray) -> float:
    """The largest 1-sigma (px) across the image of projecting a far point, from the covariance of
    [fx, fy, cx, cy, dist...] (:func:`_projection_uncertainty`'s ``max_px``)."""
    return float(_projection_uncertainty(camera, cov_intrinsics)["max_px"])


def _through_the_lens(views: list[View], board: BoardSpec, size: tuple[int, int],
                      settings: IntrinsicsSettings) -> list[View]:
    """A test field's views with each marker's centre found again through the lens a first solve gives
    (:func:`~backend.core.markers.marker_centres`): where a marker's diagonals cross in pixels is off its centre's
    image by up to 0.1 px on a strong lens, the same way in every view, which no number of views averages away.
    A board's views are returned as they are."""
    if any(v.detection.marker_corners_px is None for v in views):
        return views
    K, dist, *_ = _calibrate(views, board, size, settings)
    camera = settings.camera(size, K, dist)
    return [View(v.name, replace(v.detection, corners_px=marker_centres(v.detection.marker_corners_px, camera)))
            for v in views]


def _with_corners(views: list[View], corner_set: str) -> list[View]:
    """``views`` whose ``corners_px`` are the detector's own (``corner_set`` ``sb``) or one of its refinements."""
    if corner_set == "sb":
        return views
    return [View(v.name, replace(v.detection, corners_px=v.detection.refined[corner_set])) for v in views]


def _fit_rms(views: list[View], board: BoardSpec, size: tuple[int, int], settings: IntrinsicsSettings) -> float:
    """Reprojection RMS (px) of a plain solve (no uncertainty) on ``views``."""
    return _solve_rms(views, size, settings, _calibrate(views, board, size, settings))


def _pick_corners(views: list[View], board: BoardSpec, size: tuple[int, int],
                  settings: IntrinsicsSettings) -> tuple[list[View], dict[str, Any]]:
    """The views with the corner set (the detector's ``sb`` or a refinement) that fits ``settings``' model best.

    On rendered boards each set's RMS tracked its error against the true corners within 5 %, so the better
    fit is the more accurate set; a set only counts when every view has it.
    """
    shared = set.intersection(*(set(v.detection.refined) for v in views)) if views else set()
    if not shared:
        return views, {"chosen": "sb", "rms_px": {}, "why": "no refined corners (ChArUco, or detected live)"}
    rms = {name: _fit_rms(_with_corners(views, name), board, size, settings) for name in ["sb", *sorted(shared)]}
    chosen = min(rms, key=rms.get)
    return _with_corners(views, chosen), {"chosen": chosen, "rms_px": rms,
                                          "why": "the set whose corners fit the model best"}


def _solves_flex(board: BoardSpec, settings: IntrinsicsSettings) -> bool:
    """Whether a solve with ``settings`` solves ``board``'s flex."""
    return settings.board_flex and flex_unsupported(board, settings.model) is None


def _flex_std_m(cov_all: np.ndarray) -> np.ndarray:
    """The flex's 1-sigma along x and y (m) from :func:`_covariance`'s ``cov_all`` of a solve with the flex."""
    return np.sqrt(np.clip(np.diag(cov_all)[-2:], 0, None))


def _undetermined_flex(board: BoardSpec, settings: IntrinsicsSettings, cov_all: np.ndarray) -> str | None:
    """Why the board's flex is to be held at zero, when this solve solved it (``cov_all``: its covariance) and a term's
    sigma exceeds :data:`~backend.calib.intrinsics.flex.FLEX_MAX_STD_M`; None when it is determined or not solved."""
    if not _solves_flex(board, settings) or (std_m := _flex_std_m(cov_all)).max() <= FLEX_MAX_STD_M:
        return None
    return (f"the views do not determine it (sigma {1e3 * std_m.max():.2g} mm > {1e3 * FLEX_MAX_STD_M:.2g} mm); "
            "tilt the board 20-40 degrees in some views, about both its axes")


def _flex_report(board: BoardSpec, settings: IntrinsicsSettings, cov_all: np.ndarray,
                 note: str | None) -> dict[str, Any]:
    """The board's flex as the result gives it: ``status`` ``solved`` (with ``warp_mm`` and ``std_mm``, along x and
    y) or ``held at zero`` / ``not solved`` with ``detail``."""
    if _solves_flex(board, settings):
        return {"status": "solved", "warp_mm": [round(1e3 * w, 4) for w in board.warp_m],
                "std_mm": [round(1e3 * float(s), 4) for s in _flex_std_m(cov_all)],
                "detail": "the bow of the board's centre lines along x and y (mrcal's calobject_warp), solved with "
                          "the lens"}
    return {"status": "held at zero" if note else "not solved", "warp_mm": [0.0, 0.0], "std_mm": None,
            "detail": note or flex_unsupported(board, settings.model) or "switched off"}


def _cross_validate(views: list[View], board: BoardSpec, size: tuple[int, int],
                    settings: IntrinsicsSettings) -> dict[str, Any]:
    """Calibrate the even and the odd views apart and compare them across the image (mrcal's cross-validation).

    Each half carries the projection sigma the result reports (:func:`_noise_model_projection`), so where the
    halves differ by more than their sigmas the noise model does not explain the data: model error (a board's
    bow, a lens the model cannot follow) or bad views. Returns ``status`` ``consistent``, ``inconsistent`` or
    ``not made`` with a ``detail``, and the comparison's grids.
    """
    if len(views) < 2 * MIN_VIEWS:
        return {"status": "not made", "detail": f"{len(views)} views; two halves need at least {2 * MIN_VIEWS}"}
    halves = []
    for half in (views[0::2], views[1::2]):
        try:
            _check_views(half, board)
            K, dist, rvecs, tvecs, solved_board = _calibrate(half, board, size, settings)
        except InputError as exc:
            return {"status": "not made", "detail": f"a half of the views cannot be solved alone: {exc.message}"}
        camera = settings.camera(size, K, dist)
        A = _free_intrinsics(camera, settings)
        _, _, cov_all = _covariance(camera, half, solved_board, rvecs, tvecs, np.ones(len(half), bool), A,
                                    _solves_flex(solved_board, settings))
        sigma = _noise_model_projection(camera, cov_all, A, rvecs, [v.detection.corners_px for v in half])
        halves.append((camera, np.array(sigma["sigma_px"]), np.array(sigma["covered"])))
    (a, sigma_a, covered_a), (b, sigma_b, covered_b) = halves
    diff = projection_difference(a, sigma_a, b, sigma_b, UNCERTAINTY_GRID,
                                 covered_a & covered_b if a.spline is not None else None)
    detail = f"the halves ({len(views[0::2])} and {len(views[1::2])} views) " + _difference_phrase(diff)
    return {"status": "consistent" if diff["consistent"] else "inconsistent", "detail": detail, **diff}


def _difference_phrase(diff: dict[str, Any]) -> str:
    """How far the halves' projections differ (:func:`projection_difference`), each number said once: where
    they differ most against their sigma and, if elsewhere, where they differ most in pixels."""
    u, v = diff["worst_pixel"]
    phrase = (f"differ by {diff['worst_difference_px']:.3g} px at ({u:.0f}, {v:.0f}) px, where "
              f"{diff['worst_expected_px']:.3g} px is expected ({diff['worst_ratio']:.1f} sigma, the most against "
              "their sigma")
    if diff["max_difference_pixel"] == diff["worst_pixel"]:
        return phrase + ", and the most in pixels)"
    u, v = diff["max_difference_pixel"]
    return (phrase + f"); the most in pixels is {diff['max_difference_px']:.3g} px at ({u:.0f}, {v:.0f}) px "
                     f"({diff['max_difference_ratio']:.1f} sigma)")


def calibrate_intrinsics(
    views: list[View],
    board: BoardSpec,
    image_size: tuple[int, int],
    settings: IntrinsicsSettings | None = None,
    progress: ProgressCallback = no_progress,
) -> IntrinsicsResult:
    """Solve a camera's intrinsics from board views of one camera.

    ``image_size`` is (width, height) in pixels. Raises :class:`InputError` for
    too few views, all-alike views, or views that do not constrain the focal length.
    """
    settings = settings or IntrinsicsSettings()
    if settings.model == "auto":
        raise ValueError("model 'auto' is resolved by the services (intrinsics_models.solve_auto) before solving")
    started = time.perf_counter()
    for view in views:
        if tuple(view.detection.image_size) != tuple(image_size):
            raise InputError(f"{view.name} is {view.detection.image_size[0]}x{view.detection.image_size[1]} "
                             f"but the camera is {image_size[0]}x{image_size[1]}; all images must share one size",
                             view.name)
    progress(0.05, "picking the corner set that fits better")
    _check_views(views, board)
    settings = _resolved_spline(views, board, image_size, settings)
    views, kept, rejected, solve, corners = _picked_and_rejected(views, board, image_size, settings, progress)
    kept_by_name = {v.name: v for v in kept}
    views = [kept_by_name.get(v.name, v) for v in views]  # a view dropped whole keeps its corners, unused
    used = np.array([v.name in kept_by_name for v in views])
    flex_note, outliers_dropped = None, False
    while True:
        active = [v for v, u in zip(views, used, strict=True) if u]
        K, dist, rvecs, tvecs, board = solve
        camera = settings.camera(image_size, K, dist)
        progress(0.6 + 0.2 * outliers_dropped, "estimating uncertainty")
        A = _free_intrinsics(camera, settings)
        residuals, cov, cov_all = _covariance(camera, views, board, rvecs, tvecs, used, A,
                                              _solves_flex(board, settings))
        if not outliers_dropped and flex_note is None and (flex_note := _undetermined_flex(board, settings, cov_all)):
            settings = replace(settings, board_flex=False)  # the bow held at zero: solved again without it
            solve = _calibrate(active, board.with_warp((0.0, 0.0)), image_size, settings)
            continue
        view_rms = np.array([np.sqrt(np.mean(np.sum(r**2, axis=1))) for r, _ in residuals])
        outlier = used & (view_rms > settings.outlier_factor * np.median(view_rms[used]))
        if outliers_dropped or not (settings.drop_outliers and np.any(outlier)):
            break
        used, outliers_dropped = used & ~outlier, True  # solved again without the views flagged as outliers
        active = [v for v, u in zip(views, used, strict=True) if u]
        _check_views(active, board)
        solve = _calibrate(active, board, image_size, settings)

    std_all = sigmas(cov)
    if std_all[0] > MAX_RELATIVE_FOCAL_STD * camera.K[0, 0]:
        raise InputError(
            f"the views do not pin down the focal length (fx = {camera.K[0, 0]:.1f} +- {std_all[0]:.1f} px); "
            "tilt the board by 20-40 degrees in some views and fill more of the image",
            "views",
        )
    names = ["fx", "fy", "cx", "cy", *camera.dist_names]
    estimated = std_all > 0
    correlated = estimated & (camera.spline is None)  # a spline's hundreds of control points: no table
    corr_cov = cov[np.ix_(correlated, correlated)]
    d = np.sqrt(np.diag(corr_cov))
    correlation = corr_cov / np.outer(d, d)
    active = [v for v, u in zip(views, used, strict=True) if u]
    projection = _noise_model_projection(camera, cov_all, A, rvecs, [v.detection.corners_px for v in active])
    jackknife = (_jackknife_report(camera, cov, _jackknife_std(active, board, camera, settings, progress), estimated)
                 if settings.jackknife else None)
    progress(0.92, "cross-validating: solving each half of the views")
    cross_validation = (_cross_validate(active, board, image_size, replace(settings, jackknife=False))
                        if settings.cross_validate else {"status": "not made", "detail": "switched off"})
    all_res = np.concatenate([r for (r, _), u in zip(residuals, used, strict=True) if u])
    view_results = [
        ViewResidual(v.name, bool(u), bool(o), float(rms), v.detection.ids, r, T, rejected.get(v.name))
        for v, u, o, rms, (r, T) in zip(views, used, outlier, view_rms, residuals, strict=True)
    ]
    warnings = [f"{v.name}: reprojection RMS {v.rms_px:.2f} px is an outlier" for v in view_results if v.outlier]
    warnings += [f"{v.name}: {len(v.rejected.ids)} of {len(v.ids)} corners were outliers, more than "
                 f"{MAX_REJECTED_SHARE:.0%}: the view was dropped" for v in view_results
                 if v.rejected is not None and v.rejected.view_dropped]
    correlation_names = [n for n, e in zip(names, correlated, strict=True) if e]
    model_report = None
    if settings.model == "photogrammetric":  # one principal distance c: fy is fx, and is left out of the tables
        kept = [k for k, n in enumerate(correlation_names) if n != "fy"]
        correlation, correlation_names = correlation[np.ix_(kept, kept)], photogrammetric.INTERIOR
        model_report = photogrammetric.report(camera, np.delete(std_all, 1), correlation, cov_all, rvecs, tvecs,
                                              [v.name for v in active], settings.pixel_size_um)
    spline_report = (splined.knots_report(camera, [v.detection.corners_px for v in active],
                                          _measurements([v.detection for v in active]))
                     if camera.spline is not None else None)
    flex_report = _flex_report(board, settings, cov_all, flex_note)
    progress(1.0, "done")
    return IntrinsicsResult(
        camera=camera,
        board=board,
        settings=settings,
        rms_px=float(np.sqrt(np.mean(np.sum(all_res**2, axis=1)))),
        views=view_results,
        std={"fx": float(std_all[0]), "fy": float(std_all[1]), "cx": float(std_all[2]), "cy": float(std_all[3]),
             "dist": std_all[4:].tolist()},
        correlation_names=correlation_names,
        correlation=np.clip(correlation, -1, 1),
        projection_uncertainty=projection,
        seconds=time.perf_counter() - started,
        corners=corners,
        cross_validation=cross_validation,
        verdict=intrinsics_verdict(projection, cross_validation, flex_report, jackknife,
                                   splined=camera.spline is not None),
        warnings=warnings,
        photogrammetric=model_report,
        splined=spline_report,
        board_flex=flex_report,
        jackknife=jackknife,
    )
