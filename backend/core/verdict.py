"""How far a result can be trusted: one verdict for every solver's result.

A verdict is ``{"level": "trusted" | "check" | "reject", "reasons": [...]}`` (the CLI's JSON, the API
and the studio all show it as it is). It weighs each reported 1-sigma against a stated tolerance for that
quantity, plus at least one *independent* cross-check: two halves of the data, another scene, another
method, the multi-camera pair checks. A result is ``trusted`` only when every sigma is within its
tolerance **and** a cross-check was made and passed; a cross-check that could not be made is named as
missing and leaves the result at ``check``, never ``trusted`` by default.

- ``reject``: the result is wrong or undetermined (a cross-check failed beyond :data:`REJECT_SIGMAS` of its
  sigma, a parameter the data does not pin, a solve that did not converge). It cannot be accepted.
- ``check``: the numbers may be right, but something is missing or loose (a sigma above its tolerance,
  no cross-check possible). It can be accepted only with an explicit confirmation, which the session
  records with the acceptance.
- ``trusted``: within tolerance and cross-checked.

Build one with :class:`VerdictBuilder`, in the solver or service that knows the quantities::

    judge = VerdictBuilder()
    judge.sigma("translation", max_std_m * 1e3, tolerance=10.0, unit="mm")
    judge.cross_check_sigmas("two halves of the views", diff_px / expected_px,
                             f"halves differ by {diff_px:.2f} px, {expected_px:.2f} px expected")
    verdict = judge.verdict()

The cross-check rule, the same for every problem: a measured cross-check passes while its difference is within
:data:`CROSS_CHECK_SIGMAS` of its own 1-sigma (a check against a stated allowance instead counts the allowance
as that many sigmas); failed by up to :data:`REJECT_SIGMAS` it is ``check``, beyond it ``reject``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

Level = Literal["trusted", "check", "reject"]
LEVELS: tuple[Level, ...] = ("trusted", "check", "reject")
"""From best to worst; a verdict's level is the worst any of its findings gives."""

TRANSLATION_TOLERANCE_M = 0.01
"""Default largest acceptable 1-sigma of a transform's translation, per axis (m)."""
ROTATION_TOLERANCE_DEG = 0.2
"""Default largest acceptable 1-sigma of a transform's rotation, per axis (deg)."""
PROJECTION_TOLERANCE_PX = 0.3
"""Default largest acceptable worst-case projection 1-sigma across the image (px)."""

CROSS_CHECK_SIGMAS = 3.0
"""A measured cross-check passes while its difference is within this many of its own 1-sigmas."""
REJECT_SIGMAS = 5.0
"""A measured cross-check that fails by more than this many of its 1-sigmas is ``reject`` (the result is wrong);
failed by less, ``check``."""

NO_VERDICT_REASON = "no verdict was recorded with this result (made before verdicts, or by hand)"


@dataclass(frozen=True)
class Verdict:
    """A result's verdict: its ``level`` and every ``reason`` behind it (passed checks included)."""

    level: Level
    reasons: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """The JSON form: ``{"level", "reasons"}``."""
        return {"level": self.level, "reasons": list(self.reasons)}

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> Verdict:
        """The verdict stored in a result record; a record without one (older, or hand-set) is ``check``."""
        stored = record.get("verdict")
        if isinstance(stored, dict) and stored and "level" not in stored:  # one per part (multicam: per camera)
            return worst_of([cls._from_dict(part, f"{name}: ") for name, part in stored.items()])
        return cls._from_dict(stored)

    @classmethod
    def _from_dict(cls, stored: Any, prefix: str = "") -> Verdict:
        if not isinstance(stored, dict) or stored.get("level") not in LEVELS:
            return cls("check", [prefix + NO_VERDICT_REASON])
        return cls(stored["level"], [prefix + str(r) for r in stored.get("reasons", [])])

    def worst(self, other: Verdict) -> Verdict:
        """One verdict holding both: the worse level, every reason."""
        level = max(self.level, other.level, key=LEVELS.index)
        return Verdict(level, [*self.reasons, *other.reasons])


def worst_of(verdicts: list[Verdict]) -> Verdict:
    """The combined verdict of several (e.g. every camera of a rig); ``check`` with a reason when empty."""
    if not verdicts:
        return Verdict("check", ["nothing was judged"])
    combined = verdicts[0]
    for verdict in verdicts[1:]:
        combined = combined.worst(verdict)
    return combined


class VerdictBuilder:
    """Collects findings and gives the :class:`Verdict`; the level is the worst finding's."""

    def __init__(self) -> None:
        self._level: Level = "trusted"
        self._reasons: list[str] = []
        self._cross_checks = 0
        """Cross-checks made (passed or failed) or named as missing."""

    def _raise(self, level: Level, reason: str) -> None:
        self._level = max(self._level, level, key=LEVELS.index)
        self._reasons.append(reason)

    def reject(self, reason: str) -> None:
        """The result is wrong or undetermined."""
        self._raise("reject", reason)

    def check(self, reason: str) -> None:
        """Something needs the user's look before the result is taken."""
        self._raise("check", reason)

    def note(self, reason: str) -> None:
        """A finding that passed (kept among the reasons, so a ``trusted`` says why)."""
        self._reasons.append(reason)

    def sigma(self, name: str, value: float | None, tolerance: float, unit: str, reject_factor: float = 10.0) -> None:
        """Weigh the 1-sigma ``value`` of ``name`` against ``tolerance`` (both in ``unit``).

        Not finite (undetermined by the data), or above ``reject_factor`` times the tolerance: ``reject``;
        above the tolerance: ``check``; else a passed note.
        """
        if value is None or not np.isfinite(value):
            self.reject(f"{name} is not determined by the data (no finite sigma)")
        elif value > reject_factor * tolerance:
            self.reject(f"{name} sigma {value:.3g} {unit} is far above the tolerance {tolerance:.3g} {unit}")
        elif value > tolerance:
            self.check(f"{name} sigma {value:.3g} {unit} is above the tolerance {tolerance:.3g} {unit}")
        else:
            self.note(f"{name} sigma {value:.3g} {unit} is within the tolerance {tolerance:.3g} {unit}")

    def cross_check(self, name: str, passed: bool, detail: str, fail_level: Level = "check") -> None:
        """An independent cross-check ``name`` that was made: passed, or failed at ``fail_level``."""
        self._cross_checks += 1
        if passed:
            self.note(f"cross-check {name}: {detail}")
        else:
            self._raise(fail_level, f"cross-check {name} failed: {detail}")

    def cross_check_sigmas(self, name: str, sigmas: float, detail: str) -> None:
        """A measured cross-check ``name`` whose difference is ``sigmas`` of its own 1-sigma (for a check against an
        allowance, :data:`CROSS_CHECK_SIGMAS` times the difference over the allowance): passed within
        :data:`CROSS_CHECK_SIGMAS`; failed as ``check`` up to :data:`REJECT_SIGMAS`, as ``reject`` beyond (or when
        not finite). ``detail`` says what was compared; the number of sigmas and the rule are added."""
        if sigmas <= CROSS_CHECK_SIGMAS:
            self.cross_check(name, True, f"{detail} ({sigmas:.1f} sigma, within {CROSS_CHECK_SIGMAS:g})")
        else:
            level: Level = "check" if sigmas <= REJECT_SIGMAS else "reject"
            self.cross_check(name, False, f"{detail} ({sigmas:.1f} sigma: beyond {CROSS_CHECK_SIGMAS:g} is check, "
                             f"beyond {REJECT_SIGMAS:g} reject)", fail_level=level)

    def missing_check(self, name: str, why: str) -> None:
        """A cross-check that could not be made; the result cannot be ``trusted`` on its sigmas alone."""
        self._cross_checks += 1
        self.check(f"no cross-check {name}: {why}")

    def verdict(self) -> Verdict:
        """The verdict so far; a result whose cross-checks were neither made nor named missing is at best ``check``
        (and ``trusted`` needs every one made to pass: a missing one is a ``check`` finding)."""
        if self._cross_checks == 0:
            self.check("no independent cross-check was made")
        return Verdict(self._level, list(self._reasons))


def judge_transform_sigmas(judge: VerdictBuilder, std: dict[str, list[float | None]],
                           translation_tolerance_m: float = TRANSLATION_TOLERANCE_M,
                           rotation_tolerance_deg: float = ROTATION_TOLERANCE_DEG) -> None:
    """Weigh a transform's reported ``std`` (``{"trans_m": [3], "rot_deg": [3]}``) against its tolerances:
    the largest axis of each, translation in mm and rotation in degrees."""
    trans = [np.inf if s is None else s for s in std["trans_m"]]
    rot = [np.inf if s is None else s for s in std["rot_deg"]]
    judge.sigma("translation", 1e3 * max(trans), 1e3 * translation_tolerance_m, "mm")
    judge.sigma("rotation", max(rot), rotation_tolerance_deg, "deg")
