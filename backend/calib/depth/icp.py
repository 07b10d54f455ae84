"""ICP between two depth nodes' clouds: one more constraint of a depth network, never the only one.

Ceiling nodes of a cell see mostly floor, and each other's views overlap little and at steep angles,
so ICP between them slides along the floor: the paper found about 10 cm of error from pairwise ICP
alone, against millimetres from the cell's known geometry (:mod:`backend.calib.depth.node`).
:func:`pairwise_icp` is Open3D's point-to-plane ICP between two nodes' clouds in the world frame,
with the uncertainty of its point-to-plane residuals; :func:`icp_network` chains it from one node
held fixed through the pairs that overlap most, the ICP-only baseline the tests and the benchmark
hold the constraint solve against.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass

import numpy as np

from backend.calib.depth.checks import icp_verdict
from backend.core.errors import InputError
from backend.core.result import TransformResult
from backend.core.transforms import check_transform, invert, skew, transform_points


@dataclass
class DepthIcpSettings:
    """Open3D point-to-plane ICP between two depth nodes (m)."""

    voxel_m: float = 0.05
    """Both clouds are voxel-downsampled to this before ICP."""
    max_correspondence_m: float = 0.2
    max_iterations: int = 50
    normal_radius_m: float = 0.15
    """Radius of the target's normal estimation (at most 30 neighbours)."""
    min_points: int = 100
    min_fitness: float = 0.05
    """Below this share of the source points with a partner the clouds do not overlap: the result is rejected."""
    translation_tolerance_m: float = 0.005
    rotation_tolerance_deg: float = 0.05


def _cloud(points: np.ndarray, name: str, settings: DepthIcpSettings):
    """An Open3D cloud of the finite rows of ``points`` (N, 3, m), voxel-downsampled; InputError naming ``name``
    when malformed or too small."""
    import open3d as o3d

    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"{name} must be (N, 3) in metres, got shape {points.shape}", name)
    points = points[np.isfinite(points).all(axis=1)]
    if len(points) < settings.min_points:
        raise InputError(f"{name}: {len(points)} finite points; ICP needs at least {settings.min_points}", name)
    return o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points)).voxel_down_sample(settings.voxel_m)


SLIDE_SHARE = 0.01
"""A direction the correspondences' normals (or, for rotations, their moment arms) face less than this share of
the time is one the clouds slide along: ICP leaves it undetermined (a floor seen alone: X, Y and the heading)."""


def point_to_plane_covariance(source_world: np.ndarray, target_world: np.ndarray, target_normals: np.ndarray,
                              correspondences: np.ndarray) -> np.ndarray:
    """6x6 covariance of a world-frame correction ``p -> p + w x p + t`` (order ``[t (m), w (rad)]``) from the
    point-to-plane residuals ``n . (p - q)`` of ``correspondences`` (K, 2: source, target rows): ``sigma^2 (J^T
    J)^-1`` with ``J = [n, p x n]`` and ``sigma^2`` their variance.

    All NaN when the geometry lets the clouds slide (some direction of ``n``, or of ``(p - centre) x n`` over the
    mean squared arm, holds less than :data:`SLIDE_SHARE` of the information): noise in the normals of a floor
    would otherwise pass for information and give millimetre sigmas to a metre-wide slide."""
    p = source_world[correspondences[:, 0]]
    q = target_world[correspondences[:, 1]]
    n = target_normals[correspondences[:, 1]]
    arms = np.cross(p - p.mean(axis=0), n)
    shares = np.r_[np.linalg.eigvalsh(n.T @ n / len(n)),
                   np.linalg.eigvalsh(arms.T @ arms) / max(np.sum((p - p.mean(axis=0)) ** 2), 1e-12)]
    if shares.min() < SLIDE_SHARE:
        return np.full((6, 6), np.nan)
    J = np.hstack([n, np.cross(p, n)])
    r = np.einsum("ij,ij->i", n, p - q)
    sigma2 = float(r @ r) / max(len(r) - 6, 1)
    return sigma2 * np.linalg.inv(J.T @ J)


def pairwise_icp(node_a: str, points_a_world: np.ndarray, node_b: str, points_b_world: np.ndarray,
                 T_world_a: np.ndarray, T_world_b: np.ndarray, settings: DepthIcpSettings | None = None
                 ) -> TransformResult:
    """``T_a_b`` between two nodes by point-to-plane ICP of their clouds (each (N, 3), m, in the world frame as
    the poses ``T_world_a`` / ``T_world_b`` place them): a :class:`TransformResult` (``kind`` "depth_node",
    ``method`` "icp", ``parent`` ``node_a``, ``child`` ``node_b``) with the covariance of the point-to-plane fit.

    ICP moves ``b``'s cloud onto ``a``'s: ``T_a_b = T_world_a^-1 T_corr T_world_b``. ``residuals``: ``fitness``
    (share of b's downsampled points with a partner within ``max_correspondence_m``), ``rmse_m``,
    ``n_correspondences``. Its verdict is never ``trusted``: ICP between nodes is one more constraint, checked
    by the cell's known geometry."""
    import open3d as o3d

    started = time.perf_counter()
    settings = settings or DepthIcpSettings()
    T_world_a, _ = check_transform(T_world_a, "T_world_a")
    T_world_b, _ = check_transform(T_world_b, "T_world_b")
    target = _cloud(points_a_world, f"points of {node_a}", settings)
    source = _cloud(points_b_world, f"points of {node_b}", settings)
    target.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(settings.normal_radius_m, 100))
    reg = o3d.pipelines.registration
    fit = reg.registration_icp(source, target, settings.max_correspondence_m, np.eye(4),
                               reg.TransformationEstimationPointToPlane(),
                               reg.ICPConvergenceCriteria(max_iteration=settings.max_iterations))
    T_corr = np.asarray(fit.transformation)
    T_world_b_new = T_corr @ T_world_b
    T_a_b = invert(T_world_a) @ T_world_b_new
    correspondences = np.asarray(fit.correspondence_set)
    if len(correspondences) >= 6:
        cov_world = point_to_plane_covariance(transform_points(T_corr, np.asarray(source.points)),
                                              np.asarray(target.points), np.asarray(target.normals),
                                              correspondences)
    else:
        cov_world = np.full((6, 6), np.nan)
    # the world correction (t, w) as T_a_b's parameters: dt = R_aw (t - [t_wb] w) (a's axes), dr = R_wb^T w (b's)
    R_aw = T_world_a[:3, :3].T
    M = np.zeros((6, 6))
    M[:3, :3] = R_aw
    M[:3, 3:] = -R_aw @ skew(T_world_b_new[None, :3, 3])[0]
    M[3:, 3:] = T_world_b_new[:3, :3].T
    covariance = M @ cov_world @ M.T if np.isfinite(cov_world).all() else np.full((6, 6), np.nan)
    result = TransformResult(
        kind="depth_node", method="icp", parent=node_a, child=node_b, T_parent_child=T_a_b, covariance=covariance,
        residuals={"fitness": float(fit.fitness), "rmse_m": float(fit.inlier_rmse),
                   "n_correspondences": int(len(correspondences))},
        diagnostics={"T_correction": T_corr.tolist(), "T_world_a": T_world_a.tolist(),
                     "T_world_b": T_world_b.tolist(), "T_a_b_initial": (invert(T_world_a) @ T_world_b).tolist()},
        settings=asdict(settings), converged=bool(fit.fitness >= settings.min_fitness))
    result.verdict = icp_verdict(result, float(fit.fitness), settings)
    result.seconds = time.perf_counter() - started
    return result


def icp_network(root: str, T_world_root: np.ndarray, clouds: dict[str, np.ndarray],
                T_world_guess: dict[str, np.ndarray], settings: DepthIcpSettings | None = None
                ) -> tuple[dict[str, np.ndarray], list[TransformResult]]:
    """Every node's ``T_world_node`` from pairwise ICP alone: ``root`` held at ``T_world_root``, each other node
    reached through the pair that overlaps most (Prim's tree over the share of points within
    ``max_correspondence_m`` of each other, every cloud (N, 3, node frame, m) placed by its guess), then ICP along
    the tree from the root. Returns the poses and the tree's edges (:func:`pairwise_icp` results, parent towards
    the root); a node that overlaps no reached node, or whose ICP did not converge, keeps its guess."""
    import open3d as o3d

    settings = settings or DepthIcpSettings()
    placed = {root: check_transform(T_world_root, "T_world_root")[0]} | {
        name: check_transform(T, f"T_world_guess[{name!r}]")[0] for name, T in T_world_guess.items() if name != root}
    down = {name: _cloud(transform_points(placed[name], clouds[name]), f"points of {name}", settings)
            for name in clouds}
    reg = o3d.pipelines.registration
    reached, order, pending = [root], [], [name for name in clouds if name != root]
    while pending:
        overlap, a, b = max((reg.evaluate_registration(down[b], down[a], settings.max_correspondence_m).fitness, a, b)
                            for a in reached for b in pending)
        if overlap < settings.min_fitness:
            break
        order.append((a, b))
        reached.append(b)
        pending.remove(b)
    poses, edges = {root: placed[root]}, []
    for a, b in order:
        result = pairwise_icp(a, transform_points(poses[a], clouds[a]), b, transform_points(placed[b], clouds[b]),
                              poses[a], placed[b], settings)
        poses[b] = poses[a] @ result.T_parent_child if result.converged else placed[b]
        edges.append(result)
    return poses | {name: placed[name] for name in pending}, edges
