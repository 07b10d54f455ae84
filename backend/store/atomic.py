"""Crash-safe file writes: a reader sees the old file or the new one, never half of one.

A write goes to a temp file beside its target, ``.<name>.<8 random chars>.tmp`` (``tempfile.mkstemp``),
which is renamed over the target. A write killed before the rename leaves that temp file;
:func:`remove_stale_temp_files` clears them when a store opens.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

TEMP_NAME = re.compile(r"\..+\.[a-z0-9_]{8}\.tmp")
"""The names :func:`write_bytes_atomic` gives its temp files (``mkstemp`` draws 8 of ``a-z0-9_``)."""
UPLOAD_FOLDER_PREFIX = ".upload-"
"""Folders inside a session that hold an upload while its request is read (``backend.api.uploads``); a server
killed meanwhile leaves one behind."""
STALE_TEMP_S = 600.0
"""A temp file untouched this long (s) belongs to a write that died: no live write takes that long."""


def write_bytes_atomic(path: Path, data: bytes, *, exclusive: bool = False) -> None:
    """Write ``data`` to ``path`` via a synced temp file and an atomic rename.

    With ``exclusive=True`` an existing ``path`` is never replaced
    (:class:`FileExistsError`), which is how captures stay write-once.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")  # matches TEMP_NAME
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            handle.flush()
            os.fsync(handle.fileno())
        if exclusive:
            os.link(tmp, path)  # fails if path exists, unlike rename
            os.unlink(tmp)
        else:
            os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def write_json_atomic(path: Path, data: Any, *, exclusive: bool = False) -> None:
    write_bytes_atomic(path, json.dumps(data, indent=1).encode(), exclusive=exclusive)


def remove_stale_temp_files(root: Path, older_than_s: float = STALE_TEMP_S) -> None:
    """Delete the temp files of killed writes and the upload folders of killed requests under ``root``: only
    names matching :data:`TEMP_NAME` or starting with :data:`UPLOAD_FOLDER_PREFIX`, last modified more than
    ``older_than_s`` seconds ago (a write or upload still running elsewhere keeps its file)."""
    now = time.time()
    for folder, subfolders, names in os.walk(root):
        for name in [n for n in subfolders if n.startswith(UPLOAD_FOLDER_PREFIX)]:
            subfolders.remove(name)
            path = Path(folder) / name
            with contextlib.suppress(FileNotFoundError):
                if now - path.stat().st_mtime > older_than_s:
                    shutil.rmtree(path, ignore_errors=True)
        for name in names:
            if not TEMP_NAME.fullmatch(name):
                continue
            path = Path(folder) / name
            try:
                if now - path.stat().st_mtime > older_than_s:
                    path.unlink()
            except FileNotFoundError:  # finished or cleaned by another process meanwhile
                continue
