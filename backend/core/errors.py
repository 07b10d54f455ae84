"""The one error type for bad user input, shared by the API, the CLI and the studio."""

from __future__ import annotations


class InputError(ValueError):
    """Bad input from the user: says what is wrong, which input and what was expected.

    ``input`` names the file, field or sensor at fault so the API (as a 4xx JSON
    body), the CLI (as a one-line error) and the studio (as a notification) can all
    point the user at it.
    """

    def __init__(self, message: str, input: str | None = None, status_code: int = 422):
        super().__init__(message)
        self.message = message
        self.input = input
        self.status_code = status_code

    def to_dict(self) -> dict[str, str | None]:
        return {"message": self.message, "input": self.input}

    def one_line(self) -> str:
        where = f"{self.input}: " if self.input else ""
        return f"error: {where}{self.message}".replace("\n", " ")


class NotFoundError(InputError):
    """A named session, sensor, capture or result does not exist."""

    def __init__(self, message: str, input: str | None = None):
        super().__init__(message, input, status_code=404)


class CancelledError(RuntimeError):
    """A long job was cancelled by the user before it finished."""
