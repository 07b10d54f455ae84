"""File uploads at the API's edge: a size limit per request, checked file names, clouds streamed to disk.

A route that takes files is declared with ``route_class=UploadRoute`` on its router and the decorator
:func:`upload_limit` naming its :class:`~backend.core.limits.Limit`. The limit is enforced before the body
is read (a declared ``Content-Length`` above it is a 413 at once) and while it is read (the bytes are
counted as they arrive, so a body without a length, or with a false one, stops at the limit too). The 413
names the limit and its environment variable.

Starlette spools each uploaded file to a temporary file as it arrives; :func:`save_uploads` copies them in
chunks into a folder of the session (never the whole file in memory) for the readers that take a path.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

from fastapi import UploadFile
from fastapi.routing import APIRoute
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.types import Message, Receive, Scope, Send

from backend.core.errors import InputError
from backend.core.limits import BYTES_PER_MB, MAX_IMAGE_UPLOAD_MB, Limit
from backend.store.atomic import UPLOAD_FOLDER_PREFIX
from backend.store.session import Session

COPY_CHUNK_BYTES = 1 << 20
"""Bytes copied at a time from an upload's spool file to the session folder."""
MAX_NAME_BYTES = 255
"""Longest file name (UTF-8 bytes) a file system takes."""

Endpoint = TypeVar("Endpoint", bound=Callable[..., Any])


class UploadTooLarge(InputError, HTTPException):
    """The 413 :class:`InputError` of an over-size body, raised while FastAPI reads the body.

    FastAPI's body reader passes HTTP exceptions through as they are and turns any other into a 400 "error
    parsing the body", so this is both; the app answers it with its ``InputError`` handler like any other.
    """

    def __init__(self, message: str, input: str):
        InputError.__init__(self, message, input, status_code=413)
        self.detail, self.headers = self.message, None


def upload_limit(limit: Limit, field: str) -> Callable[[Endpoint], Endpoint]:
    """Mark a route's endpoint with the size limit of its whole request body; ``field`` (the form field of
    its files) is the ``input`` a 413 names. Takes effect on routes of class :class:`UploadRoute`."""

    def mark(endpoint: Endpoint) -> Endpoint:
        endpoint.upload_limit = (limit, field)  # type: ignore[attr-defined]
        return endpoint

    return mark


class UploadRoute(APIRoute):
    """A route that refuses a request body above its endpoint's :func:`upload_limit` with a 413."""

    async def handle(self, scope: Scope, receive: Receive, send: Send) -> None:
        marked: tuple[Limit, str] | None = getattr(self.endpoint, "upload_limit", None)
        if marked is None:
            await super().handle(scope, receive, send)
            return
        limit, field = marked
        max_bytes = limit.value() * BYTES_PER_MB
        declared = Headers(scope=scope).get("content-length", "")
        if declared.isdigit() and int(declared) > max_bytes:
            raise UploadTooLarge(f"the upload is {int(declared) / BYTES_PER_MB:,.1f} MB, more than "
                                 f"{limit.describe()}", field)
        received = 0

        async def counted() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > max_bytes:
                    raise UploadTooLarge(f"the upload is more than {limit.describe()}; it was refused after "
                                         f"{received / BYTES_PER_MB:,.1f} MB", field)
            return message

        await super().handle(scope, counted, send)


def file_name(upload: UploadFile, field: str, default: str) -> str:
    """The upload's file name without any folder part (``default`` when it has none).

    A name with a control character (a NUL byte, a newline...) or longer than :data:`MAX_NAME_BYTES` is an
    :class:`InputError` naming the form ``field``.
    """
    given = upload.filename or ""
    if any(ord(c) < 32 or ord(c) == 127 for c in given):
        raise InputError(f"the file name {given[:200]!r} in field '{field}' holds a control character (such as a "
                         "NUL byte); expected a plain file name", field)
    name = Path(given).name
    if name in ("", ".", ".."):
        return default
    if len(name.encode()) > MAX_NAME_BYTES:
        raise InputError(f"the file name {name[:60]!r}... in field '{field}' is {len(name.encode())} bytes long; "
                         f"expected at most {MAX_NAME_BYTES}", field)
    return name


def read_image_upload(upload: UploadFile, field: str, default: str = "upload") -> tuple[str, bytes]:
    """(file name, bytes) of an uploaded image; one file above :data:`MAX_IMAGE_UPLOAD_MB` is a 413 naming it."""
    name = file_name(upload, field, default)
    max_bytes = MAX_IMAGE_UPLOAD_MB.value() * BYTES_PER_MB
    if upload.size is not None and upload.size > max_bytes:
        raise InputError(f"{name}: the image file is {upload.size / BYTES_PER_MB:,.1f} MB, more than "
                         f"{MAX_IMAGE_UPLOAD_MB.describe()}", name, status_code=413)
    upload.file.seek(0)
    return name, upload.file.read()


def read_csv_upload(upload: UploadFile, field: str) -> tuple[str, bytes]:
    """(file name, bytes) of an uploaded CSV table (its size bounded by the route's :func:`upload_limit`); an empty
    file is refused naming it."""
    name = file_name(upload, field, f"{field}.csv")
    data = upload.file.read()
    if not data:
        raise InputError(f"{name} is empty; expected a CSV file", field)
    return name, data


@contextlib.contextmanager
def upload_folder(session: Session) -> Iterator[Path]:
    """A temporary folder inside the session's folder (same disk as the captures), removed afterwards."""
    with tempfile.TemporaryDirectory(dir=session.path, prefix=UPLOAD_FOLDER_PREFIX) as folder:
        yield Path(folder)


def save_upload(upload: UploadFile, name: str, folder: Path) -> Path:
    """Copy an upload in chunks to ``folder/name`` (``folder`` created); the path written."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    upload.file.seek(0)
    with path.open("wb") as out:
        shutil.copyfileobj(upload.file, out, COPY_CHUNK_BYTES)
    return path


def save_uploads(uploads: list[UploadFile], field: str, folder: Path) -> list[tuple[str, Path]]:
    """:func:`save_upload` every file (each in its own subfolder, so equal names do not collide):
    (file name, path) pairs in upload order."""
    saved = []
    for index, upload in enumerate(uploads):
        name = file_name(upload, field, "upload")
        saved.append((name, save_upload(upload, name, folder / str(index))))
    return saved
