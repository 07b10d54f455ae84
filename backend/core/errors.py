"""The one error type for bad user input, shared by the API, the CLI and the studio."""

from __future__ import annotations

import reprlib

VALUE_LIMIT = 200
"""Characters of a user's value a message echoes (:func:`shorten`)."""

MESSAGE_LIMIT = 1000
"""Characters of a message or an input name an :class:`InputError` keeps, however it was built."""

_REPR = reprlib.Repr()
# Bounded work as well as bounded text: at most this many items per level and levels deep, so a YAML alias bomb
# (a few hundred bytes standing for 10^8 strings) is summarised in microseconds.
_REPR.maxlevel, _REPR.maxlist, _REPR.maxtuple, _REPR.maxdict, _REPR.maxset = 3, 8, 8, 6, 6
_REPR.maxstring = _REPR.maxother = _REPR.maxlong = VALUE_LIMIT


def clip(text: str, limit: int = VALUE_LIMIT) -> str:
    """``text`` cut to at most ``limit`` characters, the cut marked with ``...``."""
    return text if len(text) <= limit else text[: max(limit - 3, 0)] + "..."


def shorten(value: object, limit: int = VALUE_LIMIT) -> str:
    """``repr(value)`` for a message, at most ``limit`` characters: long strings and big or deeply nested lists
    and mappings are abbreviated (``[1, 2, ...]``) without building their whole repr."""
    try:
        return clip(_REPR.repr(value), limit)
    except ValueError:  # an integer beyond Python's 4300-digit conversion limit
        return f"<a {type(value).__name__} too large to print>"


class InputError(ValueError):
    """Bad input from the user: says what is wrong, which input and what was expected.

    ``input`` names the file, field or sensor at fault so the API (as a 4xx JSON
    body), the CLI (as a one-line error) and the studio (as a notification) can all
    point the user at it. Both are clipped to :data:`MESSAGE_LIMIT` characters, so no
    input can make an error message large; values a message echoes go through
    :func:`shorten` so that the message keeps what was expected.
    """

    def __init__(self, message: str, input: str | None = None, status_code: int = 422):
        message = clip(str(message), MESSAGE_LIMIT)
        super().__init__(message)
        self.message = message
        self.input = None if input is None else clip(str(input), MESSAGE_LIMIT)
        self.status_code = status_code

    def to_dict(self) -> dict[str, str | None]:
        return {"message": self.message, "input": self.input}

    def one_line(self) -> str:
        """``error: <input>: <message>`` on one line (the input left out when the message starts with it)."""
        where = f"{self.input}: " if self.input and not self.message.startswith(self.input) else ""
        return " ".join(f"error: {where}{self.message}".splitlines())


class NotFoundError(InputError):
    """A named session, sensor, capture or result does not exist."""

    def __init__(self, message: str, input: str | None = None):
        super().__init__(message, input, status_code=404)


class CancelledError(RuntimeError):
    """A long job was cancelled by the user before it finished."""
