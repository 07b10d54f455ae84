"""The verdicts of depth-node results: the automatic solve, pairwise ICP and the guided procedure.

Each weighs the result's sigmas against the tolerances and makes the independent cross-check its method allows:
held-out captures and crosses for the automatic solve, every step's criterion at the final pose for the guided
procedure; ICP between two nodes has none of its own and says so.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from backend.core.result import TransformResult
from backend.core.verdict import CROSS_CHECK_SIGMAS, Verdict, VerdictBuilder, judge_transform_sigmas

if TYPE_CHECKING:
    from backend.calib.depth.guided import StepAdvice
    from backend.calib.depth.icp import DepthIcpSettings
    from backend.calib.depth.node import DepthNodeSettings

HELD_OUT_FACTOR = 2.0
"""A held-out capture's tables and lines pass the cross-check within this many times the translation tolerance."""


def node_verdict(std: dict, converged: bool, held: list[dict], crosses: list[dict], n_captures: int,
                 settings: DepthNodeSettings) -> Verdict:
    """The verdict of a node's automatic solve (:func:`backend.calib.depth.node.solve_depth_node`): its sigmas
    against the settings' tolerances, each held-out capture's tables and lines at the pose solved without it, and
    the crosses seen against their known positions."""
    judge = VerdictBuilder()
    if not converged:
        judge.reject("the least-squares solve did not converge; give a better initial pose")
    judge_transform_sigmas(judge, std, settings.translation_tolerance_m, settings.rotation_tolerance_deg)
    limit = HELD_OUT_FACTOR * settings.translation_tolerance_m
    worst = [h["max_error_m"] for h in held if h["max_error_m"] is not None]
    if worst:
        judge.cross_check_sigmas("held-out captures", CROSS_CHECK_SIGMAS * max(worst) / limit,
                                 f"each capture's tables and lines at the pose solved without it are within "
                                 f"{1e3 * max(worst):.1f} mm of their known values (limit {1e3 * limit:.0f} mm)")
    else:
        judge.missing_check("held-out captures", f"{n_captures} capture: capture the tables once more, moved")
    if crosses:
        far = max(c["error_m"] for c in crosses)
        judge.cross_check_sigmas("crosses", CROSS_CHECK_SIGMAS * far / settings.cross_tolerance_m,
                                 f"{len(crosses)} crosses seen (not surveyed, so not used by the solve), the "
                                 f"furthest {1e3 * far:.1f} mm from its known position (limit "
                                 f"{1e3 * settings.cross_tolerance_m:.0f} mm)")
    return judge.verdict()


def icp_verdict(result: TransformResult, fitness: float, settings: DepthIcpSettings) -> Verdict:
    """The verdict of ICP between two nodes: ``reject`` when the clouds hardly overlap, the sigmas against the
    settings' tolerances, and never ``trusted``: ICP is one more constraint, with no cross-check of its own."""
    judge = VerdictBuilder()
    if fitness < settings.min_fitness:
        judge.reject(f"the clouds hardly overlap (fitness {fitness:.3f} < {settings.min_fitness})")
    judge_transform_sigmas(judge, result.std, settings.translation_tolerance_m, settings.rotation_tolerance_deg)
    judge.missing_check("against the cell's geometry", "ICP between two nodes is one more constraint, never the "
                        "only one: solve the nodes from tables and lines and compare")
    return judge.verdict()


def guided_verdict(result: TransformResult, checks: Mapping[str, StepAdvice], least_squares: Mapping[str, Any]
                   ) -> Verdict:
    """The verdict of a guided pose: its sigmas against the default tolerances (``check`` when they were set by
    hand, saying why) and, as the cross-check, every step's criterion re-measured at the final pose."""
    judge = VerdictBuilder()
    judge_transform_sigmas(judge, result.std)
    if "problem" in least_squares:
        judge.check(f"sigma set by hand: {least_squares['problem']}")
    failed = [step for step, a in checks.items() if not a.done]
    judge.cross_check("every step's criterion at the final pose", not failed,
                      f"{', '.join(failed)} no longer hold{'s' if len(failed) == 1 else ''}" if failed else
                      "; ".join(a.criterion for a in checks.values()))
    return judge.verdict()
