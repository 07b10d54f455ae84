"""Reading an export file as text, with the error every importer gives."""

from __future__ import annotations

from pathlib import Path

from backend.core.errors import InputError


def read_text(path: Path, expected: str) -> str:
    """UTF-8 text of ``path``; :class:`InputError` naming the file and what it should hold if unreadable."""
    try:
        return Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the file ({exc}); expected {expected}", str(path)) from None
