"""IMU samples and their checks: what a camera-IMU or LiDAR-IMU solve is given.

Angular rates are in rad/s and specific forces in m/s², both in the IMU's own frame (x forward, y left, z up for a
body; whatever the IMU's case says otherwise). Times are seconds on the IMU's clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.core.errors import InputError

GAP_FACTOR = 5.0
"""A step between samples longer than this many median periods is a gap in the stream."""
SATURATION_SHARE = 0.01
"""Share of samples allowed at one axis's largest magnitude before the axis is called saturated."""


@dataclass(frozen=True)
class ImuSamples:
    """A stream of IMU samples, in time order."""

    t_s: np.ndarray
    """(N,) sample times (s) on the IMU's clock."""
    gyro_rad_s: np.ndarray
    """(N, 3) angular rate (rad/s) about the IMU's axes."""
    accel_m_s2: np.ndarray
    """(N, 3) specific force (m/s²) along the IMU's axes (gravity's reaction included: +9.8 up at rest)."""
    saturated: np.ndarray | None = None
    """(N,) True where an axis sat at its saturation value (:func:`checked_imu`): a solve leaves those out."""

    @property
    def rate_hz(self) -> float:
        """The median sample rate (Hz)."""
        return float(1.0 / np.median(np.diff(self.t_s)))

    def between(self, start_s: float, end_s: float) -> ImuSamples:
        """The samples with ``start_s <= t <= end_s``."""
        keep = (self.t_s >= start_s) & (self.t_s <= end_s)
        return ImuSamples(self.t_s[keep], self.gyro_rad_s[keep], self.accel_m_s2[keep],
                          None if self.saturated is None else self.saturated[keep])


def checked_imu(t_s: np.ndarray, gyro_rad_s: np.ndarray, accel_m_s2: np.ndarray, name: str,
                min_samples: int = 100) -> tuple[ImuSamples, list[str]]:
    """Samples as :class:`ImuSamples` and the warnings they earn; :class:`InputError` naming ``name`` for what no
    solve can use: too few samples, values not finite, or time stamps that run backwards or repeat.

    Warned, not refused (the samples are kept): gaps longer than :data:`GAP_FACTOR` periods, and axes that sit at
    their largest magnitude (a saturated gyro or accelerometer clips the motion it should measure).
    """
    t_s = np.asarray(t_s, float)
    gyro_rad_s = np.asarray(gyro_rad_s, float).reshape(-1, 3)
    accel_m_s2 = np.asarray(accel_m_s2, float).reshape(-1, 3)
    if len(t_s) < min_samples:
        raise InputError(f"{name} holds {len(t_s)} IMU sample(s); at least {min_samples} are needed", name)
    bad = ~(np.isfinite(t_s) & np.isfinite(gyro_rad_s).all(axis=1) & np.isfinite(accel_m_s2).all(axis=1))
    if bad.any():
        raise InputError(f"{name}: sample {int(np.argmax(bad)) + 1} is not finite; expected numbers in every "
                         "column", name)
    steps = np.diff(t_s)
    if (steps <= 0).any():
        at = int(np.argmax(steps <= 0))
        raise InputError(f"{name}: time stamps run backwards or repeat at sample {at + 2} ({t_s[at + 1]:.6f} s "
                         f"after {t_s[at]:.6f} s); expected strictly increasing times", name)
    warnings: list[str] = []
    period = float(np.median(steps))
    gaps = np.flatnonzero(steps > GAP_FACTOR * period)
    if len(gaps):
        longest = float(steps[gaps].max())
        warnings.append(f"{name}: {len(gaps)} gap(s) in the IMU stream, the longest {longest * 1e3:.0f} ms at "
                        f"{t_s[gaps[np.argmax(steps[gaps])]] - t_s[0]:.2f} s (the rate is {1 / period:.0f} Hz); "
                        "the trajectory is bridged across them")
    saturated = np.zeros(len(t_s), bool)
    for label, values, unit in (("gyro", gyro_rad_s, "rad/s"), ("accelerometer", accel_m_s2, "m/s²")):
        peak = np.abs(values).max(axis=0)
        at_peak = np.abs(values) >= peak * (1 - 1e-9)
        for axis in range(3):
            share = float(at_peak[:, axis].mean())
            if share > SATURATION_SHARE and peak[axis] > 0:
                saturated |= at_peak[:, axis]
                warnings.append(f"{name}: the {label}'s {'xyz'[axis]} axis sits at {peak[axis]:.3g} {unit} in "
                                f"{share:.1%} of the samples: saturated; those samples are left out, and the motion "
                                "they clip is lost: move more gently")
    return ImuSamples(t_s, gyro_rad_s, accel_m_s2, saturated), warnings
