"""Simulation only: the studio asks the simulated person to handle the yard's board another way.

Steps whose captures need the board still (6, 7) or moving (11) offer it when the session's camera is a simulator
(:func:`~backend.services.demo.move_simulated_board`); a real board is moved by a person, not the studio.
"""

from __future__ import annotations

from backend.core.errors import InputError
from backend.services.demo import BOARD_MOTIONS, move_simulated_board
from studio.context import StudioContext


def move_board(ctx: StudioContext, camera: str, motion: str) -> bool:
    """Have the simulated person handle the board as ``motion`` says for ``camera`` (a key of
    :data:`~backend.services.demo.BOARD_MOTIONS`), say so, and redraw what depends on the rig; False (and a
    notification saying why) when it cannot."""
    try:
        move_simulated_board(ctx.session, camera, motion)
    except InputError as exc:
        ctx.notify("Cannot move the simulated board", exc.message, error=True)
        return False
    ctx.notify("The simulated board", f"It is now {BOARD_MOTIONS[motion]}.")
    ctx.rig_changed()
    return True
