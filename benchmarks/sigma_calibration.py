#!/usr/bin/env python
"""Sigma calibration: are the solvers' reported 1-sigma uncertainties honest, over many simulated seeds?

For each solver below, every seed makes a new simulated data set with known truth and solves it as the tests do;
per parameter the normalised error ``z = (estimate - truth) / sigma`` is taken, sigma being the solver's reported
1-sigma. Over the seeds, per parameter:

- ``rms_z``: sqrt(mean(z^2)). Near 1: honest; below 0.8: pessimistic (sigmas too wide); above 1.25: optimistic
  (sigmas too narrow, the error is larger than the solver says). With n = 30 an honest parameter's rms_z itself
  scatters by about 1/sqrt(2n) = 0.13, so among many parameters one just outside the band can be chance;
- ``mean_z``: the mean of z (a bias shows as |mean_z| well above 1/sqrt(n) = 0.18);
- ``within_3_sigma``: the share of seeds with |z| < 3 (99.7 % for Gaussian, honest sigmas);
- ``n``: the seeds that gave a result. A seed whose solve refuses (InputError), raises, does not converge or
  reports a non-finite or zero sigma is listed under ``failed`` with the reason, and left out of z.

Solvers and what varies per seed ``s`` (seed 0 is the data of the tests named):

- ``intrinsics``: ``calibrate_intrinsics`` with the default ``IntrinsicsSettings`` (k1, k2, p1, p2, the board's
  flex; the sigmas are the noise model's, mrcal's, the jackknife only beside them)
  on 15 views of the simulated ``cam_front`` (device seed ``s``: board motion and image noise), as
  ``tests/calib/intrinsics/test_sim.py``; parameters fx, fy, cx, cy (px), k1, k2, p1, p2 (k3 is fixed at 0);
- ``lidar_camera_target``: ``solve_target`` on 12 board poses (``moving_board_poses(12, seed=s)``), a 16-beam
  scan and PnP-like pose noise per pose (seed s + 1), from ``initial_guess(s + 2)`` (10 cm, 5 deg off), as
  ``tests/calib/lidar_camera/test_target.py``;
- ``lidar_camera_edges``: ``solve_edges`` on the yard without the board from the four ``ROBOT_POSES``: every seed
  re-scans (128 beams: range noise, spin phase) and re-renders (texture phases, sensor noise) all four pairs with
  ``default_rng(s)`` through ``scan_and_image`` (the robot poses and the yard are the same for every seed), from
  ``initial_guess(s + 1)``, as ``tests/calib/lidar_camera/test_edges.py``;
- ``lidar_lidar``: ``register_pair`` with the default settings (Hessian sigma widened by the azimuth-sector
  jackknife) on one VLP-16-like pair of the yard (``scan_pair(scene, s)``: noise and spin phase), from 20 cm and
  10 deg off (``perturbed(T_TRUE, s, 0.20, 10.0)``), as ``tests/calib/lidar_lidar/test_gicp.py``;
- ``multicam``: ``calibrate_multicam`` on the tests' six-camera ring (``simulated_ring(6, 245, seed=0)``, 40 deg
  apart, a chain cam0-cam1-...-cam5) with new 0.3 px corner noise per seed (seed s + 1; the ring stays: reseeded,
  13 of 30 rings leave a camera unconnected and are refused); parameters: the six of each camera but cam0;
- ``multicam_cluster``: the same on ``benchmarks/multicam.py``'s forward-looking cluster
  (``simulated_ring(6, 245, seed=s, spacing_deg=3, walk_deg=16)``: mounts and board walk) with noise seed s + 1.

Transform parameters (LiDAR-camera, LiDAR-LiDAR, multicam) are those of ``params_between(T_truth, T_estimate)``:
t_x, t_y, t_z (m, parent axes) and r_x, r_y, r_z (rotation vector, rad, about the child's axes), against the
result's ``std_vector`` in the same order; for LiDAR-camera through the tests' ``errors_and_sigmas`` (m and deg).
Seeds run one after another in this process (the solvers' own threads: at most 2).

JSON on stdout (exactly one object), per solver: ``seeds``, ``varies``, ``per_parameter`` {name: {rms_z, mean_z,
within_3_sigma, n}}, ``rms_z_all``, ``verdict`` ("honest", else the optimistic and pessimistic parameters),
``failed`` [{seed, reason}] and ``seconds``. Progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/sigma_calibration.py [--seeds 30] [--only intrinsics]
"""

import argparse
import json
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from bench_util import log

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.core.result import TransformResult  # noqa: E402
from backend.core.transforms import params_between  # noqa: E402

HONEST_RMS_Z = (0.8, 1.25)
"""rms_z outside this band is called pessimistic (below) or optimistic (above)."""
TRANSFORM_NAMES = ["t_x", "t_y", "t_z", "r_x", "r_y", "r_z"]
"""Order of :func:`params_between` and of ``std_vector``: m, m, m, rad, rad, rad."""

NormalisedErrors = Callable[[int], np.ndarray]
"""Solves seed ``s`` and returns z per parameter; raises when the seed gives no usable result."""


class SeedFailed(Exception):
    """A solve that returned, but not a result to judge (not converged, or a sigma that is not a positive number)."""


@dataclass
class Solver:
    name: str
    parameters: list[str]
    varies: str
    """What changes from one seed to the next."""
    prepare: Callable[[], NormalisedErrors]
    """Builds what every seed shares (scenes) and returns the per-seed function."""


def usable(result: TransformResult) -> TransformResult:
    """``result``, if converged with every sigma a positive number; else :class:`SeedFailed` saying why."""
    if not result.converged:
        raise SeedFailed(f"not converged: {'; '.join(result.warnings)}")
    if not np.all(np.isfinite(result.std_vector) & (result.std_vector > 0)):
        raise SeedFailed(f"sigma not a positive number: {result.std_vector.tolist()}")
    return result


def transform_z(result: TransformResult, T_true: np.ndarray) -> np.ndarray:
    """(6,) z of a usable transform result against ``T_true``: :func:`params_between` over ``std_vector``."""
    return params_between(T_true, usable(result).T_parent_child) / result.std_vector


def intrinsics() -> NormalisedErrors:
    import backend.sim.devices  # noqa: F401  (registers the simulated camera driver, as tests/conftest.py does)
    from backend.calib.intrinsics.solver import IntrinsicsSettings, calibrate_intrinsics
    from backend.sim.demo_rig import demo_rig
    from tests.calib.intrinsics.test_sim import BOARD, VIEWS, normalised_errors, simulated_views

    truth = demo_rig().get("cam_front").intrinsics

    def z(seed: int) -> np.ndarray:
        views = simulated_views("cam_front", seed, VIEWS)
        simulated_views.cache_clear()  # each seed's views are used once
        return normalised_errors(calibrate_intrinsics(views, BOARD, truth.image_size, IntrinsicsSettings()), truth, 4)
    return z


def lidar_camera_target() -> NormalisedErrors:
    from backend.calib.lidar_camera.target import solve_target
    from backend.sim.lidar_scene import moving_board_poses
    from tests.calib.lidar_camera.conftest import TRUTH, errors_and_sigmas, initial_guess
    from tests.calib.lidar_camera.test_target import BOARD, SETTINGS, _observations

    def z(seed: int) -> np.ndarray:
        observations = _observations(moving_board_poses(12, seed=seed), beams=16, seed=seed + 1)
        result = usable(solve_target(BOARD, observations, initial_guess(seed + 2), SETTINGS))
        error, sigma = errors_and_sigmas(result, TRUTH)  # m and deg: z as params_between / std_vector
        return error / sigma
    return z


def lidar_camera_edges() -> NormalisedErrors:
    from backend.calib.lidar_camera.edges import EdgeObservation, solve_edges
    from backend.sim.demo_rig import CAM_FRONT
    from backend.sim.lidar_scene import LidarScene
    from tests.calib.lidar_camera.conftest import ROBOT_POSES, TRUTH, errors_and_sigmas, initial_guess, scan_and_image

    scene = LidarScene(include_board=False)

    def z(seed: int) -> np.ndarray:
        rng = np.random.default_rng(seed)  # as the tests' edge_pairs_folder (seed 0): scan, image, pose by pose
        pairs = []
        for i, robot_pose in enumerate(ROBOT_POSES):
            scan, image = scan_and_image(scene, robot_pose, rng)
            pairs.append(EdgeObservation(image, np.column_stack([scan.points, scan.intensity]), f"pose {i + 1}"))
        result = usable(solve_edges(CAM_FRONT, pairs, initial_guess(seed + 1)))
        error, sigma = errors_and_sigmas(result, TRUTH)
        return error / sigma
    return z


def lidar_lidar() -> NormalisedErrors:
    from backend.calib.lidar_lidar.gicp import register_pair
    from backend.sim.lidar_scene import LidarScene
    from tests.calib.lidar_lidar.conftest import T_TRUE, perturbed, scan_pair

    scene = LidarScene()

    def z(seed: int) -> np.ndarray:
        source, target = scan_pair(scene, seed)
        return transform_z(register_pair(source, target, perturbed(T_TRUE, seed, 0.20, 10.0)), T_TRUE)
    return z


def lidar_lidar_scenes() -> NormalisedErrors:
    from backend.calib.lidar_lidar.scenes import register_pairs
    from backend.sim.lidar_scene import LidarScene
    from tests.calib.lidar_lidar.conftest import PLACEMENTS, T_TRUE, perturbed, scan_pair

    scene = LidarScene()

    def z(seed: int) -> np.ndarray:
        pairs = [scan_pair(scene, len(PLACEMENTS) * seed + i, T) for i, T in enumerate(PLACEMENTS)]
        return transform_z(register_pairs(pairs, perturbed(T_TRUE, seed, 0.20, 10.0)), T_TRUE)
    return z


MULTICAM_CAMERAS = [f"cam{i}" for i in range(1, 6)]
"""The ring's cameras but the reference (cam0)."""


def multicam(cluster: bool) -> NormalisedErrors:
    """The ring of the tests (seed 0 for every seed) or, with ``cluster``, benchmarks/multicam.py's (seed s)."""
    from backend.calib.multicam.bundle import calibrate_multicam
    from backend.sim.multicam_rig import simulated_ring
    from tests.calib.multicam.conftest import RING_NOISE_PX

    def z(seed: int) -> np.ndarray:
        ring = simulated_ring(6, 245, seed=seed, spacing_deg=3.0, walk_deg=16.0) if cluster else simulated_ring(6, 245)
        result = calibrate_multicam(ring.cameras, ring.board, ring.observations(RING_NOISE_PX, seed=seed + 1))
        truth = ring.T_ref_cam(result.reference)
        if not result.converged:
            raise SeedFailed("not converged")
        return np.concatenate([transform_z(result.transforms[name], truth[name]) for name in MULTICAM_CAMERAS])
    return z


SOLVERS = [
    Solver("intrinsics", ["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"],
           "cam_front device seed s (board motion, image noise); 15 views", intrinsics),
    Solver("lidar_camera_target", TRANSFORM_NAMES,
           "board poses seed s, 16-beam scans and PnP noise seed s + 1, initial guess seed s + 2",
           lidar_camera_target),
    Solver("lidar_camera_edges", TRANSFORM_NAMES,
           "scans (range noise, spin phase) and images (texture, sensor noise) of the four fixed robot poses "
           "re-made with seed s, initial guess seed s + 1; the yard and the robot poses are fixed",
           lidar_camera_edges),
    Solver("lidar_lidar", TRANSFORM_NAMES, "scan noise and spin phase (scan_pair seed s), initial guess seed s",
           lidar_lidar),
    Solver("lidar_lidar_scenes", TRANSFORM_NAMES,
           "scan noise and spin phase of the three placements (scan_pair seeds 3s..3s + 2), initial guess seed s",
           lidar_lidar_scenes),
    Solver("multicam", [f"{camera} {name}" for camera in MULTICAM_CAMERAS for name in TRANSFORM_NAMES],
           "corner noise seed s + 1 (the tests' ring, seed 0, for every seed)", lambda: multicam(cluster=False)),
    Solver("multicam_cluster", [f"{camera} {name}" for camera in MULTICAM_CAMERAS for name in TRANSFORM_NAMES],
           "cluster mounts and board walk seed s, corner noise seed s + 1", lambda: multicam(cluster=True)),
]


def verdict(per_parameter: dict[str, dict[str, float]]) -> str:
    """"honest" when every parameter's rms_z is in :data:`HONEST_RMS_Z`, else which parameters are outside."""
    low, high = HONEST_RMS_Z
    optimistic = [name for name, p in per_parameter.items() if p["rms_z"] > high]
    pessimistic = [name for name, p in per_parameter.items() if p["rms_z"] < low]
    if not per_parameter:
        return "no results"
    parts = [f"{label}: {', '.join(names)}" for label, names in (("optimistic", optimistic),
                                                                 ("pessimistic", pessimistic)) if names]
    return "; ".join(parts) if parts else "honest"


def run(solver: Solver, seeds: int) -> dict:
    """The solver over seeds 0 .. ``seeds - 1``: z statistics per parameter, the failures and the wall time (s)."""
    started = time.perf_counter()
    log(f"{solver.name}: preparing ...")
    normalised_errors = solver.prepare()
    z_rows, failed = [], []
    for seed in range(seeds):
        seed_started = time.perf_counter()
        try:
            z = np.asarray(normalised_errors(seed), dtype=float)
        except Exception as error:  # a refusal, a crash or an unusable result: counted, with its reason
            failed.append({"seed": seed, "reason": f"{type(error).__name__}: {error}"})
            log(f"{solver.name}: seed {seed} failed: {failed[-1]['reason']}")
            continue
        z_rows.append(z)
        log(f"{solver.name}: seed {seed + 1} of {seeds}, {time.perf_counter() - seed_started:.1f} s, "
            f"max |z| {np.abs(z).max():.2f} ({solver.parameters[int(np.abs(z).argmax())]})")
    z_all = np.array(z_rows).reshape(len(z_rows), len(solver.parameters))
    per_parameter = {name: {"rms_z": float(np.sqrt(np.mean(column**2))), "mean_z": float(np.mean(column)),
                            "within_3_sigma": float(np.mean(np.abs(column) < 3)), "n": int(column.size)}
                     for name, column in zip(solver.parameters, z_all.T, strict=True) if column.size}
    return {"seeds": seeds, "varies": solver.varies, "per_parameter": per_parameter,
            "rms_z_all": float(np.sqrt(np.mean(z_all**2))) if z_all.size else None,
            "within_3_sigma_all": float(np.mean(np.abs(z_all) < 3)) if z_all.size else None,
            "verdict": verdict(per_parameter), "failed": failed, "seconds": time.perf_counter() - started}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seeds", type=int, default=30, help="seeds per solver (default 30)")
    parser.add_argument("--only", choices=[s.name for s in SOLVERS], help="run this one solver")
    args = parser.parse_args()
    started = time.perf_counter()
    results = {s.name: run(s, args.seeds) for s in SOLVERS if args.only in (None, s.name)}
    for name, result in results.items():
        log(f"{name}: rms z {result['rms_z_all']}, {result['verdict']}, {len(result['failed'])} failed, "
            f"{result['seconds']:.0f} s")
    print(json.dumps({"honest_rms_z": HONEST_RMS_Z, "solvers": results, "seconds": time.perf_counter() - started},
                     indent=1))


if __name__ == "__main__":
    main()
