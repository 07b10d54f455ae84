#!/usr/bin/env python
"""Rig graph benchmark: our pose-graph fusion against Open3D's pose-graph optimisation on the same edges.

What it measures, in one run on :data:`TRIALS` simulated rigs (the mining robot's layout: four cameras,
three LiDARs and a depth camera on ``base_link``, known truth):

- every frame's mounting guess is the truth off by tape errors (2 cm, 2 deg per axis, stated as such);
  :data:`EDGES` calibrations (camera-camera, LiDAR-camera, LiDAR-LiDAR; 1-3 mm, 0.03-0.1 deg, stated)
  form several loops;
- ``error_mm`` / ``error_deg``: the mean over trials and frames of our fused ``T_base_frame`` error;
  ``open3d_error_*``: the same for ``open3d.pipelines.registration.global_optimization``
  (Levenberg-Marquardt, ``base_link`` as the reference node, the same edges with the information
  matrices reordered to Open3D's rotation-first convention) — the in-run baseline;
- ``error_ratio``: ours / Open3D's (< 1: ours is closer to the truth);
- ``within_3_sigma``: the fraction of our frames' per-axis errors within 3 of their sigmas (Open3D gives none);
- ``solve_s`` / ``open3d_s``: the median time of one fit (ours includes the leave-one-out checks over
  every edge, which Open3D does not make), and their ratio;
- ``corrupted_flagged``: over the trials, the fraction in which an edge accepted last and 5 cm off is the
  one flagged (Open3D's line process prunes only edges marked uncertain, so it has no such figure).

Prints exactly one JSON object on stdout; progress goes to stderr.
"""

import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_util import log, pose_error  # noqa: E402

from backend.calib.rig.graph import RigEdge, solve_rig_graph  # noqa: E402
from backend.core.transforms import apply_params, from_xyz_ypr, invert, params_between  # noqa: E402

TRIALS = 12
FRAMES = {  # x, y, z (m), yaw, pitch, roll (deg) on base_link
    "cam_rgb": ((0.45, 0.10, 0.60), (0, 0, 0)), "cam_left": ((0.45, 0.06, 0.62), (2, 1, 0)),
    "cam_right": ((0.45, -0.06, 0.62), (-2, 1, 0)), "cam_thermal": ((0.44, 0.0, 0.70), (0, 5, 0)),
    "livox": ((0.50, 0.0, 0.45), (0, 8, 0)), "velodyne": ((0.0, 0.0, 1.0), (30, 0, 0)),
    "lidar_rear": ((-0.4, 0.0, 0.6), (180, 3, 0)), "realsense": ((0.48, -0.1, 0.50), (-5, 10, 0)),
}
EDGES = [  # parent, child, sigma m, sigma deg
    ("cam_left", "cam_right", 0.001, 0.03), ("cam_left", "cam_rgb", 0.0015, 0.04),
    ("cam_rgb", "cam_thermal", 0.002, 0.06), ("cam_rgb", "livox", 0.003, 0.1),
    ("cam_left", "livox", 0.003, 0.1), ("livox", "velodyne", 0.002, 0.05),
    ("velodyne", "lidar_rear", 0.002, 0.05), ("cam_right", "realsense", 0.003, 0.1),
    ("livox", "realsense", 0.002, 0.08), ("cam_thermal", "velodyne", 0.004, 0.1),
]
PRIOR_SIGMA = (0.02, 2.0)


def covariance(sigma_m, sigma_deg):
    return np.diag([sigma_m**2] * 3 + [np.radians(sigma_deg) ** 2] * 3)


def noisy(rng, T, sigma_m, sigma_deg):
    step = np.r_[rng.normal(0, sigma_m, 3), rng.normal(0, np.radians(sigma_deg), 3)]
    return apply_params(T, step)


def simulated_edges(rng, truth):
    edges = [RigEdge("base_link", name, noisy(rng, T, *PRIOR_SIGMA), covariance(*PRIOR_SIGMA), "prior")
             for name, T in truth.items()]
    for i, (parent, child, sigma_m, sigma_deg) in enumerate(EDGES):
        T = noisy(rng, invert(truth[parent]) @ truth[child], sigma_m, sigma_deg)
        edges.append(RigEdge(parent, child, T, covariance(sigma_m, sigma_deg), "sim", f"r{i}", f"slot{i}"))
    return edges


def open3d_fit(edges, names):
    """Open3D's pose graph on the same edges: node 0 is base_link; an edge (parent, child, T_parent_child) maps
    the child node's points into the parent's, so it is Open3D's edge (source=child, target=parent)."""
    import open3d as o3d

    reg = o3d.pipelines.registration
    index = {name: i for i, name in enumerate(["base_link", *names])}
    graph = reg.PoseGraph()
    initial = {"base_link": np.eye(4)} | {e.child: e.T_parent_child for e in edges if e.kind == "prior"}
    for name in index:
        graph.nodes.append(reg.PoseGraphNode(initial[name]))
    reorder = np.r_[3:6, 0:3]  # Open3D's information is over [rotation, translation]
    for e in edges:
        information = np.linalg.inv(e.covariance)[np.ix_(reorder, reorder)]
        graph.edges.append(reg.PoseGraphEdge(index[e.child], index[e.parent], e.T_parent_child, information,
                                             uncertain=False))
    option = reg.GlobalOptimizationOption(max_correspondence_distance=1.0, edge_prune_threshold=0.25,
                                          preference_loop_closure=1.0, reference_node=0)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    reg.global_optimization(graph, reg.GlobalOptimizationLevenbergMarquardt(),
                            reg.GlobalOptimizationConvergenceCriteria(), option)
    return {name: graph.nodes[i].pose for name, i in index.items()}


def main():
    truth = {name: from_xyz_ypr(np.array(xyz), np.radians(ypr)) for name, (xyz, ypr) in FRAMES.items()}
    parents = {"base_link": None} | dict.fromkeys(truth, "base_link")
    ours, theirs, covered, ours_s, theirs_s, flagged = [], [], [], [], [], 0
    for trial in range(TRIALS):
        rng = np.random.default_rng(trial)
        edges = simulated_edges(rng, truth)
        start = time.perf_counter()
        tree = solve_rig_graph("base_link", parents, edges)
        ours_s.append(time.perf_counter() - start)
        start = time.perf_counter()
        poses = open3d_fit(edges, list(truth))
        theirs_s.append(time.perf_counter() - start)
        for name, T_true in truth.items():
            estimate = tree.frames[name]
            ours.append(pose_error(estimate.T_root_frame, T_true))
            theirs.append(pose_error(poses[name], T_true))
            error = params_between(T_true, estimate.T_parent_child)
            covered.extend(np.abs(error) <= 3 * np.sqrt(np.diag(estimate.covariance)))
        corrupted = list(edges)
        last = corrupted[-1]
        corrupted[-1] = RigEdge(last.parent, last.child, last.T_parent_child @ from_xyz_ypr(
            np.array([0.05, 0.0, 0.0]), np.zeros(3)), last.covariance, last.kind, last.result_id, last.slot)
        flagged += [e.edge.result_id for e in solve_rig_graph("base_link", parents, corrupted).flagged] == [
            last.result_id]
        log(f"trial {trial + 1}/{TRIALS}: ours {np.mean([o[0] for o in ours[-len(truth):]]):.2f} mm, "
            f"Open3D {np.mean([t[0] for t in theirs[-len(truth):]]):.2f} mm")
    ours, theirs = np.array(ours), np.array(theirs)
    print(json.dumps({
        "trials": TRIALS, "frames": len(truth), "edges": len(EDGES),
        "error_mm": float(ours[:, 0].mean()), "error_deg": float(ours[:, 1].mean()),
        "open3d_error_mm": float(theirs[:, 0].mean()), "open3d_error_deg": float(theirs[:, 1].mean()),
        "error_ratio": float(ours[:, 0].mean() / theirs[:, 0].mean()),
        "within_3_sigma": float(np.mean(covered)),
        "solve_s": float(np.median(ours_s)), "open3d_s": float(np.median(theirs_s)),
        "solve_ratio": float(np.median(ours_s) / np.median(theirs_s)),
        "corrupted_flagged": flagged / TRIALS,
    }))


if __name__ == "__main__":
    main()
