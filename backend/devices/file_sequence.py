"""Replaying recorded files (images, point clouds) as a sensor, one file per read."""

from __future__ import annotations

import abc
import re
from pathlib import Path
from typing import ClassVar

from backend.core.errors import InputError
from backend.devices.base import CaptureDevice, DeviceDisconnected, DeviceError, Sample


def natural_key(name: str) -> list[tuple[int, int | str]]:
    """Sort key that orders embedded numbers by value: ``img2`` before ``img10``.

    Each part is tagged (0 for numbers, 1 for text) so numbers and text never compare directly.
    """
    return [(0, int(part)) if part.isdigit() else (1, part) for part in re.split(r"(\d+)", name.lower()) if part]


def stamped_files(folder: Path, extensions: tuple[str, ...], item: str, plural: str, input_name: str,
                  limit: int | None = None) -> list[tuple[int, Path]]:
    """``(stamp_ns, path)`` of the files in ``folder`` with one of ``extensions``, each named by its time stamp in
    ns (as EuRoC and Kalibr's bag extraction name them, ``1403715273262142976.png``), in time order.
    :class:`InputError` naming ``input_name`` for a missing or empty folder or more than ``limit`` files, or naming
    the file (an ``item``) whose name is not a time stamp."""
    if not folder.is_dir():
        raise InputError(f"{folder} is not a folder of {plural}", input_name)
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in extensions)
    if not files:
        raise InputError(f"{folder} holds no {plural} ({', '.join(extensions)})", input_name)
    if limit is not None and len(files) > limit:
        raise InputError(f"{folder} holds {len(files)} {plural}; one solve takes at most {limit}", input_name)
    bad = next((p for p in files if not p.stem.isdigit()), None)
    if bad is not None:
        raise InputError(f"{bad.name}: expected the {item}'s time stamp in ns as its name, e.g. "
                         f"1403715273262142976{extensions[0]}", str(bad))
    return sorted((int(p.stem), p) for p in files)


class FileSequence(CaptureDevice):
    """A folder of files (or one file) replayed in natural order, one per :meth:`read`.

    ``pattern`` is a glob relative to the folder; only files with one of
    :attr:`extensions` are used. With ``loop`` the sequence restarts instead of
    ending. Subclasses say what the files are and turn one file into a sample;
    a file that cannot be read raises :class:`~backend.core.errors.InputError`
    naming it, and the following ``read()`` continues with the next file.
    """

    extensions: ClassVar[tuple[str, ...]]
    noun: ClassVar[str]
    """What the files hold, plural, for messages: ``"images"``, ``"point clouds"``."""
    end_message: ClassVar[str]
    """Said at the end, formatted with ``count``: ``"end of folder after {count} images"``."""

    def __init__(self, path: str, pattern: str = "*", loop: bool = False):
        self.path = Path(path)
        self.pattern = pattern
        self.loop = loop
        self._files: list[Path] | None = None
        self._next = 0

    @abc.abstractmethod
    def load(self, file: Path, index: int) -> Sample:
        """Read one file as a sample; ``index`` is its position in the sequence."""

    @property
    def files(self) -> list[Path]:
        """The files in reading order (empty until opened)."""
        return list(self._files or [])

    def open(self) -> None:
        """List the files; raise :class:`DeviceError` if the path is missing or holds none."""
        expected = ", ".join(self.extensions)
        if self.path.is_file():
            if self.path.suffix.lower() not in self.extensions:
                raise DeviceError(f"{self.path.name} is not one of the {self.noun} expected ({expected})",
                                  str(self.path))
            files = [self.path]
        elif self.path.is_dir():
            files = [p for p in self.path.glob(self.pattern) if p.is_file() and p.suffix.lower() in self.extensions]
            if not files:
                raise DeviceError(f"folder {self.path} holds no {self.noun} matching {self.pattern!r} "
                                  f"(expected files ending in {expected})", str(self.path))
        else:
            raise DeviceError(f"folder {self.path} does not exist (expected a folder of {self.noun} or one file)",
                              str(self.path))
        self._files = sorted(files, key=lambda p: natural_key(p.name))
        self._next = 0

    def read(self) -> Sample:
        """Return the next file's sample; :class:`DeviceDisconnected` after the last (unless ``loop``)."""
        if self._files is None:
            raise DeviceError("not open; call open() first", str(self.path))
        if self._next >= len(self._files):
            if not self.loop:
                raise DeviceDisconnected(self.end_message.format(count=len(self._files)), str(self.path))
            self._next = 0
        index = self._next
        self._next += 1
        return self.load(self._files[index], index)

    def close(self) -> None:
        """Forget the file list; safe to call twice."""
        self._files = None

    def describe(self) -> str:
        count = f" ({len(self._files)} {self.noun})" if self._files is not None else ""
        return f"{self.driver} {self.path}{count}"
