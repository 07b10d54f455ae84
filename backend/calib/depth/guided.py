"""The guided, step-by-step calibration of a depth node (the paper's manual procedure), as advice per step.

The paper tuned each node by hand in a fixed order, because the rotations interact: a tilt error
moves every table height and every floor line, so the tilts are set first, from tables, and the
heading and position last, from the lines. :func:`advise` gives, for one step, what it looks at
(the features' residuals at the current pose), the values the step would set (a one-dimensional
least-squares solve of its first parameter holding the others, then its offsets), whether the step
is done at the current pose, and why it comes where it does:

1. ``initial``: the typed pose (tape measure); done when the floor shows up near ``z = 0``;
2. ``tables_behind``: tables near, middle and far: ``RotX`` makes their heights agree, then ``Z``
   brings them to their known height;
3. ``tables_beside``: tables left, centre and right: ``RotY``, then ``Z`` again;
4. ``lines``: ``RotZ`` turns the tape lines parallel to their known directions, then ``X`` and ``Y``
   slide them onto their known values.

Which step may run when is the service's business; :func:`advise` says when a step's evidence is
missing (no capture with tables behind each other, a table not found, tables at one distance).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from backend.calib.depth.features import AXES, DepthNodeSettings, DepthObservation, Feature, feature_residuals
from backend.calib.depth.node import extract_all
from backend.core.depth import POSE_COLUMNS, pose_from_row, pose_row
from backend.core.depth_cell import CellLayout
from backend.core.errors import InputError
from backend.core.transforms import check_transform, transform_points

GUIDED_STEPS = ("initial", "tables_behind", "tables_beside", "lines")
TABLE_TOLERANCE_M = 0.005
"""A table step is done when every table's height is within this (m) of its known height."""
LINE_TOLERANCE_M = 0.005
"""The lines step is done when every line's mean offset is within this (m) of its known value."""
FLOOR_TOLERANCE_M = 0.25
"""The initial step is done when the floor's mean height under the typed pose is within this (m) of zero."""
SEARCH_DEG = 10.0
"""The one-dimensional solves search this far (deg) either side of the current angle."""
MIN_TABLE_SPREAD_M = 1.0
"""Tables behind each other closer than this in range (m) give RotX no leverage."""
MIN_TABLE_SPREAD_PX = 80.0
"""Tables beside each other closer than this across the image (px) give RotY no leverage."""
MIN_LINE_EXTENT_M = 1.0
"""A line seen over less than this (m) along itself hardly turns RotZ."""

_STEP = {
    "tables_behind": ("behind", "RotX", "behind each other (bottom, middle and top of the view)"),
    "tables_beside": ("beside", "RotY", "beside each other (left, centre and right of the view)"),
}
CRITERIA = {
    "initial": f"the floor is found under the typed pose, its mean height within {FLOOR_TOLERANCE_M * 100:.0f} cm "
               "of z = 0",
    "tables_behind": f"every table behind each other within {TABLE_TOLERANCE_M * 1e3:.0f} mm of its known height",
    "tables_beside": f"every table beside each other within {TABLE_TOLERANCE_M * 1e3:.0f} mm of its known height",
    "lines": f"every floor line seen within {LINE_TOLERANCE_M * 1e3:.0f} mm of its known value",
}
WHY = {
    "initial": "Every later step finds its tables by their height and its lines by where they should be under "
               "this pose, so it must be roughly right: X, Y, Z from the tape measure, RotZ towards the cell and "
               "RotX about -140 deg as mounted.",
    "tables_behind": "Tables near, middle and far differ in height only through RotX (the tilt along the view) and "
                     "all together through Z: RotX first makes them agree with each other, then Z brings them to "
                     "their known height. The rotations interact, so they are tuned one at a time, tilts first.",
    "tables_beside": "Tables left, centre and right differ only through RotY (the roll across the view): with "
                     "RotX set, RotY makes them agree, then Z is checked again. A second pass over both table steps "
                     "takes out what each tilt left of the other.",
    "lines": "Last, because a tilt or height error shifts every line on the floor: once the node is level and at "
             "height, RotZ turns the lines parallel to their known directions, then X and Y slide them onto "
             "their known values.",
}


@dataclass
class StepAdvice:
    """What one guided step sees at the current pose and the values it would set."""

    step: str
    residuals: list[dict]
    """:func:`~backend.calib.depth.features.feature_residuals` of the features this step looks at."""
    suggestion: dict[str, float]
    """Pose-row fields this step changes (m, deg), in the order it changes them (``{"RotX": -138.6, "Z": 4.898}``)."""
    T_suggested: np.ndarray
    """``T_world_node`` (4x4, m) with the suggestion applied (the current pose when there is none)."""
    done: bool
    """The step's criterion holds at the CURRENT pose."""
    criterion: str
    why: str
    problems: list[str] = field(default_factory=list)


def _with(row: tuple[float, ...], changes: dict[str, float]) -> np.ndarray:
    """``T_world_node`` of the pose ``row`` (m, deg) with ``changes`` (pose-row fields) applied."""
    values = list(row)
    for name, value in changes.items():
        values[POSE_COLUMNS.index(name)] = value
    return pose_from_row(values)


def _mean_errors(features: list[Feature], T_world_node: np.ndarray) -> np.ndarray:
    """(F,) each feature's mean world offset from its known value (m) at ``T_world_node``."""
    return np.array([transform_points(T_world_node, f.points)[:, AXES[f.axis or "z"]].mean() - float(f.known)
                     for f in features])


def _solve_angle(row: tuple[float, ...], angle: str, objective) -> float:
    """The value (deg) of pose-row ``angle`` within :data:`SEARCH_DEG` of the current one that minimises
    ``objective(T_world_node)``, the others held."""
    current = row[POSE_COLUMNS.index(angle)]
    found = minimize_scalar(lambda value: objective(_with(row, {angle: value})), method="bounded",
                            bounds=(current - SEARCH_DEG, current + SEARCH_DEG), options={"xatol": 1e-5})
    return float(found.x)


def _tables_step(step: str, observations: list[DepthObservation], layout: CellLayout, T: np.ndarray,
                 settings: DepthNodeSettings) -> tuple[list[Feature], dict[str, float], list[str]]:
    """The tables of the step's captures, its suggestion (the tilt, then ``Z``) and its problems."""
    arrangement, angle, wording = _STEP[step]
    mine = [obs for obs in observations if obs.arrangement == arrangement]
    if not mine:
        return [], {}, [f"no capture with tables {wording}: stand three tables so and capture"]
    features, problems = extract_all(mine, T, layout, settings)
    tables = [f for f in features if f.kind == "table"]
    for obs in mine:
        found = [f for f in tables if f.capture_id == obs.capture_id]
        if len(found) < 2:
            problems.append(f"capture {obs.capture_id}: {len(found)} table found; {angle} needs two or more "
                            f"{wording}")
            continue
        centres = np.array([f.points.mean(axis=0) for f in found])
        if arrangement == "behind":
            spread = np.ptp(np.linalg.norm(centres, axis=1))
            if spread < MIN_TABLE_SPREAD_M:
                problems.append(f"capture {obs.capture_id}: the tables stand at the same distance (within "
                                f"{spread:.2f} m, the same height in the image): no leverage on RotX; put one near "
                                "and one far")
        else:
            columns = obs.intrinsics.fx * centres[:, 0] / centres[:, 2]
            if np.ptp(columns) < MIN_TABLE_SPREAD_PX:
                problems.append(f"capture {obs.capture_id}: the tables stand in one column of the image (within "
                                f"{np.ptp(columns):.0f} px): no leverage on RotY; put one left and one right")
    if len(tables) < 2 or any("no leverage" in p for p in problems):
        return tables, {}, problems
    row = pose_row(T)
    tilt = _solve_angle(row, angle, lambda T_try: float(np.var(_mean_errors(tables, T_try))))
    z = row[2] - float(_mean_errors(tables, _with(row, {angle: tilt})).mean())
    return tables, {angle: tilt, "Z": z}, problems


def _line_spread(lines: list[Feature], T_world_node: np.ndarray) -> float:
    """Sum over lines of the variance (m^2) of their points' offsets: least when each runs parallel to its known
    direction (its mean offset aside)."""
    return float(sum(np.var(transform_points(T_world_node, f.points)[:, AXES[f.axis]]) for f in lines))


def _lines_step(observations: list[DepthObservation], layout: CellLayout, T: np.ndarray,
                settings: DepthNodeSettings) -> tuple[list[Feature], dict[str, float], list[str]]:
    """The lines seen in all captures, the suggestion (``RotZ``, then ``X`` and ``Y``) and the problems."""
    features, problems = extract_all(observations, T, layout, settings)
    lines = [f for f in features if f.kind == "line"]
    if not lines:
        return [], {}, problems + ["no floor line seen: RotZ, X and Y cannot be set; check that the lines are in "
                                   "view and the pose is roughly right (initial step)"]
    for f in lines:
        world = transform_points(T, f.points)
        extent = float(np.ptp(world[:, 1 - AXES[f.axis]]))
        if extent < MIN_LINE_EXTENT_M:
            problems.append(f"line {f.name} in capture {f.capture_id} is seen over only {extent:.2f} m: it hardly "
                            "turns RotZ")
    row = pose_row(T)
    heading = _solve_angle(row, "RotZ", lambda T_try: _line_spread(lines, T_try))
    T_turned = _with(row, {"RotZ": heading})
    suggestion = {"RotZ": heading}
    errors = _mean_errors(lines, T_turned)
    weights = np.array([len(f.points) for f in lines], dtype=float)
    for axis, name in (("x", "X"), ("y", "Y")):
        on_axis = np.array([f.axis == axis for f in lines])
        if on_axis.any():
            suggestion[name] = row[AXES[axis]] - float(np.average(errors[on_axis], weights=weights[on_axis]))
        else:
            problems.append(f"no floor line {name} = const seen: {name} stays as it is")
    return lines, suggestion, problems


def advise(step: str, observations: list[DepthObservation], layout: CellLayout, T_world_node: np.ndarray,
           settings: DepthNodeSettings | None = None) -> StepAdvice:
    """The advice of guided ``step`` (one of :data:`GUIDED_STEPS`) for a node at ``T_world_node`` (4x4, m), from
    its ``observations``: the residuals it looks at, its suggestion, whether it is done, why it comes here and
    what stops it (problems). Raises :class:`InputError` for an unknown step or a non-rigid pose."""
    if step not in GUIDED_STEPS:
        raise InputError(f"unknown guided step {step!r}; the steps are {', '.join(GUIDED_STEPS)}", "step")
    settings = settings or DepthNodeSettings()
    T, _ = check_transform(T_world_node, "T_world_node")
    if step == "initial":
        features, problems = extract_all(observations, T, layout, settings)
        looked_at = [f for f in features if f.kind == "floor"]
        suggestion: dict[str, float] = {}
        if not observations:
            problems.append("no capture yet: capture the node to see the floor under the typed pose")
    elif step == "lines":
        looked_at, suggestion, problems = _lines_step(observations, layout, T, settings)
    else:
        looked_at, suggestion, problems = _tables_step(step, observations, layout, T, settings)
    residuals = feature_residuals(looked_at, T)
    tolerance = {"initial": FLOOR_TOLERANCE_M, "lines": LINE_TOLERANCE_M}.get(step, TABLE_TOLERANCE_M)
    done = bool(residuals) and all(abs(r["error_m"]) <= tolerance for r in residuals)
    T_suggested = _with(pose_row(T), suggestion) if suggestion else T
    return StepAdvice(step, residuals, suggestion, T_suggested, done, CRITERIA[step], WHY[step], problems)
