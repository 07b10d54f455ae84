"""A folder of image files replayed as a camera (driver ``"folder"``).

Files are read in natural order (``img2`` before ``img10``). A corrupt file does
not end the stream: :meth:`ImageFolder.read` raises
:class:`~backend.core.errors.InputError` naming the file and has already moved
past it, so the caller may skip it (or stop) and call ``read()`` again.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

from backend.devices.base import CaptureDevice, DeviceDisconnected, DeviceError, Sample, register_driver
from backend.devices.image_io import read_image

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
"""File extensions treated as images (compared case-insensitively)."""


def natural_key(name: str) -> list[tuple[int, int | str]]:
    """Sort key ordering digit runs by value, so ``"img2"`` sorts before ``"img10"``.

    Each part is tagged (0 for numbers, 1 for text) so numbers and text never compare directly.
    """
    return [(0, int(part)) if part.isdigit() else (1, part) for part in re.split(r"(\d+)", name.lower()) if part]


@register_driver
class ImageFolder(CaptureDevice):
    """Replays the image files of a folder, one per :meth:`read`.

    ``pattern`` is a glob relative to the folder (e.g. ``"left*"``); only files
    with an :data:`IMAGE_EXTENSIONS` extension are used. With ``loop`` the
    folder restarts from the first image instead of ending.

    Samples carry a BGR image, the read time as ``timestamp_s`` and meta
    ``{"source": file name, "frame_index": position of the file in the folder}``.
    """

    driver = "folder"

    def __init__(self, path: str, pattern: str = "*", loop: bool = False):
        self.path = Path(path)
        self.pattern = pattern
        self.loop = loop
        self._files: list[Path] | None = None
        self._next = 0

    @property
    def files(self) -> list[Path]:
        """The image files in reading order (empty until opened)."""
        return list(self._files or [])

    def open(self) -> None:
        """List the images; raise :class:`DeviceError` if the folder is missing or has none."""
        if not self.path.is_dir():
            raise DeviceError(f"folder {self.path} does not exist", str(self.path))
        files = [p for p in self.path.glob(self.pattern) if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS]
        if not files:
            raise DeviceError(
                f"folder {self.path} holds no images matching {self.pattern!r} "
                f"(expected files ending in {', '.join(IMAGE_EXTENSIONS)})",
                str(self.path),
            )
        self._files = sorted(files, key=lambda p: natural_key(p.name))
        self._next = 0

    def read(self) -> Sample:
        """Return the next image.

        Raises :class:`DeviceDisconnected` after the last image (unless ``loop``)
        and :class:`~backend.core.errors.InputError` naming a file that is not a
        readable image; the following ``read()`` continues with the next file.
        """
        if self._files is None:
            raise DeviceError("not open; call open() first", str(self.path))
        if self._next >= len(self._files):
            if not self.loop:
                raise DeviceDisconnected(f"end of folder after {len(self._files)} images", str(self.path))
            self._next = 0
        index = self._next
        self._next += 1
        file = self._files[index]
        image = read_image(file)
        return Sample(timestamp_s=time.time(), image=image, meta={"source": file.name, "frame_index": index})

    def close(self) -> None:
        """Forget the file list; safe to call twice."""
        self._files = None

    def describe(self) -> str:
        count = f" ({len(self._files)} images)" if self._files is not None else ""
        return f"{self.driver} {self.path}{count}"
