"""The verdict of a LiDAR-to-LiDAR result: its own fit, and the cross-check across scenes.

:func:`judge_fit` weighs one solve's numbers (convergence, fitness, sigmas); a solve from one place has no
independent cross-check (:func:`judge_one_scene` says so); several scenes check each other
(:func:`scenes_cross_check`: each scene against the joint solve of the others).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from backend.core.verdict import CROSS_CHECK_SIGMAS, VerdictBuilder, judge_transform_sigmas

if TYPE_CHECKING:
    from backend.calib.lidar_lidar.gicp import LidarLidarSettings, SceneResult

LOW_FITNESS = 0.1
"""Below this fitness (but above ``min_fitness``) little of the source overlaps the target: the verdict asks
for a look at the alignment (the real OpenCalib pair, a 64-beam and a short-range LiDAR, reaches 0.15)."""
ONE_SCENE = "only one scene: capture the rig in two more places"
"""Why a single-scene result has no cross-check (the verdict's missing check)."""


def judge_fit(std: dict[str, list[float | None]], fitness: float, ok: bool, problems: list[str],
              settings: LidarLidarSettings) -> VerdictBuilder:
    """The verdict's findings on one solve's own numbers: ``reject`` when it did not converge or fits poorly
    (``problems``: why, from :func:`~backend.calib.lidar_lidar.gicp.fit_warnings`), its sigmas (``std``: m and
    deg) against the default tolerances, and a ``check`` when its fitness is below :data:`LOW_FITNESS`. The caller
    adds the cross-check."""
    judge = VerdictBuilder()
    if not ok:
        judge.reject("; ".join(problems) or "the refinement failed")
    judge_transform_sigmas(judge, std)
    overlap = f"fitness {fitness:.3f} (share of source points within {settings.max_correspondence_m} m of the target)"
    if ok and fitness < LOW_FITNESS:
        judge.check(f"little overlap: {overlap}; look at the alignment before accepting")
    else:
        judge.note(overlap)
    return judge


def judge_one_scene(judge: VerdictBuilder, sectors: int | None, frames: int = 1) -> None:
    """The missing cross-check of a solve from one place (``frames`` pairs there), and what the spread over
    ``sectors`` azimuth sectors gave (None: not computed)."""
    judge.missing_check("across scenes", ONE_SCENE if frames == 1 else
                        f"{ONE_SCENE} (the {frames} frame pairs were all taken in one place)")
    if sectors:
        judge.note(f"the spread over {sectors} azimuth sectors is inside the sigma; it re-uses the same scan, "
                   "so it is no independent cross-check")


def scenes_cross_check(judge: VerdictBuilder, scenes: list[SceneResult]) -> None:
    """The verdict's cross-check across scenes, from each scene's deviation and allowance (m, rad)."""
    ratios = [float(np.max(np.abs(s.deviation) / s.allowance)) if s.converged else np.inf for s in scenes]
    worst = int(np.argmax(ratios))
    scene = scenes[worst]
    where = f"scene {worst + 1} (pairs {', '.join(str(i) for i in scene.pairs)})"
    if not scene.converged:
        judge.cross_check("across scenes", False, f"{where} does not converge to a good fit on its own: drop it or "
                          "capture it again", fail_level="reject")
        return
    d, a = scene.deviation, scene.allowance
    offset = (f"{1e3 * np.linalg.norm(d[:3]):.1f} mm / {np.degrees(np.linalg.norm(d[3:])):.3f} deg from the joint "
              f"solve of the other scenes (allowed per axis up to {1e3 * a[:3].max():.1f} mm / "
              f"{np.degrees(a[3:].max()):.3f} deg: the tolerance or {CROSS_CHECK_SIGMAS:g} sigma)")
    # the allowance counts as CROSS_CHECK_SIGMAS sigmas for the cross-check rule (a 'reject' beyond 5/3 of it)
    sigmas = CROSS_CHECK_SIGMAS * ratios[worst]
    if sigmas <= CROSS_CHECK_SIGMAS:
        judge.cross_check_sigmas("across scenes", sigmas, f"all {len(scenes)} scenes agree; the furthest, {where}, "
                                 f"lies {offset}")
    else:
        judge.cross_check_sigmas("across scenes", sigmas, f"{where} lies {offset}, {ratios[worst]:.1f} times its "
                                 "allowance: a cloud that moved, a LiDAR knocked between scenes or a poor scene; "
                                 "drop it or capture it again")
