"""The verdict of a lens: its projection uncertainty across the image and the cross-validation of two halves."""

from __future__ import annotations

from typing import Any

from backend.core.verdict import PROJECTION_TOLERANCE_PX, Verdict, VerdictBuilder


def intrinsics_verdict(projection: dict[str, Any], cross_validation: dict[str, Any]) -> Verdict:
    """The verdict of a lens: the worst projection sigma across the image (``projection["max_px"]``) against
    :data:`~backend.core.verdict.PROJECTION_TOLERANCE_PX`, and the two halves of the views solved apart
    (``cross_validation``: ``status`` and ``detail``) as the cross-check."""
    judge = VerdictBuilder()
    judge.sigma("worst projection across the image", projection["max_px"], PROJECTION_TOLERANCE_PX, "px")
    name = "two halves of the views"
    if cross_validation["status"] == "not made":
        judge.missing_check(name, cross_validation["detail"])
    else:
        passed = cross_validation["status"] == "consistent"
        judge.cross_check(name, passed, cross_validation["detail"] + (
            "" if passed else ": model error (try --model auto, or k3) or bad views (drop the outliers)"))
    return judge.verdict()
