"""A camera target by its spec: a planar board (:class:`~backend.core.boards.BoardSpec`) or a surveyed wall test
field (:class:`~backend.core.test_field.TestField`), which the intrinsics solve takes alike."""

from __future__ import annotations

from pathlib import Path
from typing import TypeAlias

from backend.core.boards import BoardSpec
from backend.core.test_field import TestField

CameraTarget: TypeAlias = BoardSpec | TestField


def parse_target(spec: str, folder: Path | None = None) -> CameraTarget:
    """A board spec or a ``testfield:`` spec, parsed (the test field's survey file read, from the session
    ``folder`` if given: :meth:`TestField.parse`)."""
    return TestField.parse(spec, folder) if spec.strip().startswith("testfield:") else BoardSpec.parse(spec)
