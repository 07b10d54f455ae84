"""How far a swept scanner's calibrated geometry can be trusted: its verdict.

Each estimated parameter's 1-sigma is weighed against a tolerance, and the independent cross-check is the
sweep's two interleaved halves: the geometry solved from the even servo steps alone and from the odd ones alone
(on the same planes) must agree within three sigmas of their difference. Interleaved rather than first and
second half, so that each half still sees every plane from the whole servo range.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from backend.core.verdict import Verdict, VerdictBuilder

if TYPE_CHECKING:
    from backend.calib.sweep.solver import SweepCalibrationResult

OFFSET_TOLERANCE_M = 0.002
"""Largest acceptable 1-sigma of the optical centre's offset from the servo axis (m)."""
ANGLE_TOLERANCE_DEG = 0.1
"""Largest acceptable 1-sigma of the servo's zero and the scanner's tilts (deg)."""

LABELS = {"offset_u_m": "offset u", "offset_v_m": "offset v", "zero_offset_rad": "servo zero",
          "tilt_u_rad": "tilt about u", "tilt_v_rad": "tilt about v"}


def sweep_verdict(result: SweepCalibrationResult) -> Verdict:
    """``reject`` when the solve did not converge, left a parameter undetermined or made the planes less flat;
    ``check`` when a sigma is above its tolerance or the halves disagree; else ``trusted``."""
    judge = VerdictBuilder()
    if not result.converged:
        judge.reject("the solve did not converge")
    if result.rms_after_m > result.rms_before_m:
        judge.reject(f"the planes got less flat ({1e3 * result.rms_before_m:.1f} mm before, "
                     f"{1e3 * result.rms_after_m:.1f} mm after)")
    for name, sigma in result.parameter_std.items():
        if name.endswith("_m"):
            judge.sigma(LABELS[name], 1e3 * sigma, 1e3 * OFFSET_TOLERANCE_M, "mm")
        else:
            judge.sigma(LABELS[name], math.degrees(sigma), ANGLE_TOLERANCE_DEG, "deg")
    if not np.isfinite(result.covariance).all():
        judge.reject("the planes do not determine every parameter")
    if result.halves_difference is None or result.halves_std is None:
        judge.missing_check("of the sweep's halves", "a half of the servo steps has too few points on the planes")
        return judge.verdict()
    z = np.abs(result.halves_difference) / np.maximum(result.halves_std, 1e-15)
    worst = int(np.argmax(z))
    judge.cross_check_sigmas("of the even and odd servo steps", float(z[worst]),
                             f"they differ most in {LABELS[result.estimated[worst]]}")
    return judge.verdict()
