"""Checked access to the fields of a YAML document, shared by the exports' readers.

Every problem raises :class:`InputError` whose message names the document (its file),
the field (a dotted path such as ``cam1.T_cn_cnm1[2]``) and what was expected.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import yaml

from backend.core.errors import InputError, clip, shorten
from backend.exports.text_file import MAX_TEXT_BYTES

MAX_YAML_DEPTH = 20
"""The deepest nesting of sequences and mappings read; calibration files nest three or four levels."""


def dump_yaml(document: Any) -> str:
    """YAML text of ``document`` in its own key order, short lists inline, no line folding."""
    return yaml.safe_dump(document, sort_keys=False, default_flow_style=None, width=math.inf)


class _RefusedYaml(yaml.YAMLError):
    """A document this reader refuses although it is valid YAML: its ``problem`` says why."""

    def __init__(self, problem: str, mark: yaml.Mark):
        super().__init__(problem)
        self.problem, self.problem_mark = problem, mark


class _PlainLoader(yaml.SafeLoader):
    """``SafeLoader`` without aliases and deep nesting: no calibration file uses either, and they are how a few
    hundred bytes expand into gigabytes (an alias bomb) or exhaust the stack (``[[[[...``)."""

    def __init__(self, stream: str):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise _RefusedYaml(f"an alias (*{clip(str(event.anchor), 40)}) refers to an anchor; aliases are not "
                               "accepted, write the values out", event.start_mark)
        self._depth += 1
        try:
            if self._depth > MAX_YAML_DEPTH:
                raise _RefusedYaml(f"nested more than {MAX_YAML_DEPTH} levels deep", self.peek_event().start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def parse_yaml(text: str, origin: str, expected: str) -> Any:
    """The document in ``text`` (plain data, as ``yaml.safe_load`` gives); invalid YAML raises
    :class:`InputError` naming ``origin``, the line and column, PyYAML's problem and ``expected`` (a cut-off file
    is the usual cause). Documents above :data:`MAX_TEXT_BYTES`, nested deeper than :data:`MAX_YAML_DEPTH` or
    holding an alias are refused the same way, before they cost time or memory."""
    size = len(text.encode("utf-8", "surrogatepass"))
    if size > MAX_TEXT_BYTES:
        raise InputError(f"{origin}: {size} bytes, above the {MAX_TEXT_BYTES}-byte limit for a YAML document; "
                         f"expected {expected}", origin, 413)
    loader = _PlainLoader(text)
    try:
        return loader.get_single_data()
    except _RefusedYaml as exc:
        raise InputError(f"{origin}: YAML refused{_at(exc.problem_mark)} ({exc.problem}); expected {expected}",
                         origin) from None
    except yaml.YAMLError as exc:
        problem = getattr(exc, "problem", None) or "syntax error"
        raise InputError(f"{origin}: not valid YAML{_at(getattr(exc, 'problem_mark', None))} ({problem}); the file "
                         f"may be truncated; expected {expected}", origin) from None
    except ValueError as exc:  # a scalar PyYAML resolves but cannot convert, e.g. an integer of 5000 digits
        raise InputError(f"{origin}: a value cannot be read ({clip(str(exc), 100)}); expected {expected}",
                         origin) from None
    finally:
        loader.dispose()


def _at(mark: yaml.Mark | None) -> str:
    """`` at line L, column C`` of a PyYAML mark (1-based), or nothing."""
    return f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""


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
            raise self.error(field, f"is {shorten(value)}", expected)
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
            raise self.error(field, f"is {shorten(value)}", "a finite number")
        return number
