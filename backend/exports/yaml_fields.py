"""Checked access to the fields of a YAML document, shared by the exports' readers.

Every problem raises :class:`InputError` whose message names the document (its file),
the field (a dotted path such as ``cam1.T_cn_cnm1[2]``) and what was expected.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import yaml

from backend.core.errors import InputError


def dump_yaml(document: Any) -> str:
    """YAML text of ``document`` in its own key order, short lists inline, no line folding."""
    return yaml.safe_dump(document, sort_keys=False, default_flow_style=None, width=math.inf)


def parse_yaml(text: str, origin: str, expected: str) -> Any:
    """``yaml.safe_load`` of ``text``; invalid YAML raises :class:`InputError` naming ``origin``, the line and
    column, PyYAML's problem and ``expected`` (a cut-off file is the usual cause)."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "syntax error"
        raise InputError(f"{origin}: not valid YAML{where} ({problem}); the file may be truncated; expected "
                         f"{expected}", origin) from None


def floats(values: Any) -> list[float]:
    """Plain Python floats, so YAML gets full-precision numbers."""
    return [float(v) for v in np.asarray(values, dtype=float).ravel()]


class YamlFields:
    """Typed, checked access to the fields of one document read from ``origin`` (a file name)."""

    def __init__(self, origin: str):
        self.origin = origin

    def error(self, field: str, problem: str, expected: str) -> InputError:
        return InputError(f"{self.origin}: field '{field}' {problem}; expected {expected}", self.origin)

    def get(self, mapping: dict[str, Any], key: str, field: str, expected: str) -> Any:
        if key not in mapping:
            raise self.error(field, "is missing", expected)
        return mapping[key]

    def mapping(self, value: Any, field: str, expected: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.error(field, f"is {value!r}", expected)
        return value

    def number(self, value: Any, field: str) -> float:
        """A finite number; strings such as ``1e-05`` (a float in YAML 1.2, a string to PyYAML) are accepted."""
        number: float | None = None
        if isinstance(value, int | float) and not isinstance(value, bool):
            number = float(value)
        elif isinstance(value, str):
            try:
                number = float(value)
            except ValueError:
                number = None
        if number is None or not math.isfinite(number):
            raise self.error(field, f"is {value!r}", "a finite number")
        return number
