"""Words that carry a state, in colour: a verdict, an edge's fit, a node's presence, a warning.

A state is a word (*trusted*, *check*, *reject*, *flagged*, *unverified*, *warning* ...) read the same with or
without colour, shown bold in its tone's colour through the raw HTML viser's markdown passes on. Emoji are not
used: where no emoji font is installed (Debian's chromium without ``fonts-noto-color-emoji``) they show as empty
boxes.
"""

from __future__ import annotations

import html
from typing import Literal

Tone = Literal["good", "warn", "bad", "muted"]
COLOURS: dict[Tone, str] = {"good": "#2b8a3e", "warn": "#d9480f", "bad": "#c92a2a", "muted": "#868e96"}
"""Mantine's green 9, orange 9, red 9 and gray 6: readable on the panel's white."""


def mark(text: str, tone: Tone) -> str:
    """``text`` in bold, in ``tone``'s colour (inline HTML for a markdown handle)."""
    return f'<b style="color: {COLOURS[tone]}">{html.escape(text)}</b>'


WARNING = mark("warning:", "warn")
"""Leads a line that warns ("warning: the overlay failed ...")."""
