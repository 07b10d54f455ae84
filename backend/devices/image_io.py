"""Reading, decoding and encoding images, with clear errors for files that are not images.

``cv2.imread`` returns ``None`` for anything it cannot read and, worse, happily
returns a partly grey image for a truncated JPEG. The functions here reject empty,
non-image and truncated files with an :class:`~backend.core.errors.InputError`
that names the file, so a folder reader, the API upload path and the CLI all
report the same thing.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from backend.core.errors import InputError

EXPECTED_FORMATS = "PNG/JPEG/BMP/TIFF/PGM/PPM"
"""The formats named in error messages."""

_JPEG_MAGIC = b"\xff\xd8\xff"
_JPEG_EOI = b"\xff\xd9"
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_PNG_IEND_CHUNK = b"\x00\x00\x00\x00IEND\xaeB`\x82"
"""A complete IEND chunk: zero length, type, CRC."""


def read_image(path: Path, *, grayscale: bool = False) -> np.ndarray:
    """Read an image file as uint8 BGR (HxWx3) or, with ``grayscale``, gray (HxW).

    Raises :class:`InputError` naming the file if it cannot be read, is empty,
    is not an image or is a truncated JPEG/PNG.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path.name}: cannot read file ({exc.strerror or exc})", input=str(path)) from None
    return _decode(data, path.name, str(path), grayscale)


def decode_image_bytes(data: bytes, name: str, grayscale: bool = False) -> np.ndarray:
    """Decode an in-memory image (e.g. an upload) with the same checks as :func:`read_image`.

    ``name`` is the file name shown in the error message and stored as its ``input``.
    """
    return _decode(data, name, name, grayscale)


def encode_png(image: np.ndarray) -> bytes:
    """Encode a uint8 gray or BGR image as PNG bytes."""
    return _encode(".png", image, [])


def encode_jpeg(image: np.ndarray, quality: int = 90) -> bytes:
    """Encode a uint8 gray or BGR image as JPEG bytes with ``quality`` in 0..100."""
    return _encode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])


def _decode(data: bytes, name: str, input: str, grayscale: bool) -> np.ndarray:
    """Check ``data`` is a complete image and decode it; ``input`` is the error's input field."""
    error = InputError(
        f"{name}: not a readable image (expected {EXPECTED_FORMATS}); the file may be truncated or not an image",
        input=input,
    )
    if not data or _is_truncated(data):
        raise error
    flag = cv2.IMREAD_GRAYSCALE if grayscale else cv2.IMREAD_COLOR
    try:
        image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), flag)
    except cv2.error:
        raise error from None
    if image is None or image.size == 0:
        raise error
    return image


def _is_truncated(data: bytes) -> bool:
    """True for a JPEG without its end-of-image marker or a PNG without its IEND chunk."""
    if data.startswith(_JPEG_MAGIC):
        return not data.rstrip(b"\x00\r\n").endswith(_JPEG_EOI)
    if data.startswith(_PNG_MAGIC):
        return data.rfind(_PNG_IEND_CHUNK) < 0
    return False


def _encode(ext: str, image: np.ndarray, params: list[int]) -> bytes:
    ok, buffer = cv2.imencode(ext, image, params)
    if not ok:
        raise ValueError(f"could not encode a {image.dtype} image of shape {image.shape} as {ext}")
    return buffer.tobytes()
