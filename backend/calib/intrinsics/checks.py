"""The verdict of a lens: its projection uncertainty across the image and the cross-validation of two halves."""

from __future__ import annotations

from typing import Any

from backend.core.verdict import CROSS_CHECK_SIGMAS, PROJECTION_TOLERANCE_PX, Verdict, VerdictBuilder


def intrinsics_verdict(projection: dict[str, Any], cross_validation: dict[str, Any],
                       models_compared: bool = False) -> Verdict:
    """The verdict of a lens: the worst projection sigma across the image (``projection["max_px"]``) against
    :data:`~backend.core.verdict.PROJECTION_TOLERANCE_PX`, and the two halves of the views solved apart
    (``cross_validation``: ``status`` and ``detail``) as the cross-check. A failed check advises what to try in
    words every front-end shares (no command-line flag), and not the model comparison once ``models_compared``."""
    judge = VerdictBuilder()
    judge.sigma("worst projection across the image", projection["max_px"], PROJECTION_TOLERANCE_PX, "px")
    name = "two halves of the views"
    if cross_validation["status"] == "not made":
        judge.missing_check(name, cross_validation["detail"])
    else:
        sigmas = cross_validation["worst_ratio"]
        model_advice = "estimate k3" if models_compared else "compare the lens models (model auto), or estimate k3"
        judge.cross_check_sigmas(name, sigmas, cross_validation["detail"] + (
            "" if sigmas <= CROSS_CHECK_SIGMAS else f": the lens model does not fit ({model_advice}) or some views "
                                                   "are bad (drop the outliers)"))
    return judge.verdict()
