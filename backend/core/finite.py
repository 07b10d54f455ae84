"""Finite-number checks for values that enter the rig, the store or an export (no NaN, no infinity)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from backend.core.errors import InputError


def first_non_finite(value: Any, path: str = "") -> tuple[str, float] | None:
    """``(path, number)`` of the first NaN or infinity inside ``value``, or None if every number is finite.

    ``value`` may nest dicts, lists, tuples and numpy arrays; the path reads like
    ``device.rate`` or ``[0][3]`` (empty for a bare number).
    """
    if isinstance(value, bool | str | bytes) or value is None:
        return None
    if isinstance(value, float | np.floating | int | np.integer):
        return None if math.isfinite(value) else (path, float(value))
    if isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
        bad = np.argwhere(~np.isfinite(value)) if value.dtype.kind == "f" else []
        if len(bad) == 0:
            return None
        index = tuple(int(i) for i in bad[0])
        return path + "".join(f"[{i}]" for i in index), float(value[index])
    if isinstance(value, dict):
        items = ((f"{path}.{key}" if path else str(key), item) for key, item in value.items())
    elif isinstance(value, list | tuple | np.ndarray):
        items = ((f"{path}[{i}]", item) for i, item in enumerate(value))
    else:
        return None
    for item_path, item in items:
        found = first_non_finite(item, item_path)
        if found is not None:
            return found
    return None


def require_finite(value: Any, what: str, input: str | None) -> None:
    """Raise :class:`InputError` (``input`` names the field or file) if ``value`` holds a NaN or infinity.

    ``what`` names the value in the message (e.g. ``"frame 'cam'"``); pass a dict such as
    ``{"T_parent_child": T}`` to have the field named too: ``frame 'cam': T_parent_child[0][3] is nan``.
    """
    found = first_non_finite(value)
    if found is not None:
        where, number = found
        raise InputError(f"{what}: {where or 'value'} is {number!r}; expected finite numbers (no NaN or infinity)",
                         input)
