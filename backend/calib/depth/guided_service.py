"""The guided procedure of one depth node (issue 14), shared by the API and the studio.

Per node, in :data:`~backend.calib.depth.guided.GUIDED_STEPS` order: ``initial`` (the pose typed from tape
or laser-meter measurements: :func:`start`), ``tables_behind`` (RotX, then Z), ``tables_beside`` (RotY, Z
again), ``lines`` (RotZ, X and Y). Each step's :func:`advise` measures that step's residuals on the node's
captures of that step's arrangement at the current pose and suggests the pose-row fields it changes
(:func:`backend.calib.depth.guided.advise`); :func:`apply` takes the suggestion, and the step is done
once its criterion holds at the new pose. :func:`nudge` sets the pose by hand at any time and :func:`undo`
goes back one pose: every pose stays in the history. :func:`finish` keeps the final pose as a
:class:`~backend.core.result.TransformResult` (kind ``depth_node``, method ``guided``) like any solve.

Steps are taken in order (rotations interact unless tuned in order): a later step before an earlier one is
done is a 409 naming both. A table not found, two tables at the same distance or empty depth is an
:class:`InputError` and the pose stays as it was. The state lives in the session's ``depth_network.json``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from backend.calib.depth import service as network
from backend.calib.depth.checks import guided_verdict
from backend.calib.depth.guided import GUIDED_STEPS as GUIDED_STEPS  # re-exported: the steps the studio offers
from backend.calib.rig import service as rig_service
from backend.core.depth import pose_from_row, pose_row
from backend.core.errors import InputError, shorten
from backend.core.result import TransformResult
from backend.core.transforms import params_between
from backend.store.schema import GuidedNodeState
from backend.store.session import Session

STEP_ARRANGEMENT: dict[str, str | None] = {"initial": None, "tables_behind": "behind", "tables_beside": "beside",
                                           "lines": None}
"""The captures each step reads: those of one arrangement, or (None) every capture of the node."""
ORDER_REASON: dict[str, str] = {
    "initial": "the typed pose is where every step starts",
    "tables_behind": "RotX before RotY: rotations interact",
    "tables_beside": "RotY before RotZ, X and Y: the lines are read on a level view",
    "lines": "the last step",
}
"""Why each step comes before the next (the 409 of a step taken out of order says it)."""


def _node_state(session: Session, node: str) -> GuidedNodeState:
    network.check_node(session, node)
    return network.state(session).guided.get(node, GuidedNodeState())


def _save(session: Session, node: str, guided: GuidedNodeState) -> None:
    with session.lock:
        file = network.state(session)
        file.guided[node] = guided
        session.save_depth_network(file)


def state(session: Session, node: str) -> dict[str, Any]:
    """Where ``node`` stands: ``{"node", "step"}`` (the step to work on: ``initial`` before :func:`start`, the
    last step once every step is done), ``complete`` (every step done), ``done``, ``pose_row`` and
    ``T_world_node`` (the current pose; None before start), ``history`` (every pose row, oldest first) and
    ``result_id`` (of :func:`finish`)."""
    guided = _node_state(session, node)
    steps = tuple(GUIDED_STEPS)
    current = np.array(guided.history[-1]) if guided.history else None
    step = "initial" if not guided.history else guided.step or steps[-1]
    return {"node": node, "step": step, "complete": all(s in guided.done for s in steps), "done": list(guided.done),
            "pose_row": None if current is None else list(pose_row(current)),
            "T_world_node": None if current is None else current.tolist(),
            "history": [list(pose_row(np.array(T))) for T in guided.history], "result_id": guided.result_id,
            "steps": list(steps)}


def start(session: Session, node: str, pose: Sequence[float]) -> dict[str, Any]:
    """Start (or restart) ``node``'s procedure from the typed ``pose`` row (X, Y, Z m; RotZ, RotY, RotX deg):
    ``initial`` is done, the next step is ``tables_behind``; earlier poses stay in the history."""
    T = pose_from_row(pose)
    guided = _node_state(session, node)
    steps = tuple(GUIDED_STEPS)
    _save(session, node, GuidedNodeState(step=steps[1], done=[steps[0]], history=[*guided.history, T.tolist()]))
    return state(session, node)


def _check_step(guided: GuidedNodeState, node: str, step: str) -> None:
    """Refuse an unknown step, a node not started, or a step whose earlier steps are not done (409)."""
    steps = tuple(GUIDED_STEPS)
    if step not in steps:
        raise InputError(f"unknown step {shorten(step)}; the steps are {list(steps)}", "step")
    if not guided.history:
        raise InputError(f"the guided procedure of {node} has not started: type its measured pose first "
                         f"(step 'initial')", "step", 409)
    if step == steps[0]:
        raise InputError("step 'initial' is the typed pose: start again from a typed pose to redo it", "step", 409)
    pending = guided.step
    if pending is not None and steps.index(step) > steps.index(pending):
        raise InputError(f"step {step!r} comes after {pending!r} ({ORDER_REASON[pending]}); finish {pending!r} "
                         "first", "step", 409)


def _observations(session: Session, node: str, step: str) -> list[Any]:
    arrangement = STEP_ARRANGEMENT[step]
    observed = network.observations(session, node, arrangement)
    if not observed:
        what = f"with the tables {arrangement} each other" if arrangement else "at all"
        raise InputError(f"no capture of {node} {what} yet; capture the node "
                         f"{f'with arrangement {arrangement!r} ' if arrangement else ''}for step {step!r}",
                         "captures")
    return observed


def advise(session: Session, node: str, step: str, T_world_node: np.ndarray | None = None) -> Any:
    """Step ``step``'s :class:`~backend.calib.depth.guided.StepAdvice` for ``node`` at ``T_world_node`` (default:
    the procedure's current pose): its residuals, the suggested pose-row fields, whether its criterion holds.
    When the captures leave the step nothing to suggest (no table found, tables at the same distance, no
    depth, no line) that is an :class:`InputError` listing why; nothing changes. Lesser problems (one capture's
    table missing) come in the advice's ``problems``."""
    from backend.calib.depth.guided import advise as solver_advise

    guided = _node_state(session, node)
    _check_step(guided, node, step)
    T = np.array(guided.history[-1]) if T_world_node is None else np.asarray(T_world_node, dtype=float)
    advice = solver_advise(step, _observations(session, node, step), network.layout(session), T)
    if advice.problems and not advice.suggestion:
        raise InputError(f"{node}, step {step!r}: {'; '.join(advice.problems)}; the pose is kept", "captures")
    return advice


def advice_dict(advice: Any) -> dict[str, Any]:
    """A :class:`~backend.calib.depth.guided.StepAdvice` as JSON (``T_suggested`` a nested list, and its row)."""
    return {"step": advice.step, "residuals": advice.residuals, "suggestion": dict(advice.suggestion),
            "T_suggested": np.asarray(advice.T_suggested).tolist(),
            "pose_row_suggested": list(pose_row(advice.T_suggested)), "done": bool(advice.done),
            "criterion": advice.criterion, "why": advice.why, "problems": list(advice.problems)}


def apply(session: Session, node: str, step: str) -> dict[str, Any]:
    """Take step ``step``'s suggestion at the current pose (the previous pose stays in the history); when its
    criterion then holds the step is done and the next one is due. :func:`state` with ``advice``: the step's
    advice at the new pose."""
    steps = tuple(GUIDED_STEPS)
    with session.lock:
        advice = advise(session, node, step)
        if not advice.suggestion:
            raise InputError(f"{node}, step {step!r}: nothing to apply ({advice.criterion}: "
                             f"{'holds' if advice.done else 'does not hold'}); the pose is kept", "step", 409)
        guided = _node_state(session, node)
        T_new = np.asarray(advice.T_suggested, dtype=float)
        after = advise(session, node, step, T_new)
        guided.history.append(T_new.tolist())
        if after.done and step not in guided.done:
            guided.done.append(step)
        if after.done and guided.step == step:
            index = steps.index(step) + 1
            guided.step = steps[index] if index < len(steps) else None
        _save(session, node, guided)
    return state(session, node) | {"advice": advice_dict(after)}


def nudge(session: Session, node: str, pose: Sequence[float]) -> dict[str, Any]:
    """Set the pose by hand (the pose row, m and deg); the steps done stay done. The previous pose stays in the
    history."""
    T = pose_from_row(pose)
    with session.lock:
        guided = _node_state(session, node)
        if not guided.history:
            raise InputError(f"the guided procedure of {node} has not started: type its measured pose first",
                             "step", 409)
        if not np.allclose(guided.history[-1], T, rtol=0, atol=1e-12):
            guided.history.append(T.tolist())
            _save(session, node, guided)
    return state(session, node)


def undo(session: Session, node: str) -> dict[str, Any]:
    """Go back to the previous pose of the history (the typed pose is the oldest one kept)."""
    with session.lock:
        guided = _node_state(session, node)
        if len(guided.history) < 2:
            raise InputError(f"{node}: no earlier pose to go back to", "history", 409)
        guided.history.pop()
        _save(session, node, guided)
    return state(session, node)


def finish(session: Session, node: str, *, accept: bool = False, confirm: bool = False) -> dict[str, Any]:
    """Keep the procedure's final pose as a result of ``node`` (kind ``depth_node``, method ``guided``, parent
    ``world``) and return its stored record; with ``accept``, accept it into the rig too (a ``check`` verdict
    needs ``confirm``).

    Covariance: the criteria holding says little of how far the pose may still be off within them, so the
    node's captures are solved by least squares from the final pose (:func:`_least_squares_check`); the pose
    is off the truth by its offset from that solution plus that solution's own error, so its covariance is
    the solution's plus the offset's outer product. When the captures cannot fix all six degrees of freedom,
    the transform set by hand's (:data:`backend.calib.rig.service.MANUAL_SIGMA`, 5 mm and 0.3 deg per axis), and
    the verdict says why. Verdict: the sigmas against the default tolerances; as the cross-check, every step's
    criterion re-measured at the final pose (a nudge after a step may have undone it)."""
    steps = tuple(GUIDED_STEPS)
    guided = _node_state(session, node)
    if not guided.history:
        raise InputError(f"the guided procedure of {node} has not started: type its measured pose first", "step",
                         409)
    missing = [s for s in steps if s not in guided.done]
    if missing:
        raise InputError(f"{node}: step {missing[0]!r} is not done yet (steps left: {missing})", "step", 409)
    T = np.array(guided.history[-1])
    checks = {step: advise(session, node, step, T) for step in steps[1:]}
    covariance, least_squares = _least_squares_check(session, node, T)
    result = TransformResult(kind="depth_node", method="guided", parent=network.WORLD, child=node, T_parent_child=T,
                             covariance=covariance,
                             residuals=_residual_summary([r for a in checks.values() for r in a.residuals]),
                             diagnostics={"steps": {step: advice_dict(a) for step, a in checks.items()},
                                          "pose_row": list(pose_row(T)),
                                          "history": [list(pose_row(np.array(h))) for h in guided.history],
                                          "least_squares": least_squares})
    result.verdict = guided_verdict(result, checks, least_squares)
    inputs = [c.id for c in network.captures(session, node)]
    record = session.result(session.add_result(node, result.to_record(), inputs=inputs))
    guided.result_id = record["id"]
    _save(session, node, guided)
    if accept:
        rig_service.accept(session, record["id"], confirm=confirm)
    return record


def _least_squares_check(session: Session, node: str, T_world_node: np.ndarray
                         ) -> tuple[np.ndarray, dict[str, Any]]:
    """The guided pose's 6x6 covariance (:data:`~backend.core.result.TRANSFORM_PARAMETERS`, m and rad) and
    what it rests on: the least-squares solve of all ``node``'s captures from ``T_world_node``, its ``pose_row``,
    its ``std``, and the guided pose's ``offset_m`` / ``offset_deg`` from it (parent axes, child axes); or,
    when that solve cannot be made, the set-by-hand covariance and the ``problem`` that stopped it."""
    from backend.calib.depth.node import solve_depth_node

    try:
        solved = solve_depth_node(node, network.observations(session, node), network.layout(session), T_world_node)
    except InputError as error:
        covariance, assumed = rig_service.manual_covariance()
        return covariance, {"problem": f"no least-squares solve of the same captures ({error.message}); {assumed}"}
    offset = params_between(solved.T_parent_child, T_world_node)
    return solved.covariance + np.outer(offset, offset), {
        "pose_row": list(pose_row(solved.T_parent_child)), "std": solved.std, "verdict": solved.verdict.level,
        "offset_m": offset[:3].tolist(), "offset_deg": np.degrees(offset[3:]).tolist()}


def _residual_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """``rms_m`` of the features' errors against their known values, the worst one and how many (m)."""
    errors = np.array([r["error_m"] for r in rows if r.get("error_m") is not None], dtype=float)
    if not len(errors):
        return {"n_features": 0}
    return {"rms_m": float(np.sqrt(np.mean(errors**2))), "max_abs_error_m": float(np.abs(errors).max()),
            "n_features": len(errors)}
