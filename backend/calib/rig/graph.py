"""The rig tree as the least-squares fit of every measured relation: a pose graph on SE(3).

Each accepted calibration is an edge ``T_parent_child`` between two frames with its 6x6
covariance (``TRANSFORM_PARAMETERS``: translation in m along the parent's axes, rotation in
rad about the child's axes); each mounting guess (tape, CAD) is a weak prior edge from a
frame's parent. The unknowns are the poses ``T_root_frame`` of every frame reachable from
the root. Minimising the sum of the edges' squared Mahalanobis errors gives the fused tree
and, from the inverse of the whitened normal matrix, each frame's covariance in its parent.
Pairwise tools (Kalibr, OpenCalib, livox_camera_calib) leave the user to compose pairs;
fusing them here is what keeps one edge from silently breaking another.

Consistency checks that come with the fit:

- every edge's residual against the fused tree (m, deg, and chi-square normalised by 6);
- every edge's *leave-one-out* disagreement: the edge against the tree solved from all the
  others, in sigma of their difference (None when nothing else constrains it);
- loops of measured edges (camera to LiDAR to LiDAR to camera) and their closure error.

An edge that disagrees with the rest beyond :data:`FLAG_SIGMA` is flagged and left out of the
fused tree, which the rest then holds. In one loop every edge disagrees alike: a loop cannot
say which of its edges is wrong. So among the edges whose removal leaves the rest consistent
(its chi-square within the :data:`CONSISTENT_PROBABILITY` quantile), the flag goes to the newest
(edges are given oldest first): the one whose acceptance broke the loop. Each flagged edge names
the edges it shares a loop with, so the user can keep it and revert one of them instead.

Written here because no library we use fits a small pose graph with these diagnostics (g2o and
GTSAM are not on our dependency list); the fit itself is :func:`scipy.optimize.least_squares`.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import solve_triangular
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation
from scipy.stats import chi2, norm

from backend.core.result import transform_std
from backend.core.transforms import apply_params_many, invert, params_between, rotation_angle_deg

FLAG_SIGMA = 3.0
"""An edge whose leave-one-out disagreement exceeds this many sigma is flagged. The disagreement is the
Mahalanobis distance of the 6-vector difference, said as the Gaussian sigma of equal probability (3 sigma:
chi-square 20.1 on 6 degrees of freedom), so a consistent rig raises a false flag on 0.27 % of its edges."""
UNDETERMINED_SIGMA = (100.0, np.pi)
"""Sigma (m, rad) given to an axis whose covariance is NaN: the edge says nothing along it."""
REFIT_LEVERAGE = 1e-4
"""An edge whose hat block leaves the other edges less than this of any direction is checked by a refit without
it rather than from the one fit: along that direction the edge is about 100 times tighter than what the others
say (0.5 mm beside a 50 mm mounting prior), and the one fit's leverage, ``(sigma_edge / sigma_others)^2``, nears
the solver's tolerance."""
JACOBIAN_STEP = 1e-7
"""Finite-difference step of the Jacobians (m, rad)."""
CONSISTENT_PROBABILITY = 0.9973
"""The rest of the graph is consistent when its chi-square is within this quantile (3 sigma) for its degrees
of freedom."""


@dataclass
class RigEdge:
    """One measured relation between two frames: an accepted result or a mounting prior."""

    parent: str
    child: str
    T_parent_child: np.ndarray
    """4x4 (m): maps points in ``child`` into ``parent``."""
    covariance: np.ndarray
    """6x6 over ``TRANSFORM_PARAMETERS`` (m, parent axes; rad, child axes); NaN rows: undetermined."""
    kind: str
    """``prior`` (a mounting guess) or the result's kind (``lidar_lidar``, ``lidar_camera``, ``multicam``, ...)."""
    result_id: str | None = None
    slot: str | None = None
    method: str = ""
    note: str = ""
    """What the user should know about this edge's sigma (e.g. assumed for a hand-set transform)."""

    def __post_init__(self) -> None:
        self.T_parent_child = np.asarray(self.T_parent_child, dtype=float).reshape(4, 4)
        self.covariance = np.asarray(self.covariance, dtype=float).reshape(6, 6)

    @property
    def label(self) -> str:
        """``r0007 lidar_camera cam_front -> lidar_top`` (or ``mounting prior base_link -> cam``)."""
        what = "mounting prior" if self.kind == "prior" else f"{self.result_id} {self.kind}"
        return f"{what} {self.parent} -> {self.child}"


@dataclass
class EdgeResidual:
    edge: RigEdge
    trans_m: float
    """|translation error| of the measurement against the fused tree (m)."""
    rot_deg: float
    """Rotation error of the measurement against the fused tree (deg)."""
    chi2: float
    """``e^T Sigma^-1 e / 6`` of that error, with the edge's own covariance."""
    disagreement_sigma: float | None
    """Disagreement with the tree solved from every other edge, in sigma of their difference (see
    :data:`FLAG_SIGMA`); None when nothing else constrains this relation."""
    flagged: bool = False
    """Disagrees with the rest beyond :data:`FLAG_SIGMA` and is left out of the fused tree."""
    conflicts_with: list[str] = field(default_factory=list)
    """For a flagged edge: the acceptance slots of the edges it shares a loop with (any of them may be the wrong
    one; reverting one of them instead keeps this edge)."""

    def to_dict(self) -> dict[str, Any]:
        """The CLI's edge entry (``conventions.md``) with the disagreement and flag beside it."""
        e = self.edge
        return {"parent": e.parent, "child": e.child, "kind": e.kind, "result_id": e.result_id, "slot": e.slot,
                "method": e.method,
                "residual": {"trans_m": self.trans_m, "rot_deg": self.rot_deg, "chi2": self.chi2},
                "disagreement_sigma": self.disagreement_sigma, "flagged": self.flagged,
                "conflicts_with": list(self.conflicts_with), "note": e.note}


@dataclass
class FrameEstimate:
    """One frame of the fused tree."""

    name: str
    parent: str | None
    T_parent_child: np.ndarray
    """4x4 (m)."""
    covariance: np.ndarray
    """6x6 of ``T_parent_child`` in the parent (``TRANSFORM_PARAMETERS``)."""
    T_root_frame: np.ndarray
    covariance_root_translation: np.ndarray
    """3x3 (m^2) of the frame's origin in the root's axes (what the 3D view draws as an ellipsoid)."""

    @property
    def std(self) -> dict[str, list[float | None]]:
        """1-sigma in the parent: ``trans_m`` (m) and ``rot_deg`` (deg, about the frame's own axes)."""
        return transform_std(self.covariance)


@dataclass
class RigLoop:
    frames: list[str]
    """The frames around the loop, starting and ending at the first (listed once)."""
    trans_m: float
    """Translation of the composed loop (m): zero for a loop that closes."""
    rot_deg: float
    edges: list[int] = field(default_factory=list)
    """Indices into :attr:`RigTree.edges` of the loop's edges."""

    def to_dict(self) -> dict[str, Any]:
        return {"frames": list(self.frames), "trans_m": self.trans_m, "rot_deg": self.rot_deg}


@dataclass
class RigTree:
    """The fused tree and every check that came with it."""

    root: str
    frames: dict[str, FrameEstimate]
    edges: list[EdgeResidual]
    loops: list[RigLoop]
    unconnected: dict[str, list[str]]
    """Frames no edge connects to the root -> the frames they do connect to."""
    chi2_total: float
    """Sum of the kept edges' (unnormalised) chi-square at the fit."""

    @property
    def flagged(self) -> list[EdgeResidual]:
        return [e for e in self.edges if e.flagged]

    def summary(self) -> dict[str, Any]:
        """The ``calib-studio rig --json`` object: ``frames``, ``edges``, ``loops`` as ``conventions.md`` gives,
        and ``unconnected`` (frame -> frames it connects to)."""
        frames = {name: {"parent": f.parent, "T_parent_child": f.T_parent_child.tolist(), "std": f.std}
                  for name, f in self.frames.items()}
        return {"root": self.root, "frames": frames, "edges": [e.to_dict() for e in self.edges],
                "loops": [loop.to_dict() for loop in self.loops], "unconnected": dict(self.unconnected)}

    def problems(self) -> list[str]:
        """One sentence per thing the user must look at: flagged edges, loops that do not close, lost frames."""
        lines = [f"{e.edge.label} disagrees with the rest of the rig by {e.disagreement_sigma:.1f} sigma "
                 f"({e.trans_m * 1000:.1f} mm, {e.rot_deg:.2f} deg) and is left out of the tree: revert it, or "
                 "revert the edges it disagrees with" for e in self.flagged]
        lines += [f"frame {name!r} is not connected to {self.root} by any edge; it connects to "
                  f"{', '.join(others) if others else 'no other frame'}" for name, others in self.unconnected.items()]
        return lines


# ---------------------------------------------------------------------------------------------
# The fit


def _whitener(covariance: np.ndarray) -> np.ndarray:
    """Lower-triangular ``L`` with ``Sigma = L L^T`` of an edge's covariance, NaN axes made uninformative and the
    matrix made positive definite (eigenvalues clipped at 1e-18)."""
    cov = np.array(covariance, dtype=float)
    undetermined = ~np.isfinite(np.diag(cov))
    undetermined |= ~np.isfinite(cov).all(axis=1)
    if undetermined.any():
        cov[undetermined, :] = 0.0
        cov[:, undetermined] = 0.0
        big = np.r_[np.full(3, UNDETERMINED_SIGMA[0]), np.full(3, UNDETERMINED_SIGMA[1])] ** 2
        cov[undetermined, undetermined] = big[undetermined]
    cov = 0.5 * (cov + cov.T)
    values, vectors = np.linalg.eigh(cov)
    cov = (vectors * np.clip(values, 1e-18, None)) @ vectors.T
    return np.linalg.cholesky(cov)


class _Graph:
    """The unknown poses of the frames reachable from the root, and the edges between them."""

    def __init__(self, root: str, frames: list[str], edges: list[RigEdge]):
        self.root = root
        self.edges = edges
        self.whiteners = [_whitener(e.covariance) for e in edges]
        self.inverse_whiteners = np.array([np.linalg.inv(L) for L in self.whiteners]).reshape(-1, 6, 6)
        self.T0 = self._initial_poses(frames)
        self.names = [name for name in frames if name in self.T0 and name != root]
        self.index = {name: i for i, name in enumerate(self.names)}

    def _initial_poses(self, frames: list[str]) -> dict[str, np.ndarray]:
        """``T_root_frame`` of every frame reachable from the root, along the most precise edges first."""
        order = sorted(range(len(self.edges)), key=lambda i: float(np.trace(self.whiteners[i] @ self.whiteners[i].T)))
        poses = {self.root: np.eye(4)}
        changed = True
        while changed:
            changed = False
            for i in order:
                edge = self.edges[i]
                if edge.parent in poses and edge.child not in poses and edge.child in frames:
                    poses[edge.child] = poses[edge.parent] @ edge.T_parent_child
                    changed = True
                elif edge.child in poses and edge.parent not in poses and edge.parent in frames:
                    poses[edge.parent] = poses[edge.child] @ invert(edge.T_parent_child)
                    changed = True
        return poses

    def poses(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """``T_root_frame`` of every solved frame at the steps ``x`` (6 per frame, ``TRANSFORM_PARAMETERS``)."""
        out = {self.root: np.eye(4)}
        if self.names:
            moved = apply_params_many(np.stack([self.T0[n] for n in self.names]), x.reshape(-1, 6))
            out.update(zip(self.names, moved, strict=True))
        return out

    def edge_errors(self, kept: list[int], poses: dict[str, np.ndarray]) -> np.ndarray:
        """(len(kept), 6) errors of the edges' measurements against ``poses``: ``params_between(measured,
        predicted)``, vectorised over the edges."""
        measured = np.stack([self.edges[k].T_parent_child for k in kept])
        T_root_parent = np.stack([poses[self.edges[k].parent] for k in kept])
        predicted = invert(T_root_parent) @ np.stack([poses[self.edges[k].child] for k in kept])
        rotation = Rotation.from_matrix(np.transpose(measured[:, :3, :3], (0, 2, 1)) @ predicted[:, :3, :3])
        return np.hstack([predicted[:, :3, 3] - measured[:, :3, 3], rotation.as_rotvec()])

    def edge_error(self, k: int, poses: dict[str, np.ndarray]) -> np.ndarray:
        return self.edge_errors([k], poses)[0]

    def residuals(self, x: np.ndarray, kept: list[int]) -> np.ndarray:
        if not kept:
            return np.zeros(0)
        errors = self.edge_errors(kept, self.poses(x))
        return np.einsum("kij,kj->ki", self.inverse_whiteners[kept], errors).ravel()

    def jacobian(self, x: np.ndarray, kept: list[int]) -> np.ndarray:
        """(6 len(kept), 6 n) whitened Jacobian of :meth:`residuals` at ``x`` (forward differences, step 1e-7).

        Columns that share no residual row are stepped together (:func:`_column_groups`), as SciPy does for a
        sparse Jacobian: one evaluation then serves a step of every frame no kept edge joins to another of them.
        """
        base = self.residuals(x, kept)
        pattern = self.sparsity(kept)
        J = np.zeros((len(base), len(x)))
        for group in _column_groups(pattern):
            moved = x.copy()
            moved[group] += JACOBIAN_STEP
            change = (self.residuals(moved, kept) - base) / JACOBIAN_STEP
            J[:, group] = np.where(pattern[:, group], change[:, None], 0.0)
        return J

    def sparsity(self, kept: list[int]) -> np.ndarray:
        """Which steps each residual row depends on: an edge's six rows on its two frames' six columns each."""
        pattern = np.zeros((6 * len(kept), 6 * len(self.names)), dtype=bool)
        for row, k in enumerate(kept):
            for frame in (self.edges[k].parent, self.edges[k].child):
                if frame in self.index:
                    pattern[6 * row:6 * row + 6, 6 * self.index[frame]:6 * self.index[frame] + 6] = True
        return pattern

    def usable(self, k: int) -> bool:
        edge = self.edges[k]
        return edge.parent in self.T0 and edge.child in self.T0

    def fit(self, kept: list[int], x0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, float]:
        """Solve with the edges ``kept``; returns the steps ``x``, their covariance and the total chi-square.

        A rig has tens of frames, so the steps are solved densely: Levenberg-Marquardt (MINPACK) with
        :meth:`jacobian`, or SciPy's trust region when fewer residuals than steps rule LM out. The iterative
        ``lsmr`` solver that a sparsity pattern selects stalled on these small, stiff problems (a 0.01 mm stereo
        edge beside 50 mm priors): in a six-node depth cell, each refit without one edge used all 200 evaluations
        and stopped 2 % above the minimum that LM reaches in 3.
        """
        n = 6 * len(self.names)
        x0 = np.zeros(n) if x0 is None else x0
        kept = [k for k in kept if self.usable(k)]
        if n == 0:
            return x0, np.zeros((0, 0)), 0.0
        method = "lm" if 6 * len(kept) >= n else "trf"
        solution = least_squares(self.residuals, x0, jac=self.jacobian, args=(kept,), method=method,
                                 xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=200)
        J = self.jacobian(solution.x, kept)
        covariance = np.linalg.pinv(J.T @ J)
        return solution.x, 0.5 * (covariance + covariance.T), float(2 * solution.cost)

    def relative(self, x: np.ndarray, covariance: np.ndarray, a: str, b: str) -> tuple[np.ndarray, np.ndarray]:
        """``T_a_b`` at ``x`` and its 6x6 covariance (``TRANSFORM_PARAMETERS``), by a numerical Jacobian."""
        poses = self.poses(x)
        T = invert(poses[a]) @ poses[b]
        columns = [6 * self.index[f] + j for f in (a, b) if f in self.index for j in range(6)]
        if not columns:
            return T, np.zeros((6, 6))
        J = np.zeros((6, len(columns)))
        for c, column in enumerate(columns):
            moved = x.copy()
            moved[column] += JACOBIAN_STEP
            P = self.poses(moved)
            J[:, c] = params_between(T, invert(P[a]) @ P[b]) / JACOBIAN_STEP
        sub = covariance[np.ix_(columns, columns)]
        return T, J @ sub @ J.T


def _column_groups(pattern: np.ndarray) -> list[list[int]]:
    """The columns of a boolean sparsity ``pattern`` (rows x columns) that depend on anything, in groups of which
    no two share a row (greedy, in column order)."""
    groups: list[list[int]] = []
    rows_taken: list[np.ndarray] = []
    for column in np.flatnonzero(pattern.any(axis=0)):
        rows = pattern[:, column]
        for group, taken in zip(groups, rows_taken, strict=True):
            if not (taken & rows).any():
                group.append(int(column))
                taken |= rows
                break
        else:
            groups.append([int(column)])
            rows_taken.append(rows.copy())
    return groups


def _edge_residual(graph: _Graph, k: int, poses: dict[str, np.ndarray], disagreement: float | None,
                   flagged: bool) -> EdgeResidual:
    error = graph.edge_error(k, poses)
    whitened = solve_triangular(graph.whiteners[k], error, lower=True)
    return EdgeResidual(graph.edges[k], float(np.linalg.norm(error[:3])), float(np.degrees(np.linalg.norm(error[3:]))),
                        float(whitened @ whitened / 6.0), disagreement, flagged)


def _as_sigma(mahalanobis2: float, dof: int = 6) -> float:
    """The Gaussian sigma whose two-sided probability equals that of a chi-square ``mahalanobis2`` on ``dof``."""
    return float(norm.isf(chi2.sf(mahalanobis2, dof) / 2))


def _leave_one_out(graph: _Graph, kept: list[int], x: np.ndarray, covariance: np.ndarray, chi2_total: float
                   ) -> dict[int, tuple[float | None, float]]:
    """Every kept edge against the fit of all the others: ``k -> (disagreement in sigma, or None when the others
    do not reach both its frames; the others' total chi-square)``.

    From the one fit, by the linear least-squares identities (Cook's leave-one-out): with the whitened Jacobian's
    hat block ``P_k = J_k (J^T J)^-1 J_k^T`` of edge ``k``, its measurement differs from the others' prediction by
    ``(I - P_k)^-1 r_k`` with covariance ``(I - P_k)^-1``, so its squared Mahalanobis distance is
    ``r_k^T (I - P_k)^-1 r_k``, which is also what leaving it out takes off the total chi-square.

    An edge that leaves the others less than :data:`REFIT_LEVERAGE` of some direction is refitted without instead
    (:func:`_against_fit`): a stereo pair (sigma 0.01 mm) beside its cameras' mounting priors (50 mm) leaves them
    1e-8, as small as the solver's tolerance and the Jacobian's error, and from the one fit it came out
    unconstrained in some fresh demos and flagged in others.
    """
    J, r = graph.jacobian(x, kept), graph.residuals(x, kept)
    out = {}
    for row, k in enumerate(kept):
        rows = slice(6 * row, 6 * row + 6)
        complement = np.eye(6) - J[rows] @ covariance @ J[rows].T
        if np.linalg.eigvalsh(0.5 * (complement + complement.T)).min() < REFIT_LEVERAGE:
            others = [j for j in kept if j != k]
            if not _reaches(graph, k, others):  # a frame's only edge (a prior alone): nothing to refit
                out[k] = (None, chi2_total)
                continue
            x_k, covariance_k, chi2_k = graph.fit(others, x)
            out[k] = (_against_fit(graph, k, others, x_k, covariance_k), chi2_k)
            continue
        mahalanobis2 = float(r[rows] @ np.linalg.solve(complement, r[rows]))
        out[k] = (_as_sigma(mahalanobis2), max(chi2_total - mahalanobis2, 0.0))
    return out


def _against_fit(graph: _Graph, k: int, kept: list[int], x: np.ndarray, covariance: np.ndarray) -> float | None:
    """A left-out edge ``k`` against the fit of ``kept``, in sigma (None when ``kept`` does not reach both its
    frames)."""
    if not _reaches(graph, k, kept):
        return None
    J, r = graph.jacobian(x, [k]), graph.residuals(x, [k])
    return _as_sigma(float(r @ np.linalg.solve(np.eye(6) + J @ covariance @ J.T, r)))


def _reaches(graph: _Graph, k: int, kept: list[int]) -> bool:
    """Whether the edges ``kept`` connect both frames of edge ``k`` to the root."""
    reachable = _reachable(graph.root, [graph.edges[j] for j in kept])
    return graph.edges[k].parent in reachable and graph.edges[k].child in reachable


def _reachable(root: str, edges: list[RigEdge]) -> set[str]:
    neighbours: dict[str, set[str]] = {}
    for e in edges:
        neighbours.setdefault(e.parent, set()).add(e.child)
        neighbours.setdefault(e.child, set()).add(e.parent)
    seen, queue = {root}, deque([root])
    while queue:
        for other in neighbours.get(queue.popleft(), ()):
            if other not in seen:
                seen.add(other)
                queue.append(other)
    return seen


def _culprit(graph: _Graph, candidates: list[int], rest_chi2: dict[int, float], kept: list[int]) -> int:
    """Of the edges that disagree, the newest whose removal leaves the rest consistent; when none does, the one
    whose removal leaves the smallest chi-square."""
    dof = 6 * (len(kept) - 1) - 6 * len(graph.names)
    limit = chi2.ppf(CONSISTENT_PROBABILITY, dof) if dof > 0 else 0.0
    consistent = [k for k in candidates if rest_chi2[k] <= limit]
    return max(consistent) if consistent else min(candidates, key=lambda k: rest_chi2[k])


def _loops(edges: list[RigEdge], measured: list[int]) -> list[RigLoop]:
    """The fundamental loops of the measured edges (a spanning forest's non-tree edges) and their closure."""
    parent_of: dict[str, tuple[str, int] | None] = {}
    tree_edges: set[int] = set()
    neighbours: dict[str, list[tuple[str, int]]] = {}
    for k in measured:
        e = edges[k]
        neighbours.setdefault(e.parent, []).append((e.child, k))
        neighbours.setdefault(e.child, []).append((e.parent, k))
    depth: dict[str, int] = {}
    for start in neighbours:
        if start in parent_of:
            continue
        parent_of[start], depth[start] = None, 0
        queue = deque([start])
        while queue:
            frame = queue.popleft()
            for other, k in neighbours[frame]:
                if other not in parent_of:
                    parent_of[other], depth[other] = (frame, k), depth[frame] + 1
                    tree_edges.add(k)
                    queue.append(other)
    loops = []
    for k in measured:
        if k in tree_edges:
            continue
        e = edges[k]
        path_a, path_b = [e.parent], [e.child]  # walk both ends up to their common ancestor
        steps_a, steps_b = [], []
        while path_a[-1] != path_b[-1]:
            if depth[path_a[-1]] >= depth[path_b[-1]]:
                up, via = parent_of[path_a[-1]]
                steps_a.append(via)
                path_a.append(up)
            else:
                up, via = parent_of[path_b[-1]]
                steps_b.append(via)
                path_b.append(up)
        # the loop: parent -> ... -> ancestor -> ... -> child -> (edge k) -> parent
        frames = path_a + path_b[-2::-1]
        loop_edges = steps_a + steps_b[::-1] + [k]
        T = np.eye(4)
        for frame_from, j in zip(frames, loop_edges, strict=True):
            edge = edges[j]
            T = T @ (edge.T_parent_child if edge.parent == frame_from else invert(edge.T_parent_child))
        loops.append(RigLoop(frames, float(np.linalg.norm(T[:3, 3])), rotation_angle_deg(T[:3, :3]), loop_edges))
    return loops


def solve_rig_graph(root: str, parents: dict[str, str | None], edges: list[RigEdge]) -> RigTree:
    """Fuse ``edges`` (oldest first; priors count as edges) into the tree whose frame ``f`` hangs under
    ``parents[f]``.

    Flagged edges are left out of the fused tree one at a time (:func:`_culprit`) until no kept edge
    disagrees with the rest beyond :data:`FLAG_SIGMA`. Frames no edge connects to the root are
    reported in ``unconnected`` and left out of ``frames``.
    """
    names = list(parents)
    graph = _Graph(root, names, edges)
    usable = [k for k in range(len(edges)) if graph.usable(k)]
    kept = list(usable)
    flagged: set[int] = set()
    disagreements: dict[int, float | None] = {}
    x, covariance, chi2_total = graph.fit(kept)
    while True:
        checks = _leave_one_out(graph, kept, x, covariance, chi2_total)
        disagreements.update({k: sigma for k, (sigma, _) in checks.items()})
        rest_chi2 = {k: rest for k, (_, rest) in checks.items()}
        candidates = [k for k in kept if (d := disagreements[k]) is not None and d > FLAG_SIGMA]
        if not candidates:
            break
        culprit = _culprit(graph, candidates, rest_chi2, kept)
        flagged.add(culprit)
        kept.remove(culprit)
        x, covariance, chi2_total = graph.fit(kept, x)
    for k in flagged:  # its disagreement with everything that was kept
        disagreements[k] = _against_fit(graph, k, kept, x, covariance)
    poses = graph.poses(x)
    residuals = [_edge_residual(graph, k, poses, disagreements.get(k), k in flagged) if k in usable else
                 EdgeResidual(edges[k], float("nan"), float("nan"), float("nan"), None, False)
                 for k in range(len(edges))]
    frames = {}
    for name in graph.names:
        parent = parents[name]
        if parent not in poses:
            continue
        T, cov = graph.relative(x, covariance, parent, name)
        i = 6 * graph.index[name]
        frames[name] = FrameEstimate(name, parent, T, cov, poses[name], covariance[i:i + 3, i:i + 3].copy())
    measured = [k for k in usable if edges[k].kind != "prior"]
    loops = _loops(edges, measured)
    for k in flagged:
        shared = {j for loop in loops if k in loop.edges for j in loop.edges if j != k}
        residuals[k].conflicts_with = list(dict.fromkeys(edges[j].slot for j in sorted(shared) if edges[j].slot))
    unconnected = {}
    for name in names:
        if name == root or name in graph.T0:
            continue
        linked = sorted({e.child if e.parent == name else e.parent for e in edges if name in (e.parent, e.child)})
        unconnected[name] = linked
    return RigTree(root, frames, residuals, loops, unconnected, chi2_total)

