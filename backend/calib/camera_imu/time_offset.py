"""The time offset and rotation between two sensors that turn together, from their angular rates.

Each sensor's angular speed is a scalar that does not depend on how the sensors are mounted, so cross-correlating
the two speed signals finds the offset between their clocks before any rotation is known (Kalibr's
``findTimeshiftCameraImuPrior`` does the same); the rotation then aligns the rate vectors (Kabsch), with the gyro's
bias. This is the camera-IMU solve's start and its independent cross-check of the rotation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.errors import InputError


@dataclass(frozen=True)
class RateAlignment:
    """How sensor b's angular rates line up with sensor a's."""

    offset_s: float
    """``t_a = t_b + offset_s`` (s): a's clock reads ``offset_s`` more at the same instant."""
    offset_std_s: float
    """1-sigma of ``offset_s`` (s): the residual spread over the signal's slope, and at least the search step (the
    rates of a sensor that only gives orientations are finite differences, whose timing the step bounds)."""
    R_a_b: np.ndarray
    """3x3 rotation taking b's rate vectors into a's axes."""
    bias_a_rad_s: np.ndarray
    """(3,) constant bias of a's rates (rad/s) beside the rotated b rates."""
    correlation: float
    """Correlation of the two angular speeds at the offset."""
    residual_rad_s: float
    """RMS (rad/s) of a's rates less the rotated b rates and the bias."""
    rotation_std_rad: float
    """Approximate 1-sigma (rad) of the rotation's angle: the residual over the root sum of squared rates."""
    curve: dict[str, list[float]]
    """The correlation against the offset (``offset_s``, ``correlation``), for a plot."""


def rates_from_rotations(t_s: np.ndarray, R_world_body: np.ndarray, max_step_s: float) -> tuple[np.ndarray,
                                                                                                  np.ndarray]:
    """Body-frame angular rates (rad/s) between consecutive orientations (K, 3, 3), at the mid times (s); pairs
    further apart than ``max_step_s`` are skipped."""
    steps = np.diff(t_s)
    keep = steps <= max_step_s
    relative = Rotation.from_matrix(np.einsum("kji,kjl->kil", R_world_body[:-1], R_world_body[1:]))
    rates = relative.as_rotvec() / steps[:, None]
    return 0.5 * (t_s[:-1] + t_s[1:])[keep], rates[keep]


def align_rates(t_a: np.ndarray, rates_a: np.ndarray, t_b: np.ndarray, rates_b: np.ndarray, *,
                max_offset_s: float = 0.5, step_s: float = 1e-3, name: str = "rates") -> RateAlignment:
    """Offset (``t_a = t_b + offset``), rotation and a's bias that best line up a's rate vectors (N, 3) with b's
    (M, 3). The offset is searched over ``±max_offset_s`` in ``step_s`` steps by the correlation of the angular
    speeds, refined by a parabola through the peak; :class:`InputError` naming ``name`` when the signals do not
    overlap or do not correlate (no motion)."""
    offsets = np.arange(-max_offset_s, max_offset_s + step_s / 2, step_s)
    speed_a, speed_b = np.linalg.norm(rates_a, axis=1), np.linalg.norm(rates_b, axis=1)
    correlation = np.full(len(offsets), np.nan)
    for i, offset in enumerate(offsets):
        inside = (t_b + offset >= t_a[0]) & (t_b + offset <= t_a[-1])
        if inside.sum() < 20:
            continue
        moved = np.interp(t_b[inside] + offset, t_a, speed_a)
        correlation[i] = np.corrcoef(moved, speed_b[inside])[0, 1]
    if not np.isfinite(correlation).any():
        raise InputError(f"{name}: the two streams do not overlap in time within ±{max_offset_s} s", name)
    best = int(np.nanargmax(correlation))
    if correlation[best] < 0.5:
        raise InputError(f"{name}: the angular speeds correlate at most {correlation[best]:.2f} (at an offset of "
                         f"{offsets[best] * 1e3:.0f} ms): too little rotation, or the streams are not of one motion",
                         name)
    offset_s = float(offsets[best])
    if 0 < best < len(offsets) - 1 and np.isfinite(correlation[best - 1: best + 2]).all():
        left, middle, right = correlation[best - 1: best + 2]
        curvature = left - 2 * middle + right
        if curvature < 0:
            offset_s += float(0.5 * (left - right) / curvature * step_s)
    inside = (t_b + offset_s >= t_a[0]) & (t_b + offset_s <= t_a[-1])
    moved = np.column_stack([np.interp(t_b[inside] + offset_s, t_a, rates_a[:, i]) for i in range(3)])
    b = rates_b[inside]
    bias = np.zeros(3)
    for _ in range(5):  # rotation and bias alternately: each is closed-form given the other
        R_a_b = Rotation.align_vectors(moved - bias, b)[0].as_matrix()
        bias = np.mean(moved - b @ R_a_b.T, axis=0)
    residual = moved - b @ R_a_b.T - bias
    rms = float(np.sqrt(np.mean(np.sum(residual**2, axis=1))))
    # sigma of the offset: the residual's spread over the rate of change of the aligned signal, per sample
    slope = np.gradient(moved, t_b[inside] + offset_s, axis=0)
    information = float(np.sum(slope**2)) / max(rms**2 / 3, 1e-18)
    rotation_std = rms / float(np.sqrt(np.sum(b**2)))
    offset_std = float(np.hypot(1 / np.sqrt(information), step_s)) if information > 0 else float("inf")
    return RateAlignment(offset_s, offset_std, R_a_b,
                         bias, float(correlation[best]), rms, rotation_std,
                         {"offset_s": offsets.tolist(), "correlation": np.nan_to_num(correlation).tolist()})
