"""A dropdown of a sensor's stored results, newest first: pick one to inspect it, or to accept it (and so revert)."""

from __future__ import annotations

from collections.abc import Callable

import viser

NO_RESULT = "(none)"


class ResultHistory:
    """Holds the dropdown; ``on_pick(result_id)`` runs when the user picks a result (not when :meth:`fill` sets one)."""

    def __init__(self, gui: viser.GuiApi, on_pick: Callable[[str], None], *, label: str = "Result",
                 hint: str | None = None):
        self.dropdown = gui.add_dropdown(label, options=[NO_RESULT], hint=hint)
        self._filling = False
        self.dropdown.on_update(lambda _: None if self._filling or self.selected is None else on_pick(self.selected))

    @property
    def selected(self) -> str | None:
        """The result id on show, or None when there is none."""
        return None if self.dropdown.value == NO_RESULT else self.dropdown.value

    def fill(self, result_ids: list[str], select: str | None) -> str | None:
        """List ``result_ids`` (newest first) and show ``select`` if it is among them, else the newest; returns it."""
        self._filling = True  # setting the dropdown fires its callback
        try:
            self.dropdown.options = result_ids or [NO_RESULT]
            self.dropdown.value = select if select in result_ids else self.dropdown.options[0]
        finally:
            self._filling = False
        return self.selected
