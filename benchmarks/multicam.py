#!/usr/bin/env python
"""Multi-camera benchmark: our joint solve of 6 cameras x 245 frames against OpenCV's pairwise chaining.

What it measures, in one run on the same simulated observations:

- ``solve_s``: ``calibrate_multicam`` (input checks, PnP and the spanning-tree initial rig,
  the robust bundle adjustment, the outlier rounds and the covariance), intrinsics held
  (as the mining robot's team did: fixed intrinsics), target under 10 s on 2 cores;
- ``chain_s``: the in-run baseline, the usual camera chain: ``cv2.stereoCalibrate`` with
  ``CALIB_FIX_INTRINSIC`` (and OpenCV's default termination) on each neighbouring pair's shared
  frames (cam0-cam1, cam1-cam2, ...), composed along the chain. Mixed lens models (one camera
  is fisheye) are handled by giving OpenCV undistorted, normalised corners with ``K = I``, the
  exact geometry;
- ``chain_order_spread_mm`` / ``_deg``: how far two chain orders (cam0..cam5, and
  :data:`OTHER_ORDER` through other pairs) disagree on the same data, the largest over the
  cameras: the dependence on the order the mining team saw (1.1 mm, 0.055 deg);
  ``order_spread_mm`` / ``_deg``: the same for our solve with cam0 and cam5 as references;
- ``error_mm`` / ``error_deg``, ``chain_error_*``: the largest translation (mm) and rotation
  (deg) error over the cameras against the simulator's truth;
- ``within_3_sigma``: whether every axis of every camera's error is within 3 of its sigmas;
- ``peak_rss_mb``: peak resident memory of the process at the end (ru_maxrss).

Rig: ``simulated_ring(6, 245, spacing_deg=3, walk_deg=16)``: six cameras looking forward 3 deg
apart (1280x720, 1920x1200 pair, 1280x800 fisheye, 640x512 thermal-like, 848x480), the 0.8 m
board walking through their common view at 1.2-3 m, 0.3 px corner noise: about 1180 views (a
camera misses the frames in which the board leaves its image). Times are the median of
``REPEATS`` runs (time.perf_counter). ``solve_ratio`` is ours / chain (> 1: ours is slower).

Prints exactly one JSON object on stdout; progress goes to stderr.
"""

import json
import sys
from pathlib import Path

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_util import log, median_time, peak_rss_mb  # noqa: E402

from backend.calib.multicam.bundle import calibrate_multicam  # noqa: E402
from backend.core.transforms import invert  # noqa: E402
from backend.sim.multicam_rig import simulated_ring  # noqa: E402

OTHER_ORDER = ["cam0", "cam2", "cam1", "cam3", "cam5", "cam4"]
"""A second chain through other pairs (0-2, 2-1, 1-3, 3-5, 5-4 instead of 0-1, 1-2, 2-3, 3-4, 4-5)."""


def chain(sim, observations, order):
    """``T_first_cam`` of every camera by stereoCalibrate along ``order``, composed from the first camera."""
    by_view = {(o.camera, o.frame): o.detection for o in observations}
    object_points = sim.board.object_points.astype(np.float32)
    T_first = {order[0]: np.eye(4)}
    for a, b in zip(order[:-1], order[1:], strict=True):
        frames = sorted({f for c, f in by_view if c == a} & {f for c, f in by_view if c == b})
        normalised = {c: [sim.cameras[c].undistort_points(by_view[c, f].corners_px).astype(np.float32)
                          for f in frames] for c in (a, b)}
        _, *_, R, T, _, _ = cv2.stereoCalibrate(
            [object_points] * len(frames), normalised[a], normalised[b], np.eye(3), None, np.eye(3), None,
            (sim.cameras[a].width, sim.cameras[a].height), flags=cv2.CALIB_FIX_INTRINSIC)
        T_b_a = np.eye(4)
        T_b_a[:3, :3], T_b_a[:3, 3] = R, T.ravel()
        T_first[b] = T_first[a] @ invert(T_b_a)
    return T_first


def spread(T_one, T_other):
    """Largest translation (mm) and rotation (deg) difference over the cameras of two rigs in one frame."""
    mm = max(np.linalg.norm(T_one[n][:3, 3] - T_other[n][:3, 3]) * 1e3 for n in T_one)
    deg = max(np.degrees(Rotation.from_matrix(T_one[n][:3, :3].T @ T_other[n][:3, :3]).magnitude()) for n in T_one)
    return float(mm), float(deg)


def in_frame_of(T_ref_cam, camera):
    return {name: invert(T_ref_cam[camera]) @ T for name, T in T_ref_cam.items()}


def main():
    sim = simulated_ring(6, 245, seed=0, spacing_deg=3.0, walk_deg=16.0)
    observations = sim.observations(0.3, seed=1)
    names = list(sim.cameras)
    log(f"{len(observations)} views of {len(names)} cameras over {len(sim.T_rig_board)} frames")
    truth = sim.T_ref_cam("cam0")

    results = []
    solve_s = median_time(lambda: results.append(calibrate_multicam(sim.cameras, sim.board, observations)))
    ours = results[-1]
    log(f"ours: {solve_s:.2f} s, converged {ours.converged}")
    reversed_result = calibrate_multicam({n: sim.cameras[n] for n in names[::-1]}, sim.board, observations)
    order_mm, order_deg = spread(in_frame_of(ours.T_ref_cam, "cam0"), in_frame_of(reversed_result.T_ref_cam, "cam0"))

    chains = []
    chain_s = median_time(lambda: chains.append(chain(sim, observations, names)))
    forward = chains[-1]
    chain_order_mm, chain_order_deg = spread(forward, chain(sim, observations, OTHER_ORDER))
    log(f"chain: {chain_s:.2f} s; orders differ by {chain_order_mm:.3f} mm, {chain_order_deg:.4f} deg")

    error_mm, error_deg = spread(ours.T_ref_cam, truth)
    chain_error_mm, chain_error_deg = spread(forward, truth)
    within = True
    for name in names[1:]:
        error = invert(truth[name]) @ ours.T_ref_cam[name]
        std = ours.transforms[name].std
        within &= bool(np.all(np.abs(ours.T_ref_cam[name][:3, 3] - truth[name][:3, 3]) < 3 * np.array(std["trans_m"])))
        within &= bool(np.all(np.abs(np.degrees(Rotation.from_matrix(error[:3, :3]).as_rotvec()))
                              < 3 * np.array(std["rot_deg"])))
    print(json.dumps({
        "cameras": len(names), "frames": len(sim.T_rig_board), "views": len(observations),
        "solve_s": round(solve_s, 3), "chain_s": round(chain_s, 3), "solve_ratio": round(solve_s / chain_s, 2),
        "target_s": 10.0, "converged": ours.converged,
        "error_mm": round(error_mm, 4), "error_deg": round(error_deg, 5),
        "chain_error_mm": round(chain_error_mm, 4), "chain_error_deg": round(chain_error_deg, 5),
        "order_spread_mm": order_mm, "order_spread_deg": order_deg,
        "chain_order_spread_mm": round(chain_order_mm, 4), "chain_order_spread_deg": round(chain_order_deg, 5),
        "within_3_sigma": within, "rms_px": {n: round(v, 4) for n, v in ours.rms_px.items()},
        "peak_rss_mb": round(peak_rss_mb(), 1),
    }))


if __name__ == "__main__":
    main()
