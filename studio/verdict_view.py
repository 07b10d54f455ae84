"""The verdict of a result on its card, and the confirmation a ``check`` verdict needs before it is accepted.

Every step's result card shows :func:`verdict_markdown` (the level and every reason behind it); beside its
*Accept* button sits the :class:`ConfirmCheck` box, whose value goes to the service's ``accept(...,
confirm=...)``. A ``reject`` cannot be accepted at all; the session refuses it with its reasons.
"""

from __future__ import annotations

import viser

from backend.core.verdict import Verdict
from studio.marks import mark

BADGES = {"trusted": mark("trusted", "good"), "check": mark("check", "warn"), "reject": mark("reject", "bad")}
ADVICE = {
    "trusted": "",
    "check": "Read the reasons; tick *Confirm the check* to accept it as it is.",
    "reject": "It cannot be accepted.",
}


def verdict_markdown(verdict: Verdict) -> str:
    """``Verdict: <level>`` with its advice, then one line per reason (markdown)."""
    lines = [f"Verdict: {BADGES[verdict.level]}. {ADVICE[verdict.level]}".rstrip()]
    lines += [f"- {reason}" for reason in verdict.reasons]
    return "\n".join(lines)


class ConfirmCheck:
    """A checkbox confirming a ``check`` verdict for the next *Accept*; it clears itself once used, and shows only
    beside a result whose verdict is ``check`` (a ``trusted`` one needs no confirmation, a ``reject`` takes none)."""

    def __init__(self, gui: viser.GuiApi):
        self.checkbox = gui.add_checkbox(
            "Confirm the check", initial_value=False, visible=False,
            hint="accept a result whose verdict is 'check' as it is; the confirmation is recorded with the acceptance")

    def show_for(self, level: str | None) -> None:
        """Show the box, cleared, for a result whose verdict is ``level`` (None: no result)."""
        self.checkbox.value = False
        self.checkbox.visible = level == "check"

    def take(self) -> bool:
        """The box's value for this acceptance; the box is cleared, so each confirmation is given once."""
        value = bool(self.checkbox.value)
        self.checkbox.value = False
        return value
