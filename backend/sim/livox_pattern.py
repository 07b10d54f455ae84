"""Non-repetitive scan patterns of simulated Livox LiDARs: where firing ``k`` points.

Livox's Horizon and Avia steer their beams with a pair of rotating prisms (Risley prisms); the beam never retraces
its path, so the part of the field of view hit at least once grows with the integration time. The patterns here
are models with the sensors' published fields of view, firing rates and beam counts, not Livox's exact patterns:

- ``"Avia"``: a rosette over 70.4 deg x 77.2 deg (horizontal x vertical, an ellipse in azimuth/elevation), 6 beams.
  Two prisms turn in opposite directions at ``f1`` and ``f2`` Hz; beam ``j`` sits ``j/6`` of a turn further on the
  first prism. Its angular position is ``(e^{i(2 pi f1 t + 2 pi j/6)} + e^{-i 2 pi f2 t}) / 2`` (inside the unit
  disc), scaled to the half fields of view.
- ``"Horizon"``: a Lissajous figure over 81.7 deg x 25.1 deg (a rectangle), 5 beams a fifth of a period apart.

``f2 = f1 / golden ratio``, so the pattern never repeats. Over 0.5 deg cells of the field of view either
pattern hits about 62 % of the cells in 0.1 s and 98 to 99.9 % in 0.5 s.

Firing ``k`` happens at ``k * point_interval_ns`` (4167 ns: 240,000 firings/s for both models), with beams taking
turns (``j = k mod beams``). Directions are unit vectors in the LiDAR frame: x forward, y left, z up; the azimuth
turns from x towards y and the elevation up from the x-y plane.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.core.accumulation import FieldOfView
from backend.devices.livox import LIVOX_FOV
from backend.devices.livox_packets import POINT_INTERVAL_NS

_GOLDEN = (1 + 5**0.5) / 2


@dataclass(frozen=True)
class ScanPattern:
    """A simulated Livox scan pattern (see the module docstring)."""

    model: str
    fov: FieldOfView
    beams: int
    f1_hz: float
    """Turning rate of the first prism (Hz)."""
    kind: str
    """``"rosette"`` or ``"lissajous"``."""
    point_interval_ns: int

    @property
    def f2_hz(self) -> float:
        """Turning rate of the second prism (Hz): ``f1 / golden ratio``."""
        return self.f1_hz / _GOLDEN

    def angles(self, firing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(azimuth_rad, elevation_rad)`` of firings ``firing`` (int, counted from the sensor's start)."""
        firing = np.asarray(firing, np.int64)
        t = firing * (self.point_interval_ns * 1e-9)
        beam_phase = 2 * np.pi * (firing % self.beams) / self.beams
        if self.kind == "rosette":
            z = 0.5 * (np.exp(1j * (2 * np.pi * self.f1_hz * t + beam_phase)) + np.exp(-2j * np.pi * self.f2_hz * t))
            u, v = z.real, z.imag
        else:
            u, v = np.sin(2 * np.pi * self.f1_hz * t + beam_phase), np.sin(2 * np.pi * self.f2_hz * t)
        return u * self.fov.horizontal_rad / 2, v * self.fov.vertical_rad / 2

    def directions(self, firing: np.ndarray) -> np.ndarray:
        """(N, 3) unit directions of firings ``firing`` in the LiDAR frame."""
        azimuth, elevation = self.angles(firing)
        return np.column_stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                                np.sin(elevation)])


PATTERNS = {
    "Avia": ScanPattern("Avia", LIVOX_FOV["Avia"], beams=6, f1_hz=97.3, kind="rosette",
                        point_interval_ns=POINT_INTERVAL_NS[7]),
    "Horizon": ScanPattern("Horizon", LIVOX_FOV["Horizon"], beams=5, f1_hz=41.3, kind="lissajous",
                           point_interval_ns=POINT_INTERVAL_NS[3]),
}
"""The simulated models by name."""
