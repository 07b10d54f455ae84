"""The verdict of a LiDAR-to-camera result and its cross-checks.

:func:`judge`: the sigmas against each method's tolerance, the cross-check between independent captures (the
target's poses; the targetless methods' places: the edges' two halves, the intensity method's leave one out) and any
extra check made elsewhere, such as another method on the same pairs (:func:`method_agreement`).

The cross-check between LiDAR-to-camera methods (edges against intensity, on the same pairs): the difference of
the two ``T_camera_lidar`` in the result's parameters (:func:`backend.core.transforms.params_between`: m along
the camera's axes, rad about the LiDAR's) against the combined 1-sigma ``sqrt(sigma_a^2 + sigma_b^2)`` per
parameter, the two estimates' errors being independent (different cues of the same data).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from backend.calib.lidar_camera.edges import MIN_HALVES_PLACES
from backend.calib.lidar_camera.intensity import MIN_SPREAD_PLACES
from backend.calib.lidar_camera.places import one_place_note
from backend.core.result import TRANSFORM_PARAMETERS, TransformResult, finite_or_none
from backend.core.transforms import params_between
from backend.core.verdict import CROSS_CHECK_SIGMAS, Verdict, VerdictBuilder, judge_transform_sigmas

AGREEMENT_SIGMAS = CROSS_CHECK_SIGMAS
"""Two methods agree when no parameter differs by more than this many combined sigmas."""


@dataclass
class MethodAgreement:
    """How far one method's transform is from another's, in metres, degrees and combined sigmas."""

    other_method: str
    difference: np.ndarray
    """(6,) the other's transform about this one's (m, m, m, rad, rad, rad)."""
    combined_std: np.ndarray
    """(6,) ``sqrt(sigma_a^2 + sigma_b^2)`` per parameter (same units; inf where either is undetermined)."""

    @property
    def normalised(self) -> np.ndarray:
        """(6,) ``|difference| / combined_std``."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.combined_std > 0, np.abs(self.difference) / self.combined_std, np.inf)

    @property
    def passed(self) -> bool:
        return bool(np.all(self.normalised <= AGREEMENT_SIGMAS))

    @property
    def sigmas(self) -> float:
        """The largest difference, in combined sigmas (the cross-check's measure)."""
        return float(np.max(self.normalised))

    def detail(self) -> str:
        """One line for the verdict's reasons."""
        worst = int(np.argmax(self.normalised))
        return (f"the {self.other_method} method's transform is {1000 * np.abs(self.difference[:3]).max():.1f} mm and "
                f"{np.degrees(np.abs(self.difference[3:]).max()):.3f} deg away, at most {self.normalised[worst]:.1f} "
                f"combined sigmas (parameter {worst + 1} of 6; agreement within {AGREEMENT_SIGMAS:g})")

    def to_record(self) -> dict[str, Any]:
        return {"other_method": self.other_method, "passed": self.passed,
                "difference_m": finite_or_none(self.difference[:3]),
                "difference_deg": finite_or_none(np.degrees(self.difference[3:])),
                "normalised": finite_or_none(self.normalised), "detail": self.detail()}


def compare_methods(T_a: np.ndarray, covariance_a: np.ndarray, T_b: np.ndarray, covariance_b: np.ndarray,
                    other_method: str) -> MethodAgreement:
    """The agreement of transform ``T_b`` (method ``other_method``) with ``T_a``; both covariances 6x6 over
    :data:`~backend.core.result.TRANSFORM_PARAMETERS` (m, rad)."""
    variance = np.clip(np.diag(covariance_a), 0, None) + np.clip(np.diag(covariance_b), 0, None)
    return MethodAgreement(other_method, params_between(T_a, T_b), np.sqrt(variance))


TOLERANCES = {"target": (0.01, 0.3), "corners": (0.01, 0.3), "vtarget": (0.01, 0.3), "edges": (0.02, 0.3),
              "intensity": (0.02, 0.3)}
"""Largest acceptable error per method, per axis: translation (m), rotation (deg). A board pins the LiDAR to a
centimetre; a targetless scene's edges are mostly far (10-40 m on a road), where they fix the rotation well and
the translation barely, so the edges method is allowed 2 cm (its translation is often held by a prior). A result is
trusted only when :data:`COVERAGE` sigmas fit inside them."""
COVERAGE = 3.0
"""The sigmas are judged against the :data:`TOLERANCES` divided by this: an error of up to three sigmas is to be
expected (on the simulated board, 12 poses: 0.23 deg off with a 0.13 deg sigma)."""
MAX_SPREAD_RATIO = CROSS_CHECK_SIGMAS
"""The target's leave-one-pose-out cross-check (:func:`_spread_check`) passes when the spread of the re-solves
without one pose is at most this many times the Jacobian's sigma on every parameter: the poses agree within their
noise. Beyond :data:`~backend.core.verdict.REJECT_SIGMAS` times, the poses do not agree and the result is
``reject`` (the cross-check rule of :mod:`backend.core.verdict`)."""
PAN_AXIS_TOLERANCE_DEG = 0.1
"""Largest acceptable error of a pan axis's direction (deg): at 45 deg of pan it moves the predicted camera by
less than 0.08 deg. Judged, as the transforms are, at :data:`COVERAGE` sigmas."""
PAN_AXIS_POINT_TOLERANCE_M = 0.01
"""Largest acceptable error of a pan axis's place across itself (m): at 45 deg of pan it moves the predicted camera
by less than 8 mm."""
MANUAL_VERDICT = Verdict("check", ["set by hand: no uncertainty, no cross-check"])
"""The verdict of a hand-set (``manual``) result."""


@dataclass(frozen=True)
class CrossCheck:
    """An independent check of a result made elsewhere (another method on the same pairs, say)."""

    name: str
    detail: str
    sigmas: float | None = None
    """The difference in its own sigmas, judged by the cross-check rule (:meth:`VerdictBuilder.cross_check_sigmas`);
    None: the check could not be made (``detail`` says why), and the verdict names it as missing."""

    @property
    def made(self) -> bool:
        """Whether the check was made (it has a measure)."""
        return self.sigmas is not None


def _diagnostic(result: TransformResult, key: str, undetermined: float = np.nan) -> np.ndarray | None:
    """A (6,) vector of ``result.diagnostics`` (m, rad) as floats, ``undetermined`` where it is None; None when the
    solver did not compute it."""
    values = result.diagnostics.get(key)
    return None if values is None else np.array([undetermined if v is None else v for v in values], dtype=float)


def judge(result: TransformResult, extra: Sequence[CrossCheck] = ()) -> Verdict:
    """The verdict of a solved ``T_camera_lidar`` (also stored on ``result.verdict``).

    Unconverged or ambiguous: ``reject``. Else the sigmas against the method's :data:`TOLERANCES`, competing
    alignments of the edges method and a translation held at the guess (``check``), the cross-check between
    independent captures (:func:`_spread_check`: the target's poses, the edges' two halves of the pairs), and the
    ``extra`` cross-checks: another method's answer on the same pairs, say. Without any cross-check it stays at
    ``check``, saying which is missing.
    """
    builder = VerdictBuilder()
    method = result.method
    if not result.converged:
        builder.reject("the solve is not usable: " + "; ".join(result.warnings or ["it did not converge"]))
    translation_m, rotation_deg = TOLERANCES[method]
    judge_transform_sigmas(builder, result.std, translation_m / COVERAGE, rotation_deg / COVERAGE)
    if method == "edges" and result.diagnostics.get("std_multistart") is not None:
        builder.check("other alignments fit about as well; the sigmas are widened to cover them")
    held = result.diagnostics.get("translation_held")
    if held is not None:
        builder.check(f"translation held at the guess \u00b1 {100 * held['sigma_m']:g} cm: this scene cannot "
                      "determine it")
    _spread_check(builder, result, method)
    for check in extra:
        if check.made:
            builder.cross_check_sigmas(check.name, check.sigmas, check.detail)
        else:
            builder.missing_check(check.name, check.detail)
    result.verdict = builder.verdict()
    return result.verdict


def _spread_check(builder: VerdictBuilder, result: TransformResult, method: str) -> None:
    """The cross-check between independent captures. Target: the leave-one-pose-out spread against the Jacobian's
    sigma (:data:`MAX_SPREAD_RATIO`; ``diagnostics["std_spread"]`` and ``["std_jacobian"]``). Edges: its two halves
    of the pairs solved apart (``diagnostics["halves_offset"]``) differ by at most
    :data:`COVERAGE` times the sigma of that difference, taken as twice the reported sigma (each half has half the
    data, about sqrt 2 times the whole's sigma, and the difference of two is sqrt 2 times that again). Intensity:
    :func:`_intensity_places_check`."""
    if method == "intensity":
        _intensity_places_check(builder, result)
        return
    if method in ("target", "corners", "vtarget"):  # poses of the board, placements of it in the sweep, V-targets
        std_spread = _diagnostic(result, "std_spread")
        if std_spread is None:
            builder.missing_check("over poses", "too few poses for a leave-one-out re-solve (3 or more are needed)")
            return
        ratio = std_spread / np.maximum(_diagnostic(result, "std_jacobian"), 1e-12)
        ratio_check(builder, "leave one of the poses out", ratio, MAX_SPREAD_RATIO,
                    "the re-solves spread at most {ratio} times the Jacobian's sigma", _worst_pose(result))
        return
    halves_offset = _diagnostic(result, "halves_offset")
    if halves_offset is None:
        _missing_places_check(builder, result, "between places", MIN_HALVES_PLACES)
        return
    expected = 2 * result.std_vector
    ratio = np.abs(halves_offset) / np.maximum(expected, 1e-12)
    ratio_check(builder, "between two halves of the places", ratio, COVERAGE,
                "the halves' solutions differ by at most {ratio} times the expected sigma of the difference")


def _worst_pose(result: TransformResult) -> str:
    """``"; without <pose> it moves ..."``: the pose whose leave-one-out re-solve moves the target result most (its
    ``diagnostics["poses"]`` entry), to look at first; empty without one."""
    moved = [pose for pose in result.diagnostics.get("poses", []) if pose.get("without_sigmas") is not None]
    if not moved:
        return ""
    worst = max(moved, key=lambda pose: pose["without_sigmas"])
    return (f"; without {worst['name']} the result moves most: {1000 * worst['without_m']:.1f} mm, "
            f"{worst['without_deg']:.2f} deg ({worst['without_sigmas']:.1f} of the Jacobian's sigmas)")


def ratio_check(builder: VerdictBuilder, name: str, ratio: np.ndarray, limit: float, detail: str,
                after: str = "") -> None:
    """A cross-check ``name`` that passes when every parameter's (6,) ``ratio`` (of :data:`TRANSFORM_PARAMETERS`) is
    at most ``limit``, which counts as :data:`~backend.core.verdict.CROSS_CHECK_SIGMAS` sigmas for the cross-check
    rule; ``detail`` names the worst as ``{ratio}``, followed by the parameter, the limit and ``after``."""
    ratio = np.where(np.isfinite(ratio), ratio, np.inf)
    worst = int(np.argmax(ratio))
    builder.cross_check_sigmas(name, float(ratio[worst]) * CROSS_CHECK_SIGMAS / limit,
                               detail.format(ratio=f"{ratio[worst]:.1f}") + f" ({TRANSFORM_PARAMETERS[worst]}), "
                               f"limit {limit:g}{after}")


def _missing_places_check(builder: VerdictBuilder, result: TransformResult, name: str, needed: int) -> None:
    """The cross-check ``name`` named missing: the result's pairs (``diagnostics["places"]``) came from fewer than
    ``needed`` places."""
    places = result.diagnostics.get("places") or []
    builder.missing_check(name, one_place_note(sum(map(len, places)), len(places), needed))


def _intensity_places_check(builder: VerdictBuilder, result: TransformResult) -> None:
    """The intensity method's cross-check between places: its leave-one-place-out spread
    (``diagnostics["std_places"]``, with pairs from three places or more) is at most :data:`MAX_SPREAD_RATIO` times the
    sigma the rest of the data gives (the larger of the curvature's and the spread over image regions and restarts,
    which one pair already shows; an undetermined curvature sigma is infinite)."""
    std_places = _diagnostic(result, "std_places")
    if std_places is None:
        _missing_places_check(builder, result, "over places", MIN_SPREAD_PLACES)
        return
    within = _diagnostic(result, "std_curvature", np.inf)
    std_groups = _diagnostic(result, "std_groups")
    if std_groups is not None:
        within = np.fmax(within, std_groups)
    ratio_check(builder, "leave one of the places out", std_places / np.maximum(within, 1e-12),
                MAX_SPREAD_RATIO, "the re-solves spread at most {ratio} times the sigma the rest of the data gives")


def judge_pan_axis(std: dict[str, list[float | None]], axis_sigma_deg: float, axis_point_sigma_m: float,
                   positions: Sequence[dict[str, Any]]) -> Verdict:
    """The verdict of a camera's pan-axis model (:mod:`backend.calib.lidar_camera.pan_axis`): the sigma of its pose
    at reading 0 (``std``, as a transform result's) against the corners method's :data:`TOLERANCES`, the axis's
    direction (deg) and place (m) against :data:`PAN_AXIS_TOLERANCE_DEG` and :data:`PAN_AXIS_POINT_TOLERANCE_M`, all
    at :data:`COVERAGE` sigmas; each position's own solve is a cross-check (its ``sigmas``: how far the model's
    prediction lies from it, in the own solve's sigma)."""
    builder = VerdictBuilder()
    translation_m, rotation_deg = TOLERANCES["corners"]
    judge_transform_sigmas(builder, std, translation_m / COVERAGE, rotation_deg / COVERAGE)
    builder.sigma("pan axis direction", axis_sigma_deg, PAN_AXIS_TOLERANCE_DEG / COVERAGE, "deg")
    builder.sigma("pan axis place", 1000 * axis_point_sigma_m, 1000 * PAN_AXIS_POINT_TOLERANCE_M / COVERAGE, "mm")
    for position in positions:
        builder.cross_check_sigmas(
            f"the camera's own solve at {position['pan_deg']:+.1f} deg",
            position["sigmas"], f"the axis puts the camera {position['from_prediction_mm']:.1f} mm and "
            f"{position['from_prediction_deg']:.3f} deg from it")
    return builder.verdict()
