"""A folder of image files replayed as a camera (driver ``"folder"``).

Files are read in natural order (``img2`` before ``img10``). A corrupt file does
not end the stream: :meth:`ImageFolder.read` raises
:class:`~backend.core.errors.InputError` naming the file and has already moved
past it, so the caller may skip it (or stop) and call ``read()`` again.
"""

from __future__ import annotations

import time
from pathlib import Path

from backend.core.errors import InputError
from backend.devices.base import Sample, register_driver
from backend.devices.file_sequence import FileSequence, natural_key
from backend.devices.image_io import read_image

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
"""File extensions treated as images (compared case-insensitively)."""


def image_files(folder: Path, label: str | None = None) -> list[Path]:
    """The images of ``folder`` in natural order; :class:`InputError` naming ``label`` (default the folder)
    when it is not a folder or holds no :data:`IMAGE_EXTENSIONS` file."""
    label = str(folder) if label is None else label
    if not folder.is_dir():
        raise InputError(f"{label} is not a folder of images", str(folder))
    files = sorted((p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTENSIONS),
                   key=lambda p: natural_key(p.name))
    if not files:
        raise InputError(f"{label} holds no images (expected {', '.join(IMAGE_EXTENSIONS)})", str(folder))
    return files


@register_driver
class ImageFolder(FileSequence):
    """Replays the image files of a folder, one per :meth:`read`.

    ``pattern`` is a glob relative to the folder (e.g. ``"left*"``); only files
    with an :data:`IMAGE_EXTENSIONS` extension are used. With ``loop`` the
    folder restarts from the first image instead of ending.

    Samples carry a BGR image, the read time as ``timestamp_s`` and meta
    ``{"source": file name, "frame_index": position of the file in the folder}``.
    """

    driver = "folder"
    extensions = IMAGE_EXTENSIONS
    noun = "images"
    end_message = "end of folder after {count} images"

    def load(self, file: Path, index: int) -> Sample:
        return Sample(timestamp_s=time.time(), image=read_image(file), meta={"source": file.name, "frame_index": index})
