"""Numeric CSV tables with named columns (IMU samples, detected board corners), read with their sizes bounded."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from backend.core.errors import InputError
from backend.core.limits import MAX_TABLE_MB


def read_table(path: Path, columns: tuple[str, ...], name: str | None = None) -> np.ndarray:
    """The (N, len(columns)) float64 rows of a CSV file whose first line names ``columns`` (a leading ``#`` is
    allowed, as EuRoC writes it), in that order. :class:`InputError` naming the file (``name``, else its path) for
    a missing or too large file, other columns, or a row that is not numbers."""
    shown = name or str(path)
    limit = MAX_TABLE_MB.value() * 1_000_000
    try:
        with open(path, "rb") as handle:
            data = handle.read(limit + 1)
    except OSError as exc:
        raise InputError(f"cannot read {shown}: {exc.strerror or exc}", shown) from None
    if len(data) > limit:
        raise InputError(f"{shown} is larger than {MAX_TABLE_MB.describe()}", shown, 413)
    return parse_table(data, columns, shown)


def parse_table(data: bytes, columns: tuple[str, ...], name: str) -> np.ndarray:
    """:func:`read_table` on a file's bytes."""
    expected = ", ".join(columns)
    text = data.decode("utf-8", errors="replace")
    header, _, body = text.partition("\n")
    found = tuple(c.strip().lower() for c in header.lstrip("#").strip().split(","))
    if found != tuple(c.lower() for c in columns):
        aliases = {"ts": "t_ns", "timestamp": "t_ns"}
        if tuple(aliases.get(c, c) for c in found) != tuple(c.lower() for c in columns):
            raise InputError(f"{name}: the header names the columns {', '.join(found)[:200]}; expected {expected}",
                             name)
    try:
        rows = np.loadtxt(io.StringIO(body), delimiter=",", ndmin=2, dtype=float)
    except ValueError as exc:
        raise InputError(f"{name}: {str(exc).splitlines()[0][:200]}; expected numbers in the columns {expected}",
                         name) from None
    if rows.size == 0:
        raise InputError(f"{name} holds no rows; expected the columns {expected}", name)
    if rows.shape[1] != len(columns):
        raise InputError(f"{name}: rows have {rows.shape[1]} values; expected {len(columns)} ({expected})", name)
    return rows
