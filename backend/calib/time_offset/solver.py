"""The time offset between two sensors from their motion signals: aligned whole, aligned by halves, judged."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from typing import Any

from backend.calib.time_offset.alignment import OffsetAlignment, align_signals
from backend.calib.time_offset.checks import HalvesCheck, judge, reported_std
from backend.calib.time_offset.signals import MIN_SAMPLES, MotionSignal
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, SolveResult, no_progress
from backend.core.verdict import Verdict

KIND = "time_offset"


@dataclass(frozen=True)
class TimeOffsetSettings:
    max_offset_s: float = 0.5
    """The offset is searched within ``±max_offset_s`` (s)."""
    step_s: float = 1e-3
    """Search step (s), refined by a parabola through the best step."""

    def __post_init__(self) -> None:
        if not 0 < self.step_s <= self.max_offset_s <= 5.0:
            raise InputError(f"the search needs 0 < step_s <= max_offset_s <= 5 s, not step_s={self.step_s} and "
                             f"max_offset_s={self.max_offset_s}", "max_offset_s")


@dataclass
class TimeOffsetResult(SolveResult):
    """``t_b = t_a + offset_s`` between sensors ``a`` and ``b``, with its sigma, checks and the signals behind it."""

    kind = KIND
    sensor_a: str
    sensor_b: str
    offset_s: float
    std_s: float
    """Reported 1-sigma (s): the alignment's, widened to the two halves' spread."""
    alignment: OffsetAlignment
    halves: HalvesCheck | None
    verdict: Verdict
    signals: dict[str, dict[str, Any]]
    """Both signals for a plot: per sensor ``t_s`` (its own clock) and ``vectors``, and ``kind``."""
    settings: TimeOffsetSettings
    seconds: float

    def summary(self) -> dict[str, Any]:
        """The ``time-offset`` command's JSON."""
        return {"sensor_a": self.sensor_a, "sensor_b": self.sensor_b, "time_offset_s": self.offset_s,
                "std": {"time_s": self.std_s, "rot_deg": self.alignment.rotation_std_deg},
                "R_a_b": self.alignment.R_a_b.tolist(), "samples": self.alignment.samples,
                "verdict": self.verdict.to_dict(), "seconds": self.seconds}

    def to_record(self) -> dict[str, Any]:
        return self.summary() | {"kind": KIND, "converged": True, "alignment": self.alignment.to_dict(),
                                 "halves": None if self.halves is None else self.halves.to_dict(),
                                 "signals": self.signals, "settings": asdict(self.settings)}


def solve_time_offset(a: MotionSignal, b: MotionSignal, settings: TimeOffsetSettings | None = None,
                      progress: ProgressCallback = no_progress) -> TimeOffsetResult:
    """The offset lining ``b``'s motion up with ``a``'s, each half of ``a``'s span aligned alone as the cross-check."""
    started = time.perf_counter()
    settings = settings or TimeOffsetSettings()
    progress(0.1, f"lining {b.sensor}'s motion up with {a.sensor}'s")
    whole = align_signals(a, b, max_offset_s=settings.max_offset_s, step_s=settings.step_s)
    progress(0.5, "aligning each half of the recording alone")
    middle = 0.5 * (a.t_s[0] + a.t_s[-1])
    halves, missing = None, ""
    try:
        first, second = (align_signals(a.between(*span), b, max_offset_s=settings.max_offset_s, step_s=settings.step_s)
                         for span in ((a.t_s[0], middle), (middle, a.t_s[-1])))
        halves = HalvesCheck((first.offset_s, second.offset_s), (first.offset_std_s, second.offset_std_s))
    except InputError as exc:
        missing = f"a half of the recording could not be aligned alone ({exc.message}); record longer than " \
                  f"{2 * MIN_SAMPLES} samples of motion in each half"
    std_s = reported_std(whole, halves)
    progress(1.0, f"offset {1e3 * whole.offset_s:.2f} ms")
    signals = {s.sensor: {"kind": s.kind, "t_s": s.t_s.tolist(), "vectors": s.vectors.tolist()} for s in (a, b)}
    return TimeOffsetResult(a.sensor, b.sensor, whole.offset_s, std_s, whole, halves, judge(whole, halves, std_s,
                                                                                            missing),
                            signals, settings, time.perf_counter() - started)
