"""States are words in colour, never emoji: Debian's chromium without an emoji font draws emoji as empty boxes."""

from __future__ import annotations

import re
from pathlib import Path

from studio.marks import COLOURS, mark

STUDIO = Path(__file__).resolve().parents[2] / "studio"
EMOJI = re.compile("[\u2600-\u27bf\u2b00-\u2bff\U0001f000-\U0001faff\ufe0f]")
"""Symbols, dingbats, arrows-and-shapes and the emoji planes, and the emoji variation selector."""


def test_no_studio_text_uses_an_emoji():
    found = [f"{path.relative_to(STUDIO)}:{number}: {line.strip()}"
             for path in sorted(STUDIO.rglob("*.py"))
             for number, line in enumerate(path.read_text().splitlines(), 1) if EMOJI.search(line)]
    assert not found, "\n".join(found)


def test_a_mark_is_the_word_in_its_colour():
    assert mark("reject", "bad") == f'<b style="color: {COLOURS["bad"]}">reject</b>'
    assert mark("<b>", "good") == f'<b style="color: {COLOURS["good"]}">&lt;b&gt;</b>'
