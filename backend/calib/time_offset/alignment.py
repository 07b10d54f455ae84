"""The clock offset that best lines two sensors' motion signals up, with its sigma.

Convention (Kalibr's, as the camera-IMU solve): ``t_b = t_a + offset_s``, sensor b's clock reads ``offset_s`` more
than a's at the same instant.

- Two ``rates`` signals go through the camera-IMU solve's rate alignment
  (:func:`~backend.calib.camera_imu.time_offset.align_rates`: the angular speeds' correlation finds the offset
  before any rotation is known, then Kabsch gives the rotation and a's bias).
- Two ``directions`` signals (a board's normal) are lined up by scanning the offset: at each candidate the denser
  signal is interpolated at the sparser one's times (a cubic spline: a straight line between 15 Hz samples of a
  board swinging at 0.7 Hz cuts its arcs by 0.3 deg, which the rotation takes up) and the rotation that best maps
  one onto the other is solved in closed form (Wahba's problem, a 3x3 SVD per offset, all offsets at once); the
  cost is the mean squared difference of the unit vectors left over. The minimum is refined by a parabola through
  its neighbours.
- Two ``lines`` signals (a board's cut through a 2D scanner's plane, both in the scanner's axes, z = 0) are scanned
  the same way, but the rotation is a turn about the scan plane's normal alone, in closed form
  (``angle = atan2(sum (b x a) . z, sum a . b)``): Wahba's 3x3 SVD on vectors that all lie in one plane has a
  rank-2 matrix and so picks the best of the in-plane turns *and mirror images* (a mirror composed with z -> -z is
  a proper rotation), under which a line swinging to and fro can match its own mirror image at a wrong offset. One
  angle to solve and one residual component a sample (across the line; along it a unit vector barely errs), so the
  residual's degrees of freedom and the rotation's sigma count one axis. A board turned only about a horizontal axis
  or its own normal leaves the line still: at least :data:`MIN_TURN_DEG` of turn about the vertical (yaw) is asked
  for.

The offset's sigma is Gauss-Newton's: the residual's spread over the rate at which the aligned signal changes,
summed over the samples (``sigma^2 = s^2 / sum |d(R v)/dt|^2``, ``s^2`` per residual component: three for normals,
the one across the line for lines), the spread widened by how much the residuals persist
from sample to sample (:func:`persistence`), and at least the search step.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import make_interp_spline

from backend.calib.camera_imu.time_offset import align_rates
from backend.calib.time_offset.signals import MIN_SAMPLES, MotionSignal
from backend.core.errors import InputError
from backend.core.result import finite_or_none

MIN_TURN_DEG = 10.0
"""Least spread (deg) of a board's normal (or its line in a scan plane) over the recording for its timing to be
readable."""


@dataclass(frozen=True)
class OffsetAlignment:
    """How sensor b's motion lines up with sensor a's."""

    kind: str
    """What was lined up: ``directions`` (board normals), ``rates`` (angular rates) or ``lines`` (a board's cut
    through a 2D scanner's plane)."""
    offset_s: float
    """``t_b = t_a + offset_s`` (s)."""
    offset_std_s: float
    """1-sigma of ``offset_s`` (s)."""
    R_a_b: np.ndarray
    """3x3 rotation taking b's vectors into a's axes (the two sensors' relative mounting; for ``lines``, both in the
    scanner's axes, a turn about the scan plane's normal: what ``T_camera_lidar``'s yaw is off by)."""
    rotation_std_deg: float
    """1-sigma (deg) of the rotation about its least determined axis (for normals that stayed within a cone, the
    cone's axis; for lines, about the scan plane's normal)."""
    residual: float
    """RMS of a's vectors less the rotated, shifted b's (unit-vector lengths, or rad/s for rates)."""
    samples: int
    """Samples of the sparser signal that entered the fit."""
    curve: dict[str, list[float]]
    """The alignment's score against the offset, for a plot: ``offset_s`` and ``score`` (the cost, None where too
    few samples overlap; or the angular speeds' correlation for rates) with ``score_name``."""

    def to_dict(self) -> dict:
        return {"kind": self.kind, "offset_s": self.offset_s, "offset_std_s": self.offset_std_s,
                "R_a_b": self.R_a_b.tolist(), "rotation_std_deg": self.rotation_std_deg, "residual": self.residual,
                "samples": self.samples, "curve": self.curve}


def align_signals(a: MotionSignal, b: MotionSignal, *, max_offset_s: float = 0.5,
                  step_s: float = 1e-3) -> OffsetAlignment:
    """The offset (``t_b = t_a + offset``) within ``±max_offset_s`` and the rotation lining ``b`` up with ``a``;
    :class:`InputError` naming the sensors when the signals are of different kinds, do not overlap or show too
    little motion."""
    if a.kind != b.kind:
        raise InputError(f"{a.sensor} gives {a.kind} and {b.sensor} gives {b.kind}: their motions cannot be compared",
                         b.sensor)
    if a.kind == "rates":
        rates = align_rates(b.t_s, b.vectors, a.t_s, a.vectors, max_offset_s=max_offset_s, step_s=step_s,
                            name=f"{a.sensor}+{b.sensor}")
        return OffsetAlignment("rates", rates.offset_s, rates.offset_std_s, rates.R_a_b.T,
                               float(np.degrees(rates.rotation_std_rad)), rates.residual_rad_s, len(a.t_s),
                               {"offset_s": rates.curve["offset_s"], "score": rates.curve["correlation"],
                                "score_name": "angular speeds' correlation"})
    what, advice = (("line in the 2D scanner's plane", "turn the board about a vertical axis (yaw) through at least "
                     f"{MIN_TURN_DEG:g} deg while carrying it across the scan plane") if a.kind == "lines" else
                    ("normal", f"tilt and turn the board through at least {MIN_TURN_DEG:g} deg while both sensors "
                     "watch"))
    for signal in (a, b):
        turn = np.degrees(np.arccos(np.clip(signal.vectors @ _mean_direction(signal.vectors), -1, 1)).max())
        if turn < MIN_TURN_DEG:
            raise InputError(f"{signal.sensor}: the board's {what} turned at most {turn:.1f} deg; {advice}",
                             signal.sensor)
    if len(a.t_s) <= len(b.t_s):  # interpolate the denser signal at the sparser one's times
        return _align_directions(a, b, max_offset_s, step_s)
    flipped = _align_directions(b, a, max_offset_s, step_s)
    return replace(flipped, offset_s=-flipped.offset_s, R_a_b=flipped.R_a_b.T,
                   curve=flipped.curve | {"offset_s": [-o for o in flipped.curve["offset_s"]]})


def _mean_direction(vectors: np.ndarray) -> np.ndarray:
    mean = vectors.mean(axis=0)
    return mean / max(np.linalg.norm(mean), 1e-12)


def sample_signal(signal: MotionSignal, t_s: np.ndarray, derivative: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``signal`` interpolated at ``t_s`` by a cubic spline (renormalised; or its ``derivative``-th derivative) and a
    mask of the times inside it and not across a gap of more than 2.5 median steps."""
    step = float(np.median(np.diff(signal.t_s)))
    after = np.clip(np.searchsorted(signal.t_s, t_s), 1, len(signal.t_s) - 1)
    inside = (t_s >= signal.t_s[0]) & (t_s <= signal.t_s[-1]) & (
        signal.t_s[after] - signal.t_s[after - 1] <= 2.5 * step)
    values = make_interp_spline(signal.t_s, signal.vectors, k=3)(np.clip(t_s, signal.t_s[0], signal.t_s[-1]),
                                                                 nu=derivative)
    return (values if derivative else values / np.linalg.norm(values, axis=1, keepdims=True)), inside


def _wahba(sparse: np.ndarray, dense: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per offset (O, N, 3 vectors, O x N weights of 0 or 1): the rotations R (O, 3, 3) minimising the weighted
    ``sum |sparse - R dense|^2`` and that minimum over the weights' sum (mean squared residual)."""
    H = np.einsum("on,oni,onj->oij", weights, sparse, dense)
    U, S, Vt = np.linalg.svd(H)
    sign = np.sign(np.linalg.det(U @ Vt))
    S[:, 2] *= sign
    U[:, :, 2] *= sign[:, None]
    count = np.maximum(weights.sum(axis=1), 1)
    return U @ Vt, np.maximum((2 * count - 2 * S.sum(axis=1)) / count, 0.0)


def _turn_in_plane(sparse: np.ndarray, dense: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_wahba` for vectors in the plane z = 0: the rotations about z alone (O, 3, 3), at the angle
    ``atan2(sum (dense x sparse) . z, sum dense . sparse)``, and the mean squared residual."""
    dot = np.einsum("on,oni,oni->o", weights, sparse[..., :2], dense[..., :2])
    cross = np.einsum("on,on->o", weights, dense[..., 0] * sparse[..., 1] - dense[..., 1] * sparse[..., 0])
    angle = np.arctan2(cross, dot)
    R = np.zeros((len(angle), 3, 3))
    R[:, 0, 0] = R[:, 1, 1] = np.cos(angle)
    R[:, 1, 0] = np.sin(angle)
    R[:, 0, 1] = -R[:, 1, 0]
    R[:, 2, 2] = 1.0
    count = np.maximum(weights.sum(axis=1), 1)
    return R, np.maximum((2 * count - 2 * np.hypot(dot, cross)) / count, 0.0)


def persistence(residuals: np.ndarray) -> float:
    """How much residuals (N, 3) in time order that persist from sample to sample widen a white-noise variance:
    ``(1 + rho) / (1 - rho)`` for their lag-one autocorrelation ``rho`` (an AR(1) model's variance of a mean; rho
    held within 0 to 0.95). A LiDAR's board normal errs alike over consecutive scans (the same scan lines cross the
    board), so a white-noise sigma would claim the halves of a recording agree to a fraction of a millisecond when
    they differ by several."""
    centred = residuals - residuals.mean(axis=0)
    denominator = float(np.sum(centred**2))
    rho = float(np.sum(centred[1:] * centred[:-1]) / denominator) if denominator > 0 else 0.0
    rho = min(max(rho, 0.0), 0.95)
    return (1 + rho) / (1 - rho)


def _align_directions(sparse: MotionSignal, dense: MotionSignal, max_offset_s: float,
                      step_s: float) -> OffsetAlignment:
    """:func:`align_signals` for unit vectors (normals, or lines in a scan plane) with ``sparse`` the signal of fewer
    samples (it is ``a``)."""
    planar = sparse.kind == "lines"
    fit = _turn_in_plane if planar else _wahba
    offsets = np.arange(-max_offset_s, max_offset_s + step_s / 2, step_s)
    times = sparse.t_s[None, :] + offsets[:, None]
    moved, inside = sample_signal(dense, times.ravel())
    moved, inside = moved.reshape(*times.shape, 3), inside.reshape(times.shape)
    counts = inside.sum(axis=1)
    usable = counts >= max(MIN_SAMPLES, 0.5 * counts.max())
    if not usable.any():
        raise InputError(f"{sparse.sensor} and {dense.sensor} do not overlap in time within ±{max_offset_s} s",
                         dense.sensor)
    _, cost = fit(np.broadcast_to(sparse.vectors, moved.shape), moved, inside.astype(float))
    cost[~usable] = np.nan
    best = int(np.nanargmin(cost))
    offset_s = float(offsets[best])
    if 0 < best < len(offsets) - 1 and np.isfinite(cost[best - 1: best + 2]).all():
        left, middle, right = cost[best - 1: best + 2]
        curvature = left - 2 * middle + right
        if curvature > 0:
            offset_s += float(0.5 * (left - right) / curvature * step_s)
    at, keep = sample_signal(dense, sparse.t_s + offset_s)
    R, final = fit(sparse.vectors[None, keep], at[None, keep], np.ones((1, int(keep.sum()))))
    R_a_b = R[0]
    n = int(keep.sum())
    mapped = at[keep] @ R_a_b.T
    # per component (lines: the one across the line), less the rotation's 3 (1) and the offset; widened for errors
    # that persist from sample to sample
    freedom = n - 2 if planar else 3 * n - 4
    variance = float(final[0]) * n / max(freedom, 1) * persistence(sparse.vectors[keep] - mapped)
    slope_at, _ = sample_signal(dense, sparse.t_s[keep] + offset_s, derivative=1)
    information = float(np.sum(slope_at**2)) / max(variance, 1e-18)
    offset_std = float(np.hypot(1 / np.sqrt(information), step_s / np.sqrt(12))) if information > 0 else float("inf")
    if planar:  # each sample gives the turn's angle with the residual's variance
        rotation_std = float(np.degrees(np.sqrt(variance / n)))
    else:
        information = (n * np.eye(3) - mapped.T @ mapped) / max(variance, 1e-18)  # sum of (I - m m^T) / s^2
        rotation_std = float(np.degrees(np.sqrt(np.linalg.eigvalsh(np.linalg.inv(information)).max())))
    return OffsetAlignment(sparse.kind, offset_s, offset_std, R_a_b, rotation_std, float(np.sqrt(final[0])), n,
                           {"offset_s": offsets.tolist(), "score": finite_or_none(cost),
                            "score_name": f"mean squared {'line' if planar else 'normal'} difference"})
