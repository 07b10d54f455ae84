"""The verdict of a lens: its projection uncertainty where the views reach, and the cross-validation of two halves."""

from __future__ import annotations

from typing import Any

from backend.core.verdict import CROSS_CHECK_SIGMAS, PROJECTION_TOLERANCE_PX, Verdict, VerdictBuilder

MIN_COVERED_SHARE = 1 / 3
"""A lens whose views' boards reach less of the image than this share is judged on too little of it (``check``).
The sigma beyond the boards is extrapolation either way, and named; OpenCV's 13-view sample sets reach 43-44 %,
the VLP-16 rig's 8 views of a small board 7 %."""
JACKKNIFE_NOTE_RATIO = 2.0
"""A jackknife wider than this many noise-model sigmas is named in the verdict (a note: the cross-validation
judges)."""


def intrinsics_verdict(projection: dict[str, Any], cross_validation: dict[str, Any],
                       board_flex: dict[str, Any] | None = None, jackknife: dict[str, Any] | None = None,
                       models_compared: bool = False, splined: bool = False) -> Verdict:
    """The verdict of a lens, as mrcal judges one.

    - The noise model's projection sigma (``projection``: :func:`~backend.calib.intrinsics.solver.
      _noise_model_projection`) at its worst where the views' boards reach (``max_covered_px``) against
      :data:`~backend.core.verdict.PROJECTION_TOLERANCE_PX`; beyond the views the sigma is extrapolation and is
      named, not judged, and views that reach under :data:`MIN_COVERED_SHARE` of the image are a ``check`` (boards
      that reach no cell's centre at all are judged across the whole image).
    - The cross-check: two halves of the views solved apart (``cross_validation``: ``status`` and ``detail``). Halves
      that differ by more than their sigmas are model error, and the advice names the fixes in the order to try
      them: the board's flex when it was not solved (``board_flex``), a richer lens model (not the model comparison
      once ``models_compared``; for a ``splined`` model, fewer knots: each half has half the measurements), more
      views where the sigma map is worst.
    - The views' jackknife (``jackknife``) is named when it is much wider than the noise model, as a note.

    Advice is in words every front-end shares (no command-line flag).
    """
    judge = VerdictBuilder()
    if projection["max_covered_px"] is None:  # boards too small to reach a grid cell's centre: judge the whole image
        judge.sigma("worst projection across the image", projection["max_px"], PROJECTION_TOLERANCE_PX, "px")
    else:
        judge.sigma("worst projection where the views reach", projection["max_covered_px"], PROJECTION_TOLERANCE_PX,
                    "px")
    share = projection["covered_share"]
    if projection["max_uncovered_px"] is not None:
        beyond = projection.get("beyond_reach", "extrapolated")
        reach = (f"the views' boards reach {share:.0%} of the image; beyond them the sigma is up to "
                 f"{projection['max_uncovered_px']:.3g} px ({beyond}: add views there to calibrate it)")
        if share < MIN_COVERED_SHARE:
            judge.check(f"{reach}, under the {MIN_COVERED_SHARE:.0%} a lens is judged on")
        else:
            judge.note(reach)
    name = "two halves of the views"
    if cross_validation["status"] == "not made":
        judge.missing_check(name, cross_validation["detail"])
    else:
        sigmas = cross_validation["worst_ratio"]
        judge.cross_check_sigmas(name, sigmas, cross_validation["detail"] + (
            "" if sigmas <= CROSS_CHECK_SIGMAS else f": model error, the noise model does not explain the data; "
                                                    f"{_model_error_advice(board_flex, models_compared, splined)}"))
    if jackknife is not None and jackknife["ratio"] > JACKKNIFE_NOTE_RATIO:
        judge.note(f"the views' jackknife spreads the lens up to {jackknife['ratio']:.1f}x its noise-model sigma "
                   "(errors shared within views); the cross-validation judges whether that is model error")
    return judge.verdict()


def _model_error_advice(board_flex: dict[str, Any] | None, models_compared: bool, splined: bool) -> str:
    """The fixes for model error, in the order to try them."""
    fixes = []
    if board_flex is not None and board_flex["status"] != "solved":
        fixes.append(f"solve the board's flex (now {board_flex['status']}: {board_flex['detail']})")
    if splined:
        fixes.append("ask for fewer spline knots (each half of the views measures the knots half as often, and a "
                     "spline too fine for them follows each half's noise)")
    else:
        fixes.append("try a richer lens model (estimate k3)" if models_compared
                     else "try a richer lens model (compare the lens models with model auto, or estimate k3)")
    fixes.append("add views where the sigma map is worst, or drop bad views (the outliers)")
    return "; ".join(fixes)
