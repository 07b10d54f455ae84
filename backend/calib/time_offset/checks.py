"""How far a time offset can be trusted: its sigma against the tolerance, and the two halves of the recording.

The offset's own sigma assumes independent errors from sample to sample; a board's normal read from a smeared scan
or a camera's rolling shutter errs alike over many samples, so each half of the recording is aligned on its own as
the independent cross-check, and the reported sigma is the larger of the whole recording's and the halves' spread
(half their difference), as the camera-IMU and LiDAR-IMU solves report theirs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.calib.time_offset.alignment import OffsetAlignment
from backend.core.verdict import Verdict, VerdictBuilder

OFFSET_TOLERANCE_S = 0.002
"""Largest acceptable 1-sigma of an offset (s): a board carried at 1 m/s moves 2 mm in it."""
MAX_NORMAL_RMS = 0.05
"""Largest RMS difference of two sensors' board normals (or lines in a scan plane) once lined up (unit vectors, about
3 deg): beyond it they did not follow one board's smooth motion (another plane taken for the board, a board held still
between jumps)."""


@dataclass(frozen=True)
class HalvesCheck:
    """The offsets of the recording's first and second halves, each aligned alone."""

    offsets_s: tuple[float, float]
    stds_s: tuple[float, float]

    @property
    def difference_s(self) -> float:
        return self.offsets_s[1] - self.offsets_s[0]

    @property
    def expected_s(self) -> float:
        """1-sigma of the difference from the halves' own sigmas (s)."""
        return float(np.hypot(*self.stds_s))

    def to_dict(self) -> dict:
        return {"offsets_s": list(self.offsets_s), "stds_s": list(self.stds_s), "difference_s": self.difference_s,
                "expected_s": self.expected_s}


def reported_std(whole: OffsetAlignment, halves: HalvesCheck | None) -> float:
    """The offset's reported 1-sigma (s): the whole recording's, widened to the halves' spread where larger."""
    return whole.offset_std_s if halves is None else max(whole.offset_std_s, abs(halves.difference_s) / 2)


def judge(whole: OffsetAlignment, halves: HalvesCheck | None, std_s: float, halves_missing: str = "") -> Verdict:
    """The verdict: the reported sigma against :data:`OFFSET_TOLERANCE_S`, the halves as the cross-check."""
    builder = VerdictBuilder()
    if whole.kind != "rates" and whole.residual > MAX_NORMAL_RMS:
        what = "lines in the scan plane" if whole.kind == "lines" else "normals"
        builder.reject(f"the two sensors' board {what} still differ by {np.degrees(whole.residual):.1f} deg RMS "
                       f"once lined up (at most {np.degrees(MAX_NORMAL_RMS):.0f} expected): they did not follow one "
                       "smoothly moving board; carry it through both views without stopping")
    builder.sigma("time offset", 1e3 * std_s, 1e3 * OFFSET_TOLERANCE_S, "ms")
    if halves is None:
        builder.missing_check("two halves", halves_missing)
    else:
        builder.cross_check_sigmas(
            "two halves", abs(halves.difference_s) / max(halves.expected_s, 1e-12),
            f"the halves' offsets ({1e3 * halves.offsets_s[0]:.2f} and {1e3 * halves.offsets_s[1]:.2f} ms) differ by "
            f"{1e3 * abs(halves.difference_s):.2f} ms, {1e3 * halves.expected_s:.2f} ms expected")
    builder.note(f"lined up on {whole.samples} samples; RMS difference {whole.residual:.3g} after the offset and "
                 f"the mounting rotation (sigma {whole.rotation_std_deg:.2f} deg about its weakest axis)")
    return builder.verdict()
