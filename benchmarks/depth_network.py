#!/usr/bin/env python
"""Depth-network benchmark: the automatic and guided solves of every node of the simulated cell, against
pairwise ICP alone on the same clouds.

What it measures, in one run on the simulated cell (``backend.sim.depth_cell``: the paper's six Kinect v2
nodes at their calibrated poses, 512 x 424 time-of-flight depth with the range noise of a Kinect v2):

- per node, three noisy captures: three tables behind each other, three beside each other, and none
  (floor, tape lines and crosses); the initial pose is the truth off by ``GUESS_OFF_M`` / ``GUESS_OFF_DEG``
  in random directions (a tape measure's accuracy, stated as such);
- ``solve_s``: the median wall time (``REPEATS`` runs) of ``solve_depth_node`` per node (feature extraction in
  every round, the least-squares solves, the leave-one-capture-out jackknife and the verdict) and
  ``solve_cpu_s`` the process CPU time of one (what the solve costs on an idle machine: the wall time
  grows with the load the start line reports);
  ``error_mm`` / ``error_deg``: the norm of its translation error and the angle of its rotation error against
  the truth; ``sigma_mm`` / ``sigma_deg``: the norm of its reported 1-sigma; ``verdict``;
- ``guided_s``, ``guided_error_mm`` / ``_deg``: the guided procedure's advice applied for its four steps in
  order, twice (``depth_guided.advise``), from the same guess;
- the baseline, ``icp_error_mm`` / ``_deg``: Open3D point-to-plane ICP alone (``depth_icp.icp_network``):
  ``sn1`` held at the truth, every other node reached through the pair that overlaps most, from the same
  guesses, on the same clouds (the captures without tables, one scene); ``icp_s`` its time for the network;
- ``error_ratio``: the worst ICP error over the worst automatic error (> 1: ICP alone is that much worse);
- ``peak_rss_mb``: the peak resident memory at the end.

Prints exactly one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/depth_network.py
"""

import json
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_util import REPEATS, log, median_time, peak_rss_mb, pose_error  # noqa: E402

from backend.calib.depth.features import DepthObservation  # noqa: E402
from backend.calib.depth.guided import GUIDED_STEPS, advise  # noqa: E402
from backend.calib.depth.icp import icp_network  # noqa: E402
from backend.calib.depth.node import solve_depth_node  # noqa: E402
from backend.core.depth import KINECT_V2  # noqa: E402
from backend.core.depth_cell import PAPER_NODE_POSES, default_cell_layout  # noqa: E402
from backend.core.transforms import apply_params  # noqa: E402
from backend.sim.depth_cell import CellScene, node_pose, table_placements  # noqa: E402

GUESS_OFF_M, GUESS_OFF_DEG = 0.05, 2.0
GUIDED_PASSES = 2


def main():
    started = time.perf_counter()
    log(f"load average at start: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores (other processes skew the "
        "timings)")
    layout = default_cell_layout()
    empty = CellScene(layout, [])
    rng = np.random.default_rng(1)
    nodes, free_clouds, guesses = {}, {}, {}
    for k, node in enumerate(PAPER_NODE_POSES):
        T_true = node_pose(node)
        observations = []
        for i, arrangement in enumerate(("behind", "beside", "free")):
            scene = empty if arrangement == "free" else CellScene(layout, table_placements(node, arrangement, layout))
            frame = scene.render(T_true, np.random.default_rng(100 * k + i))
            points, index = KINECT_V2.unproject(frame.depth_m)
            observations.append(DepthObservation(f"c{i}", points, frame.amplitude.ravel()[index], index,
                                                 list(layout.tables) if scene.placements else [], arrangement))
        direction, axis = rng.normal(size=3), rng.normal(size=3)
        guesses[node] = apply_params(T_true, np.r_[GUESS_OFF_M * direction / np.linalg.norm(direction),
                                                   np.radians(GUESS_OFF_DEG) * axis / np.linalg.norm(axis)])
        free_clouds[node] = observations[2].points

        log(f"{node}: solving x{REPEATS} ...")
        solve_s = median_time(lambda: solve_depth_node(node, observations, layout, guesses[node]))  # noqa: B023
        cpu_start = time.process_time()
        result = solve_depth_node(node, observations, layout, guesses[node])
        solve_cpu_s = time.process_time() - cpu_start
        error_mm, error_deg = pose_error(result.T_parent_child, T_true)
        sigma = result.std_vector

        guided_start = time.perf_counter()
        T = guesses[node]
        for _ in range(GUIDED_PASSES):
            for step in GUIDED_STEPS:
                T = advise(step, observations, layout, T).T_suggested
        guided_s = time.perf_counter() - guided_start
        guided_mm, guided_deg = pose_error(T, T_true)
        nodes[node] = {"points": int(sum(len(o.points) for o in observations)), "solve_s": solve_s,
                       "solve_cpu_s": solve_cpu_s,
                       "error_mm": error_mm, "error_deg": error_deg,
                       "sigma_mm": float(np.linalg.norm(sigma[:3]) * 1e3),
                       "sigma_deg": float(np.degrees(np.linalg.norm(sigma[3:]))),
                       "verdict": result.verdict.level, "guided_s": guided_s, "guided_error_mm": guided_mm,
                       "guided_error_deg": guided_deg}
        log(f"  {solve_s:.2f} s ({solve_cpu_s:.2f} s CPU), {error_mm:.2f} mm {error_deg:.4f} deg "
            f"({result.verdict.level}); guided {guided_s:.1f} s, {guided_mm:.2f} mm {guided_deg:.4f} deg")

    log("pairwise ICP alone from sn1 ...")
    icp_start = time.perf_counter()
    icp_poses, edges = icp_network("sn1", node_pose("sn1"), free_clouds, {n: guesses[n] for n in nodes if n != "sn1"})
    icp_s = time.perf_counter() - icp_start
    for node in nodes:
        nodes[node]["icp_error_mm"], nodes[node]["icp_error_deg"] = pose_error(icp_poses[node], node_pose(node))
        log(f"  {node}: ICP {nodes[node]['icp_error_mm']:.0f} mm {nodes[node]['icp_error_deg']:.2f} deg")
    worst = max(v["error_mm"] for v in nodes.values())
    icp_worst = max(v["icp_error_mm"] for v in nodes.values())
    print(json.dumps({
        "nodes": nodes,
        "guess_off": {"trans_m": GUESS_OFF_M, "rot_deg": GUESS_OFF_DEG},
        "solve_s_mean": float(np.mean([v["solve_s"] for v in nodes.values()])),
        "solve_cpu_s_mean": float(np.mean([v["solve_cpu_s"] for v in nodes.values()])),
        "guided_s_mean": float(np.mean([v["guided_s"] for v in nodes.values()])),
        "worst_error_mm": worst, "worst_error_deg": max(v["error_deg"] for v in nodes.values()),
        "worst_guided_error_mm": max(v["guided_error_mm"] for v in nodes.values()),
        "icp_s": icp_s, "icp_edges": [[e.parent, e.child, e.verdict.level] for e in edges],
        "icp_worst_error_mm": icp_worst, "error_ratio": icp_worst / worst,
        "peak_rss_mb": peak_rss_mb(), "seconds": time.perf_counter() - started,
    }))


if __name__ == "__main__":
    main()
