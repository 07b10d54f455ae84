"""Reading and writing export files as text, with the errors every importer and exporter gives."""

from __future__ import annotations

import os
import stat
import tempfile
from pathlib import Path

from backend.core.errors import InputError
from backend.store.atomic import write_bytes_atomic

MAX_TEXT_BYTES = 1_000_000
"""The largest file read as text (bytes): calibration files are a few kilobytes."""


def read_text(path: Path, expected: str) -> str:
    """UTF-8 text of ``path``; :class:`InputError` naming the file and what it should hold if unreadable or larger
    than :data:`MAX_TEXT_BYTES` (checked before reading more than that, so ``/dev/zero`` is refused too)."""
    try:
        with open(path, "rb") as handle:
            data = handle.read(MAX_TEXT_BYTES + 1)
        if len(data) > MAX_TEXT_BYTES:
            raise InputError(f"{path}: larger than the {MAX_TEXT_BYTES}-byte limit for a text file; expected "
                             f"{expected}", str(path), 413)
        return data.decode("utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read the file ({exc}); expected {expected}", str(path)) from None


def check_writable(path: Path) -> None:
    """Refuse an output path that cannot be written, before any work is done: a folder, a path in a folder that
    does not exist or is a file, a folder where no file can be created (a probe file is created and removed: this
    holds for root and read-only file systems too), an existing file without write permission."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder; expected the path of a file to write", str(path))
    folder = path.parent
    if not folder.exists():
        raise InputError(f"{path}: the folder {folder} does not exist; create it first", str(path))
    if not folder.is_dir():
        raise InputError(f"{path}: {folder} is a file, not a folder", str(path))
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f"{path}: the file is not writable (permission denied)", str(path))
    if path.exists() and not path.is_file():
        return  # a device or pipe such as /dev/stdout is written in place, nothing is created beside it
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=f".{path.name}.", suffix=".tmp")
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise InputError(f"{path}: cannot create a file in the folder {folder} ({exc.strerror or exc})",
                         str(path)) from None


def write_text(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` as :func:`write_bytes` does."""
    write_bytes(path, text.encode("utf-8"))


def write_bytes(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path``: atomically for a regular or new file (a failed write leaves the old file
    whole; the file keeps its permissions, a new one gets the umask's), in place for a device or pipe
    (``/dev/stdout``). Any failure raises :class:`InputError` naming the file and the system's reason."""
    path = Path(path)
    try:
        if path.exists() and not path.is_file():
            with open(path, "wb") as handle:
                handle.write(data)
            return
        mode = stat.S_IMODE(path.stat().st_mode) if path.exists() else 0o666 & ~_umask()
        write_bytes_atomic(path, data)
        os.chmod(path, mode)
    except OSError as exc:
        raise InputError(f"{path}: cannot write the file ({exc.strerror or exc})", str(path)) from None


def _umask() -> int:
    """The process's umask (read by setting it and setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask
