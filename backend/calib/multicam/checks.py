"""How far each camera of a multi-camera solve can be trusted: the pair checks and the per-camera verdicts.

Two checks that the bundle adjustment's own sigmas cannot make:

* **Pair checks.** For every pair of cameras that saw the board together, the corners both saw should lie on
  each other's epipolar lines under the solved rig and intrinsics. This does not use the board's geometry (its
  square size, flatness), so a wrong board spec or a pose that only fits through the board poses shows here.
* **Intrinsics estimated inside the rig.** A camera whose intrinsics came from the rig's sets alone has no
  held-out check of its lens model (step 3's cross-validation makes one) and usually too few views in the
  image corners: the verdict gives its projection sigma across the image and tells the user to calibrate it
  in step 3 first. (The demo's ``cam_right`` from 10 sets once got
  k2 = -0.10 against the truth +0.045, 60 px wrong in the corners, at an RMS of 0.18 px).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from backend.calib.board.detection import common_corners
from backend.calib.intrinsics.solver import worst_projection_sigma_px
from backend.calib.multicam.graph import Observation
from backend.calib.multicam.stereo import epipolar_errors
from backend.core.camera import DIST_NAMES, CameraIntrinsics
from backend.core.verdict import (
    CROSS_CHECK_SIGMAS,
    PROJECTION_TOLERANCE_PX,
    Verdict,
    VerdictBuilder,
    judge_transform_sigmas,
)

if TYPE_CHECKING:
    from backend.calib.multicam.bundle import MulticamResult

TRANSLATION_TOLERANCE_M = 0.002
"""Largest acceptable 1-sigma per axis of a camera's position in the rig (m): a camera-to-camera baseline is
measured to about a millimetre on a board."""
ROTATION_TOLERANCE_DEG = 0.1
"""Largest acceptable 1-sigma per axis of a camera's rotation in the rig (deg)."""
EPIPOLAR_FACTOR = 2.0
"""A pair passes when its epipolar RMS is within this many times the larger of its two cameras' RMS ..."""
EPIPOLAR_FLOOR_PX = 0.5
"""... or within this many pixels (corner noise alone gives a few tenths)."""


def pair_checks(result: MulticamResult, observations: list[Observation]) -> list[dict[str, Any]]:
    """For each pair of cameras that saw the board together: the shared frames, the baseline (m) and the
    epipolar RMS (px) of the corners both saw under the solved rig."""
    by_view = {(o.camera, o.frame): o.detection for o in observations}
    checks = []
    for edge in result.graph.to_record()["edges"]:
        a, b = edge["a"], edge["b"]
        left_px, right_px = [], []
        for frame in sorted({f for c, f in by_view if c == a} & {f for c, f in by_view if c == b}):
            in_a, in_b = common_corners(by_view[a, frame], by_view[b, frame])
            left_px.append(in_a)
            right_px.append(in_b)
        T_a_b = np.linalg.solve(result.T_ref_cam[a], result.T_ref_cam[b])
        errors = epipolar_errors(result.cameras[a], result.cameras[b], T_a_b, np.concatenate(left_px),
                                 np.concatenate(right_px))
        checks.append({"a": a, "b": b, "frames": edge["frames"], "baseline_m": float(np.linalg.norm(T_a_b[:3, 3])),
                       "epipolar_rms_px": float(np.sqrt(np.mean(errors**2)))})
    return checks


def intrinsics_projection_sigma_px(camera: CameraIntrinsics, free: list[str], covariance: np.ndarray) -> float:
    """Worst 1-sigma (px) across the image of projecting a far point, for a camera whose parameters ``free``
    (names among fx, fy, cx, cy and its distortion terms) have the ``covariance`` (their order)."""
    names = ["fx", "fy", "cx", "cy", *DIST_NAMES[camera.model]]
    full = np.zeros((len(names), len(names)))
    where = [names.index(name) for name in free]
    full[np.ix_(where, where)] = covariance
    return worst_projection_sigma_px(camera, full)


def camera_verdicts(result: MulticamResult) -> dict[str, Verdict]:
    """One verdict per camera: the solve's convergence, the pose's sigmas (not for the reference, which fixes
    the gauge), the projection sigma of intrinsics estimated in the rig, and the pair checks it takes part in."""
    rms = result.rms_px
    verdicts = {}
    for name in result.cameras:
        judge = VerdictBuilder()
        if not result.converged:
            judge.reject("the rig solve did not converge: " + "; ".join(result.warnings))
        if name == result.reference:
            judge.note("the reference camera: its pose fixes the rig's frame")
        else:
            judge_transform_sigmas(judge, result.transforms[name].std, TRANSLATION_TOLERANCE_M,
                                   ROTATION_TOLERANCE_DEG)
        if name in result.intrinsics_projection_sigma_px:
            sigma_px = result.intrinsics_projection_sigma_px[name]
            judge.sigma(f"{name}'s lens (projection across the image, estimated in the rig)", sigma_px,
                        PROJECTION_TOLERANCE_PX, "px")
            judge.missing_check(f"of {name}'s intrinsics",
                                f"they were estimated inside the rig solve from its sets alone; calibrate {name} in "
                                "step 3 (Camera intrinsics) first, then solve the rig again")
        for pair in result.pairs:
            if name not in (pair["a"], pair["b"]):
                continue
            other = pair["b"] if pair["a"] == name else pair["a"]
            limit = max(EPIPOLAR_FLOOR_PX, EPIPOLAR_FACTOR * max(rms[pair["a"]], rms[pair["b"]]))
            judge.cross_check_sigmas(f"epipolar with {other}", CROSS_CHECK_SIGMAS * pair["epipolar_rms_px"] / limit,
                                     f"{pair['epipolar_rms_px']:.3f} px over {pair['frames']} shared sets "
                                     f"(limit {limit:.3f} px)")
        verdicts[name] = judge.verdict()
    return verdicts
