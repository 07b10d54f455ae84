"""Reading, decoding and encoding images, with clear errors for files that are not images.

``cv2.imread`` returns ``None`` for anything it cannot read and, worse, happily
returns a partly grey image for a truncated JPEG. The functions here reject empty,
non-image and truncated files with an :class:`~backend.core.errors.InputError`
that names the file, so a folder reader, the API upload path and the CLI all
report the same thing.

Images are also refused above :data:`~backend.core.limits.MAX_IMAGE_PIXELS` before they are decoded: the
width and height come from the file's header (PNG IHDR, JPEG SOF, BMP, TIFF and PNM headers), so a small
file that would decode to gigabytes (a decompression bomb) costs nothing. A file whose header does not give
its size is refused as not an image of the expected formats.
"""

from __future__ import annotations

import re
import struct
from pathlib import Path

import cv2
import numpy as np

from backend.core.errors import InputError
from backend.core.limits import MAX_IMAGE_PIXELS

EXPECTED_FORMATS = "PNG/JPEG/BMP/TIFF/PGM/PPM"
"""The formats named in error messages."""

_JPEG_MAGIC = b"\xff\xd8\xff"
_JPEG_EOI = b"\xff\xd9"
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
_PNG_IEND_CHUNK = b"\x00\x00\x00\x00IEND\xaeB`\x82"
"""A complete IEND chunk: zero length, type, CRC."""
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
"""JPEG start-of-frame markers (every C0-CF but DHT C4, JPG C8 and DAC CC): they carry the image size."""
_JPEG_NO_LENGTH = {0x01, *range(0xD0, 0xD8)}
"""JPEG markers without a length field (TEM, RST0-7)."""
_PNM_HEADER = re.compile(rb"P[1-6](?:\s+|#[^\n]*\n)+(\d+)(?:\s+|#[^\n]*\n)+(\d+)")
"""A PBM/PGM/PPM header up to its height (whitespace and ``#`` comments between the fields)."""


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


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) in px read from an image file's header alone, or None when the header gives none.

    Reads PNG (IHDR), JPEG (the first SOF marker), BMP, TIFF (the first IFD's ImageWidth and ImageLength)
    and PBM/PGM/PPM headers; nothing is decoded.
    """
    try:
        if data.startswith(_PNG_MAGIC):
            return _png_size(data)
        if data.startswith(_JPEG_MAGIC):
            return _jpeg_size(data)
        if data.startswith(b"BM"):
            return _bmp_size(data)
        if data[:4] in (b"II*\x00", b"MM\x00*"):
            return _tiff_size(data)
        match = _PNM_HEADER.match(data[:1024])
        return (int(match[1]), int(match[2])) if match else None
    except struct.error:  # the header is cut short
        return None


def check_pixels(data: bytes, name: str, input: str | None = None) -> tuple[int, int]:
    """The image's (width, height) in px from its header; :class:`InputError` naming the file when the header
    gives no size (422) or the image has more pixels than :data:`MAX_IMAGE_PIXELS` allows (413)."""
    size = image_size(data)
    if size is None or min(size) <= 0:
        raise _unreadable(name, input or name)
    width, height = size
    if width * height > MAX_IMAGE_PIXELS.value():
        raise InputError(f"{name}: the image is {width}x{height} px ({width * height:,} px), more than "
                         f"{MAX_IMAGE_PIXELS.describe()}", input=input or name, status_code=413)
    return size


def _unreadable(name: str, input: str) -> InputError:
    return InputError(
        f"{name}: not a readable image (expected {EXPECTED_FORMATS}); the file may be truncated or not an image",
        input=input,
    )


def _png_size(data: bytes) -> tuple[int, int] | None:
    if data[12:16] != b"IHDR":
        return None
    return struct.unpack_from(">II", data, 16)


def _jpeg_size(data: bytes) -> tuple[int, int] | None:
    """Walk the JPEG's marker segments up to the first SOF (or give up at the scan, SOS)."""
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker in _JPEG_NO_LENGTH:
            i += 2
            continue
        if marker in _JPEG_SOF:
            height, width = struct.unpack_from(">HH", data, i + 5)
            return width, height
        if marker == 0xDA:
            return None
        i += 2 + struct.unpack_from(">H", data, i + 2)[0]
    return None


def _bmp_size(data: bytes) -> tuple[int, int]:
    """BITMAPCOREHEADER (12 bytes: 16-bit sizes) or a later header (signed 32-bit; negative height: top-down)."""
    (header,) = struct.unpack_from("<I", data, 14)
    width, height = struct.unpack_from("<hh" if header == 12 else "<ii", data, 18)
    return abs(width), abs(height)


def _tiff_size(data: bytes) -> tuple[int, int] | None:
    """ImageWidth (tag 256) and ImageLength (257) of the first IFD, SHORT or LONG."""
    order = "<" if data[:2] == b"II" else ">"
    (offset,) = struct.unpack_from(order + "I", data, 4)
    (count,) = struct.unpack_from(order + "H", data, offset)
    found = {}
    for entry in range(count):
        start = offset + 2 + 12 * entry
        tag, kind = struct.unpack_from(order + "HH", data, start)
        if tag in (256, 257) and kind in (3, 4):  # SHORT or LONG, left-justified in the value field
            found[tag] = struct.unpack_from(order + ("H" if kind == 3 else "I"), data, start + 8)[0]
    return (found[256], found[257]) if len(found) == 2 else None


def _decode(data: bytes, name: str, input: str, grayscale: bool) -> np.ndarray:
    """Check ``data`` is a complete image within the pixel limit and decode it; ``input`` is the error's input."""
    error = _unreadable(name, input)
    if not data or _is_truncated(data):
        raise error
    check_pixels(data, name, input)
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
