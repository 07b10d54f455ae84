"""Depth images as samples: the one conversion every depth source shares, and a folder of depth images replayed
as a depth camera (driver ``"depth_files"``).

Every depth source (this folder reader, the ``kinect2`` and ``realsense`` drivers, depth topics of a ROS 2 bag)
ends in :func:`depth_sample`, so their samples look alike: ``depth`` (H, W) float32 metres along the optical axis
(0 = no return), ``points`` (N, 3) the valid pixels unprojected into the node frame (optical: X right, Y down,
Z out, m), ``intensity`` (N,) the IR amplitude of those pixels (or None), ``meta["intrinsics"]``
(:meth:`DepthIntrinsics.to_dict`, the pinhole that reproduces ``points`` from ``depth``) and
``meta["pixel_index"]`` (N,) the flat row-major pixel index of every point and ``meta["amplitude"]`` (H, W) the
whole amplitude image (numpy arrays, so not stored with a capture's meta): a Kinect v2 reports a saturated pixel (a
retroreflective cross) with amplitude 65535 but no depth, so the crosses show only in the whole image.

A source whose lens has distortion first resamples its image onto the undistorted pinhole grid
(:func:`undistort_depth`), so the stored depth image and its pinhole alone give back the same points.

The folder reader takes 16-bit PNG depth in millimetres or ``.npy`` depth in metres, with an optional amplitude
(IR) image beside each (same stem + ``_ir`` or ``_amplitude``, PNG or ``.npy``) and an intrinsics file: JSON with
the :class:`~backend.core.depth.DepthIntrinsics` fields (and optional ``dist``, the five OpenCV
``[k1, k2, p1, p2, k3]``) or a ROS camera_info YAML. Sizes are read from the file headers and checked against
:data:`~backend.core.limits.MAX_IMAGE_PIXELS` before anything is decoded; a bad file raises
:class:`~backend.core.errors.InputError` naming it (the next ``read()`` goes on with the next file).
"""

from __future__ import annotations

import functools
import json
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.depth import DepthIntrinsics
from backend.core.errors import InputError, shorten
from backend.core.limits import MAX_IMAGE_PIXELS
from backend.devices.base import DeviceError, Sample, register_driver
from backend.devices.file_sequence import FileSequence
from backend.devices.image_io import check_pixels
from backend.exports.ros_camera_info import load_camera_info
from backend.exports.text_file import read_text
from backend.exports.yaml_fields import YamlFields

DEPTH_EXTENSIONS = (".png", ".npy")
"""Depth image files: 16-bit PNG in millimetres, ``.npy`` (float) in metres."""
AMPLITUDE_SUFFIXES = ("_ir", "_amplitude")
"""Stem endings of the amplitude (IR) image beside a depth image, e.g. ``0001.png`` and ``0001_ir.png``."""
INTRINSICS_NAMES = ("intrinsics.json", "camera_info.yaml", "camera_info.yml")
"""Intrinsics files looked for in the folder when the ``intrinsics`` setting is not given, in this order."""
MM_PER_M = 1000.0

EDGE_JUMP_FRACTION = 0.03
"""Depth spread (max - min over a pixel's 3x3 neighbourhood, as a fraction of its depth) above which resampling
takes the nearest pixel rather than interpolating: interpolating across a table's edge would invent points in the
air between the table top and the floor."""

_INTRINSICS_EXPECTED = ("JSON with width, height (px), fx, fy, cx, cy (px), optional min_range_m, max_range_m (m) "
                        "and dist ([k1, k2, p1, p2, k3])")


# --------------------------------------------------------------------------------------------
# The conversion every depth source shares


def pinhole_of(camera: CameraIntrinsics, min_range_m: float, max_range_m: float) -> DepthIntrinsics:
    """The undistorted pinhole (K of ``camera``, px) of a depth camera, used between ``min_range_m`` and
    ``max_range_m`` (m)."""
    K = camera.K
    return DepthIntrinsics(camera.width, camera.height, float(K[0, 0]), float(K[1, 1]), float(K[0, 2]),
                           float(K[1, 2]), float(min_range_m), float(max_range_m))


def check_ranges(min_range_m: float, max_range_m: float, device: str) -> tuple[float, float]:
    """``(min_range_m, max_range_m)`` as floats; :class:`DeviceError` naming ``device`` unless
    ``0 <= min < max`` (m, finite)."""
    try:
        low, high = float(min_range_m), float(max_range_m)
    except (TypeError, ValueError):
        low = high = float("nan")
    if not (np.isfinite(low) and np.isfinite(high) and 0 <= low < high):
        raise DeviceError(f"min_range_m and max_range_m must be finite metres with 0 <= min < max, got "
                          f"{shorten(min_range_m)} and {shorten(max_range_m)}", device)
    return low, high


def _no_return_as_zero(depth_m: np.ndarray) -> np.ndarray:
    """``depth_m`` as contiguous float32 (m) with NaN, infinite and negative depths set to 0 (no return)."""
    depth = np.asarray(depth_m, dtype=np.float32)
    with np.errstate(invalid="ignore"):
        return np.ascontiguousarray(np.where(np.isfinite(depth) & (depth > 0), depth, np.float32(0)))


@functools.lru_cache(maxsize=16)
def _undistortion_maps(K: tuple[float, ...], dist: tuple[float, ...],
                       size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """For every pixel of the undistorted pinhole (K, px), where it lies in the distorted image (x and y maps,
    px), kept per camera: a live camera's every frame uses the same (read-only) maps."""
    K_matrix = np.array(K).reshape(3, 3)
    maps = cv2.initUndistortRectifyMap(K_matrix, np.array(dist), None, K_matrix, size, cv2.CV_32FC1)
    for image in maps:
        image.setflags(write=False)
    return maps


def undistort_depth(depth_m: np.ndarray, amplitude: np.ndarray | None,
                    camera: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray | None]:
    """``depth_m`` (H, W, m along the optical axis; 0, NaN or negative = no return) and ``amplitude`` (H, W or
    None) of a camera with lens distortion, resampled onto the undistorted pinhole with the same K (px): what
    :func:`pinhole_of` describes. Without distortion both come back unchanged.

    Depth along the optical axis does not change when a pixel moves, so resampling is exact up to the
    interpolation: bilinear on smooth surfaces, the nearest pixel where a neighbour has no return or the depth
    jumps by more than :data:`EDGE_JUMP_FRACTION` (edges: no invented points between surfaces). OpenCV's
    ``initUndistortRectifyMap`` gives, for every output pixel, where it lies in the distorted image.
    """
    if camera.model != "pinhole-radtan":
        raise InputError(f"depth with a {camera.model} lens is not supported; expected pinhole-radtan", "intrinsics")
    if not np.any(camera.dist):
        return depth_m, amplitude
    depth = _no_return_as_zero(depth_m)
    map_x, map_y = _undistortion_maps(tuple(camera.K.ravel()), tuple(camera.dist), camera.image_size)

    def remap(image: np.ndarray, interpolation: int) -> np.ndarray:
        return cv2.remap(image, map_x, map_y, interpolation, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    kernel = np.ones((3, 3), np.uint8)
    low = remap(cv2.erode(depth, kernel, borderType=cv2.BORDER_REPLICATE), cv2.INTER_NEAREST)
    high = remap(cv2.dilate(depth, kernel, borderType=cv2.BORDER_REPLICATE), cv2.INTER_NEAREST)
    # Replicated borders: the last row and column interpolate too; beyond the image the nearest remap gives 0.
    linear = cv2.remap(depth, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    smooth = (low > 0) & (high - low <= EDGE_JUMP_FRACTION * linear)
    nearest = remap(depth, cv2.INTER_NEAREST)
    undistorted = np.where(smooth & (nearest > 0), linear, nearest).astype(np.float32)
    if amplitude is None:
        return undistorted, None
    return undistorted, remap(np.ascontiguousarray(amplitude, dtype=np.float32), cv2.INTER_LINEAR)


def depth_sample(depth_m: np.ndarray, intrinsics: DepthIntrinsics, timestamp_s: float, source: str,
                 amplitude: np.ndarray | None = None, meta: dict[str, Any] | None = None) -> Sample:
    """The depth :class:`Sample` of an undistorted depth image (H, W, m along the optical axis).

    NaN, infinite and negative depths become 0 (no return); pixels outside the intrinsics' range are kept in
    ``depth`` but not unprojected. ``amplitude`` (H, W, the sensor's units) gives the points' ``intensity``.
    ``meta`` is extended with ``intrinsics``, ``pixel_index`` and ``amplitude`` (see the module docs). Raises
    :class:`InputError` naming ``source`` when a size does not match the intrinsics or no pixel has a depth
    within range (an empty or covered view).
    """
    depth = np.asarray(depth_m, dtype=np.float32)
    size = f"{intrinsics.width}x{intrinsics.height}"
    if depth.shape != (intrinsics.height, intrinsics.width):
        found = f"{depth.shape[1]}x{depth.shape[0]}" if depth.ndim == 2 else f"of shape {depth.shape}"
        raise InputError(f"{source}: the depth image is {found} px; its intrinsics say {size}", source)
    depth = _no_return_as_zero(depth)
    points, index = intrinsics.unproject(depth)
    if len(index) == 0:
        raise InputError(f"{source}: no pixel of the {size} depth image lies within {intrinsics.min_range_m:g} to "
                         f"{intrinsics.max_range_m:g} m (an empty, covered or out-of-range view)", source)
    intensity = None
    if amplitude is not None:
        amplitude = np.asarray(amplitude, dtype=np.float32)
        if amplitude.shape != depth.shape:
            raise InputError(f"{source}: the amplitude image has shape {amplitude.shape}; the depth image "
                             f"{depth.shape}", source)
        intensity = amplitude.ravel()[index]
    meta = {**(meta or {}), "intrinsics": intrinsics.to_dict(), "pixel_index": index}
    if amplitude is not None:
        meta["amplitude"] = amplitude
    return Sample(timestamp_s=timestamp_s, depth=depth, points=points, intensity=intensity, meta=meta)


# --------------------------------------------------------------------------------------------
# Depth image and intrinsics files


def _npy_header(path: Path) -> tuple[tuple[int, ...], np.dtype] | None:
    """Shape and dtype an .npy file declares, from its header alone (None when it cannot be read)."""
    readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    try:
        with path.open("rb") as handle:
            shape, _, dtype = readers[np.lib.format.read_magic(handle)](handle)
    except Exception:  # not an .npy, an unknown version, a header cut short...
        return None
    return tuple(shape), dtype


def _read_npy_image(path: Path, expected: str, kinds: str) -> np.ndarray:
    """A 2-D .npy array whose dtype kind is in ``kinds``, its pixels checked from the header before loading."""
    header = _npy_header(path)
    if header is None:
        raise InputError(f"{path.name}: not a readable .npy file (truncated or not NumPy); expected {expected}",
                         str(path))
    shape, dtype = header
    if len(shape) != 2 or dtype.names or dtype.kind not in kinds:
        raise InputError(f"{path.name}: an array of shape {shape} and dtype {dtype}; expected {expected}", str(path))
    if shape[0] * shape[1] > MAX_IMAGE_PIXELS.value():
        raise InputError(f"{path.name}: the image is {shape[1]}x{shape[0]} px, more than "
                         f"{MAX_IMAGE_PIXELS.describe()}", str(path), 413)
    try:
        return np.load(path, allow_pickle=False)
    except Exception as exc:  # data cut short
        raise InputError(f"{path.name}: cannot be read ({shorten(str(exc))}); expected {expected}",
                         str(path)) from None


def _read_png(path: Path, expected: str) -> np.ndarray:
    """The pixels of a PNG at full depth (uint8 or uint16), its size checked from the header before decoding."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path.name}: cannot read the file ({exc.strerror or exc})", str(path)) from None
    if not data.startswith(b"\x89PNG\r\n\x1a\n"):
        raise InputError(f"{path.name}: not a PNG file; expected {expected}", str(path))
    check_pixels(data, path.name, str(path))
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise InputError(f"{path.name}: the PNG cannot be decoded (truncated?); expected {expected}", str(path))
    return image


def read_depth_image(path: Path | str) -> np.ndarray:
    """Depth (H, W) float32 in metres from a 16-bit PNG in millimetres or a float ``.npy`` in metres."""
    path = Path(path)
    if path.suffix.lower() == ".npy":
        return _read_npy_image(path, "an (H, W) float array of depth in metres", "f").astype(np.float32)
    expected = "a single-channel 16-bit PNG of depth in millimetres"
    image = _read_png(path, expected)
    if image.dtype != np.uint16 or image.ndim != 2:
        channels = 1 if image.ndim == 2 else image.shape[2]
        raise InputError(f"{path.name}: a {8 * image.dtype.itemsize}-bit PNG with {channels} channel(s); expected "
                         f"{expected}", str(path))
    return (image.astype(np.float32) / np.float32(MM_PER_M)).astype(np.float32)


def read_amplitude_image(path: Path | str) -> np.ndarray:
    """Amplitude (IR) image (H, W) float32 in the sensor's units from an 8/16-bit gray PNG or a numeric .npy."""
    path = Path(path)
    expected = "a single-channel PNG or an (H, W) numeric .npy of IR amplitude"
    if path.suffix.lower() == ".npy":
        return _read_npy_image(path, expected, "fiu").astype(np.float32)
    image = _read_png(path, expected)
    if image.ndim != 2:
        raise InputError(f"{path.name}: a PNG with {image.shape[2]} channels; expected {expected}", str(path))
    return image.astype(np.float32)


def load_depth_camera(path: Path | str) -> tuple[CameraIntrinsics, tuple[float, float] | None]:
    """The depth camera in an intrinsics file and its range ``(min_range_m, max_range_m)`` if the file gives one.

    ``.json``: the :class:`DepthIntrinsics` fields and optional ``dist``; ``.yaml``/``.yml``: a ROS camera_info
    (read by :func:`~backend.exports.ros_camera_info.load_camera_info`, plumb_bob). Problems raise
    :class:`InputError` naming the file and the field.
    """
    path = Path(path)
    if path.suffix.lower() in (".yaml", ".yml"):
        camera, _ = load_camera_info(path)
        return camera, None
    if path.suffix.lower() != ".json":
        raise InputError(f"{path}: unknown intrinsics file type; expected .json ({_INTRINSICS_EXPECTED}) or a ROS "
                         "camera_info .yaml", str(path))
    try:
        document = json.loads(read_text(path, _INTRINSICS_EXPECTED))
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON (line {exc.lineno}: {exc.msg}); expected {_INTRINSICS_EXPECTED}",
                         str(path)) from None
    fields = YamlFields(str(path))
    document = fields.mapping(document, "(document)", _INTRINSICS_EXPECTED)
    values = {}
    for key in ("width", "height", "fx", "fy", "cx", "cy"):
        values[key] = fields.number(fields.get(document, key, key, "a number (px)"), key)
    for key in ("width", "height", "fx", "fy"):
        if values[key] <= 0 or (key in ("width", "height") and not float(values[key]).is_integer()):
            raise fields.error(key, f"is {shorten(document[key])}", "a positive " +
                               ("integer (px)" if key in ("width", "height") else "number (px)"))
    dist = document.get("dist", [0.0] * 5)
    if not isinstance(dist, list) or len(dist) != 5:
        raise fields.error("dist", f"is {shorten(dist)}", "five numbers [k1, k2, p1, p2, k3]")
    dist = [fields.number(value, f"dist[{i}]") for i, value in enumerate(dist)]
    ranges = None
    if "min_range_m" in document or "max_range_m" in document:
        low = fields.number(document.get("min_range_m", DepthIntrinsics.min_range_m), "min_range_m")
        high = fields.number(document.get("max_range_m", DepthIntrinsics.max_range_m), "max_range_m")
        if not 0 <= low < high:
            raise fields.error("max_range_m", f"is {high} with min_range_m {low}", "metres with 0 <= min < max")
        ranges = (low, high)
    K = np.array([[values["fx"], 0, values["cx"]], [0, values["fy"], values["cy"]], [0, 0, 1]])
    return CameraIntrinsics("pinhole-radtan", int(values["width"]), int(values["height"]), K, dist), ranges


def amplitude_file(depth_file: Path) -> Path | None:
    """The amplitude image beside ``depth_file`` (same stem + an :data:`AMPLITUDE_SUFFIXES` ending, PNG or .npy),
    or None."""
    for suffix in AMPLITUDE_SUFFIXES:
        for extension in DEPTH_EXTENSIONS:
            candidate = depth_file.with_name(depth_file.stem + suffix + extension)
            if candidate.is_file():
                return candidate
    return None


@register_driver
class DepthFiles(FileSequence):
    """Replays a folder of depth images (see the module docs), one per :meth:`read`, as a depth camera.

    ``intrinsics`` is the intrinsics file (relative paths inside the folder); without it the folder's
    ``intrinsics.json`` or ``camera_info.yaml`` is used. ``min_range_m`` / ``max_range_m`` (m) override the range
    the file gives (default 0.5 to 9 m). Samples are :func:`depth_sample` s with the read time as
    ``timestamp_s`` and meta ``source`` (the depth file's name), ``amplitude_source`` (or None) and
    ``frame_index``.
    """

    driver = "depth_files"
    extensions = DEPTH_EXTENSIONS
    noun = "depth images"
    end_message = "end of folder after {count} depth images"

    def __init__(self, path: str, intrinsics: str | None = None, pattern: str = "*", loop: bool = False,
                 min_range_m: float | None = None, max_range_m: float | None = None):
        super().__init__(path, pattern, loop)
        self.intrinsics_path = None if intrinsics is None else Path(intrinsics)
        self.min_range_m, self.max_range_m = min_range_m, max_range_m
        if min_range_m is not None or max_range_m is not None:
            check_ranges(*self._ranges(None), str(path))
        self.camera: CameraIntrinsics | None = None
        """The depth camera as the intrinsics file gives it, distortion included (known once open)."""
        self.pinhole: DepthIntrinsics | None = None
        """The undistorted pinhole of the samples (known once open)."""

    def _intrinsics_file(self) -> Path:
        folder = self.path if self.path.is_dir() else self.path.parent
        if self.intrinsics_path is not None:
            return self.intrinsics_path if self.intrinsics_path.is_absolute() else folder / self.intrinsics_path
        for name in INTRINSICS_NAMES:
            if (folder / name).is_file():
                return folder / name
        raise DeviceError(f"no intrinsics file: expected one of {', '.join(INTRINSICS_NAMES)} in {folder}, or the "
                          "intrinsics setting naming one", str(self.path))

    def open(self) -> None:
        """List the depth images (amplitude images beside them are not replayed themselves) and read the
        intrinsics; :class:`DeviceError` saying what is missing or wrong."""
        super().open()
        self._files = [f for f in self.files if not is_amplitude_file(f)]
        if not self._files:
            raise DeviceError(f"{self.path} holds amplitude images but no depth images", str(self.path))
        try:
            camera, ranges = load_depth_camera(self._intrinsics_file())
        except InputError as exc:
            self._files = None
            raise DeviceError(exc.message, exc.input or str(self.path)) from None
        self.camera = camera
        self.pinhole = pinhole_of(camera, *check_ranges(*self._ranges(ranges), str(self.path)))

    def _ranges(self, from_file: tuple[float, float] | None) -> tuple[float, float]:
        """The settings' range where given, else the intrinsics file's, else :class:`DepthIntrinsics`' (m)."""
        low, high = from_file or (DepthIntrinsics.min_range_m, DepthIntrinsics.max_range_m)
        return (low if self.min_range_m is None else self.min_range_m,
                high if self.max_range_m is None else self.max_range_m)

    def load(self, file: Path, index: int) -> Sample:
        assert self.camera is not None and self.pinhole is not None  # set by open()
        depth = read_depth_image(file)
        amplitude_path = amplitude_file(file)
        amplitude = None if amplitude_path is None else read_amplitude_image(amplitude_path)
        if amplitude is not None and amplitude.shape != depth.shape:
            raise InputError(f"{amplitude_path.name}: {amplitude.shape[1]}x{amplitude.shape[0]} px, but its depth "
                             f"image {file.name} is {depth.shape[1]}x{depth.shape[0]} px", str(amplitude_path))
        if depth.shape != (self.camera.height, self.camera.width):
            raise InputError(f"{file.name}: the depth image is {depth.shape[1]}x{depth.shape[0]} px; the intrinsics "
                             f"say {self.camera.width}x{self.camera.height}", str(file))
        depth, amplitude = undistort_depth(depth, amplitude, self.camera)
        meta = {"source": file.name, "amplitude_source": amplitude_path.name if amplitude_path else None,
                "frame_index": index}
        return depth_sample(depth, self.pinhole, time.time(), file.name, amplitude, meta)

    def describe(self) -> str:
        size = f" {self.camera.width}x{self.camera.height}" if self.camera is not None else ""
        return super().describe() + size


def is_amplitude_file(path: Path) -> bool:
    """Whether ``path`` is an amplitude image: its stem ends in an :data:`AMPLITUDE_SUFFIXES` ending."""
    return any(path.stem.endswith(suffix) and len(path.stem) > len(suffix) for suffix in AMPLITUDE_SUFFIXES)
