"""The wire format of a node agent's frames: quantised arrays, zlib-compressed, behind a header that states sizes.

A frame is ``PREAMBLE`` (magic ``CSNF``, version, kind, header length) + a JSON header + the zlib streams of its
arrays, one after the other. The header states every array's dtype, shape, raw and compressed size, so
:func:`decode_frame` refuses a frame over its limits (points, pixels) or whose sizes disagree *before* it
decompresses anything, and then inflates each array with ``zlib.decompressobj(...).decompress(max_length=)``:
a small frame that would inflate to gigabytes (a zlib bomb) costs nothing.

Kinds and their quantisation (what the frame loses):

- ``cloud`` (a LiDAR, or a depth camera's voxelised stream): points as integer steps from the cloud's minimum
  corner (1 mm when voxelised, 0.1 mm in a full frame), axis by axis, as zigzag-coded differences from point to
  point in the smallest unsigned type, bytes shuffled; intensity as float16 (3 significant digits; 4 mantissa
  bits, within 3 %, in the stream).
- ``depth`` (a depth camera's full frame): depth as uint16 mm (0 = no return; depth beyond 65.5 m dropped) coded
  as differences along each row, IR amplitude as a float16 image, the valid pixels as a packed bit mask. The
  points are unprojected again on decoding with the frame's intrinsics (``meta["intrinsics"]``, else the Kinect
  v2's for a 512x424 image); a depth image of unknown intrinsics carries its points as in ``cloud``.
- ``image`` (a camera): PNG (lossless) in a full frame, JPEG (quality 85) in the stream.

Only the JSON-friendly part of ``Sample.meta`` travels (:meth:`Sample.storable_meta`); a decoded depth frame's
meta gets ``pixel_index`` (N,) and ``amplitude`` (H, W) back as arrays.
"""

from __future__ import annotations

import json
import math
import struct
import zlib
from dataclasses import dataclass
from typing import Any

import numpy as np

from backend.core.depth import KINECT_V2, DepthIntrinsics
from backend.core.errors import InputError, shorten
from backend.core.limits import MAX_CLOUD_POINTS, MAX_IMAGE_PIXELS
from backend.core.voxels import voxel_downsample
from backend.devices.base import Sample
from backend.devices.image_io import decode_image_bytes, encode_jpeg, encode_png

MAGIC = b"CSNF"
"""Calibration Studio node frame."""
VERSION = 1
PREAMBLE = struct.Struct("<4sBBI")
"""magic, version, kind code, JSON header length (bytes)."""
KINDS = ("cloud", "depth", "image")
MAX_HEADER_BYTES = 1_000_000
"""Largest JSON header a frame may have (meta included)."""
STREAM_POINT_STEP_M = 0.001
"""Quantisation step (m) of a voxelised frame's points."""
FULL_POINT_STEP_M = 0.0001
"""Quantisation step (m) of a full frame's points (LiDAR captures)."""
DEPTH_STEP_M = 0.001
"""Quantisation step (m) of a depth image: uint16 millimetres."""
JPEG_QUALITY = 85
"""JPEG quality of a camera's streamed (previewed) images; captures are PNG."""
ZLIB_LEVEL = 1
"""zlib level: on a Kinect frame after the delta and shuffle filters, level 6 takes 1.6x the time of level 1 for
frames 2-3 % smaller."""
STREAM_INTENSITY_BITS = 4
"""Mantissa bits a streamed frame keeps of each intensity (of float16's 10): within 3 %, enough to shade a preview
and a third of the bytes of the full value."""

_DTYPES = {"uint8", "uint16", "uint32", "uint64", "float16", "float32"}
_FILTERS = {"delta", "shuffle"}
_ARRAYS = {"cloud": {"points", "intensity"}, "depth": {"depth", "amplitude", "valid", "points"},
           "image": {"image"}}
"""The arrays each kind may carry."""


@dataclass
class _Array:
    """One array of a frame as it is stored (after its filters), and what the header says of it."""

    name: str
    data: np.ndarray
    extra: dict[str, Any]
    filters: tuple[str, ...] = ()
    """``delta``: the values are zigzag-coded differences along the last axis (undone by a cumulative sum);
    ``shuffle``: the bytes are stored plane by plane (all low bytes, then the high bytes), as Blosc and HDF5 do,
    which lets zlib find the slowly varying high bytes."""

    def stored_bytes(self) -> bytes:
        if "shuffle" not in self.filters:
            return self.data.tobytes()
        return np.ascontiguousarray(self.data).reshape(-1).view(np.uint8).reshape(-1, self.data.itemsize).T.tobytes()

    def header(self, compressed: bytes) -> dict[str, Any]:
        return {"name": self.name, "dtype": str(self.data.dtype), "shape": list(self.data.shape),
                "raw_bytes": int(self.data.nbytes), "zlib_bytes": len(compressed), "filters": list(self.filters),
                **self.extra}


def _delta(values: np.ndarray) -> np.ndarray:
    """Zigzag-coded differences along the last axis of integer ``values`` (small for smooth data), in the
    smallest unsigned type that holds them."""
    diff = np.diff(values.astype(np.int64), axis=-1, prepend=0)
    zigzag = (diff << 1) ^ (diff >> 63)
    top = int(zigzag.max()) if zigzag.size else 0
    return zigzag.astype(np.uint16 if top < 2**16 else np.uint32 if top < 2**32 else np.uint64)


def _undelta(zigzag: np.ndarray) -> np.ndarray:
    """The int64 values :func:`_delta` coded."""
    z = zigzag.astype(np.int64)
    return np.cumsum((z >> 1) ^ -(z & 1), axis=-1)


def _unfilter(raw: bytes, spec: dict[str, Any]) -> np.ndarray:
    """An array of a frame from its inflated bytes and its header spec (filters undone)."""
    dtype = np.dtype(spec["dtype"])
    data = np.frombuffer(raw, np.uint8)
    if "shuffle" in spec.get("filters", ()):
        data = data.reshape(dtype.itemsize, -1).T.copy()
    values = data.view(dtype).reshape(spec["shape"])
    return _undelta(values) if "delta" in spec.get("filters", ()) else values


def encode_frame(sample: Sample, voxel_m: float | None) -> bytes:
    """The bytes of one frame of ``sample``: its full resolution when ``voxel_m`` is None (a capture), else its
    cloud voxel-downsampled to ``voxel_m`` (m; one centroid per voxel) for the live stream.

    A depth image (``sample.depth``) travels as itself in a full frame, as its voxelised cloud in the stream;
    a camera image as PNG (full) or JPEG (stream); a LiDAR's points as they are (full) or voxelised.
    """
    full = voxel_m is None
    level = ZLIB_LEVEL
    meta = sample.storable_meta()
    if sample.depth is not None and full:
        kind, arrays = "depth", _depth_arrays(sample, meta)
    elif sample.points is not None or sample.depth is not None:
        kind = "cloud"
        points, intensity = _valid_cloud(sample)
        if not full:
            if not voxel_m > 0:
                raise InputError(f"voxel size {voxel_m!r} m: expected a positive number of metres", "voxel_m")
            points, intensity = voxel_downsample(points, intensity, float(voxel_m))
            meta["voxel_m"] = float(voxel_m)
        arrays = _cloud_arrays(points, intensity, FULL_POINT_STEP_M if full else STREAM_POINT_STEP_M,
                               None if full else STREAM_INTENSITY_BITS)
    elif sample.image is not None:
        kind = "image"
        encoded = encode_png(sample.image) if full else encode_jpeg(sample.image, JPEG_QUALITY)
        arrays = [_Array("image", np.frombuffer(encoded, np.uint8), {"format": "png" if full else "jpeg"})]
        level = 0  # already compressed
    else:
        raise InputError("the sample holds no depth, points or image to send", "sample")
    compressed = [zlib.compress(a.stored_bytes(), level) for a in arrays]
    header = json.dumps({"timestamp_s": float(sample.timestamp_s), "meta": meta,
                         "arrays": [a.header(c) for a, c in zip(arrays, compressed, strict=True)]},
                        separators=(",", ":")).encode()
    if len(header) > MAX_HEADER_BYTES:
        raise InputError(f"the sample's meta makes a {len(header):,}-byte header; at most {MAX_HEADER_BYTES:,}",
                         "meta")
    return b"".join([PREAMBLE.pack(MAGIC, VERSION, KINDS.index(kind), len(header)), header, *compressed])


def decode_frame(data: bytes, max_points: int | None = None, max_pixels: int | None = None,
                 source: str = "frame") -> Sample:
    """The :class:`Sample` a frame of :func:`encode_frame` holds (points in the sensor frame, m).

    Refuses, with an :class:`InputError` naming ``source`` (e.g. ``"frame from sn3"``), a frame that is not one,
    of another version, whose header's sizes disagree with its bytes, or that holds more than ``max_points``
    points (default :data:`MAX_CLOUD_POINTS`) or an image of more than ``max_pixels`` (default
    :data:`MAX_IMAGE_PIXELS`), all before decompressing.
    """
    max_points = MAX_CLOUD_POINTS.value() if max_points is None else max_points
    max_pixels = MAX_IMAGE_PIXELS.value() if max_pixels is None else max_pixels
    kind, header, body = _read_header(bytes(data), source)
    arrays = _check_arrays(kind, header, len(body), max_points, max_pixels, source)
    values: dict[str, np.ndarray] = {}
    offset = 0
    for spec in arrays:
        raw = _inflate(body[offset:offset + spec["zlib_bytes"]], spec["raw_bytes"], spec["name"], source)
        offset += spec["zlib_bytes"]
        values[spec["name"]] = _unfilter(raw, spec)
    meta = dict(header.get("meta") or {})
    timestamp_s = float(header.get("timestamp_s", 0.0))
    specs = {spec["name"]: spec for spec in arrays}
    if kind == "image":
        image = decode_image_bytes(values["image"].tobytes(), source)
        return Sample(timestamp_s, image=image, meta=meta)
    if kind == "cloud":
        points = _dequantise(values["points"], specs["points"], source)
        intensity = values["intensity"].astype(np.float32) if "intensity" in values else None
        return Sample(timestamp_s, points=points, intensity=intensity, meta=meta)
    return _depth_sample(timestamp_s, values, specs, meta, source)


def _valid_cloud(sample: Sample) -> tuple[np.ndarray, np.ndarray | None]:
    """The sample's points (N, 3, m) and intensity (N,), unprojected from its depth image if it has no points."""
    if sample.points is not None:
        points = np.asarray(sample.points, dtype=float).reshape(-1, 3)
        intensity = None if sample.intensity is None else np.asarray(sample.intensity, dtype=np.float32).ravel()
        if intensity is not None and len(intensity) != len(points):
            raise InputError(f"{len(intensity)} intensities for {len(points)} points", "intensity")
        keep = np.isfinite(points).all(axis=1)
        return points[keep], None if intensity is None else intensity[keep]
    points, _ = _intrinsics(sample.depth, sample.meta).unproject(sample.depth)
    return points, None


def _intrinsics(depth: np.ndarray, meta: dict[str, Any]) -> DepthIntrinsics:
    """The depth image's pinhole: ``meta["intrinsics"]``, else the Kinect v2's for a 512x424 image."""
    if isinstance(meta.get("intrinsics"), dict):
        try:
            return DepthIntrinsics.from_dict(meta["intrinsics"])
        except (KeyError, TypeError, ValueError):
            raise InputError(f"intrinsics {shorten(meta['intrinsics'])}: expected width, height, fx, fy, cx, cy",
                             "meta.intrinsics") from None
    if depth.shape == (KINECT_V2.height, KINECT_V2.width):
        return KINECT_V2
    raise InputError(f"a {depth.shape[1]}x{depth.shape[0]} depth image without meta['intrinsics']: "
                     "cannot unproject it", "meta.intrinsics")


def frame_intrinsics(depth: np.ndarray, meta: dict[str, Any]) -> DepthIntrinsics | None:
    """The pinhole a depth frame is unprojected with (``meta["intrinsics"]``, else the Kinect v2's for a 512x424
    image), or None when neither applies (the frame then carries its points)."""
    try:
        return _intrinsics(depth, meta)
    except InputError:
        return None


def _depth_arrays(sample: Sample, meta: dict[str, Any]) -> list[_Array]:
    """A full depth frame: uint16 mm depth, float16 amplitude image, bit mask of the sample's valid pixels."""
    depth = np.asarray(sample.depth, dtype=np.float32)
    if depth.ndim != 2:
        raise InputError(f"depth image of shape {depth.shape}: expected (H, W)", "depth")
    flat_index = _pixel_index(sample, depth)
    valid = np.zeros(depth.size, bool)
    valid[flat_index] = True
    amplitude = np.zeros(depth.size, np.float32)
    if isinstance(sample.meta.get("amplitude"), np.ndarray) and sample.meta["amplitude"].size == depth.size:
        amplitude = np.asarray(sample.meta["amplitude"], np.float32).ravel()
    elif sample.intensity is not None and len(sample.intensity) == len(flat_index):
        amplitude[flat_index] = sample.intensity
    with np.errstate(invalid="ignore"):
        millimetres = np.where(np.isfinite(depth) & (depth > 0) & (depth < 65.535), np.rint(depth / DEPTH_STEP_M), 0)
    arrays = [_Array("depth", _delta(millimetres), {"step_m": DEPTH_STEP_M},
                     ("delta", "shuffle")),
              _Array("amplitude", amplitude.astype(np.float16).reshape(depth.shape), {}, ("shuffle",)),
              _Array("valid", np.packbits(valid), {"pixels": int(depth.size)})]
    intrinsics = frame_intrinsics(depth, sample.meta)
    if intrinsics is None:
        if sample.points is None or len(sample.points) != len(flat_index):
            raise InputError("a depth image of unknown intrinsics needs its points, one per valid pixel", "points")
        arrays += _cloud_arrays(np.asarray(sample.points, float)[np.argsort(flat_index)], None, FULL_POINT_STEP_M)
    else:
        meta["intrinsics"] = intrinsics.to_dict()
    return arrays


def _pixel_index(sample: Sample, depth: np.ndarray) -> np.ndarray:
    """The flat (row-major) pixel of each of the sample's points: ``meta["pixel_index"]``, else every pixel with
    a return (depth > 0)."""
    index = sample.meta.get("pixel_index")
    if index is None:
        return np.flatnonzero(np.nan_to_num(depth.ravel()) > 0)
    index = np.asarray(index).ravel()
    if index.size and (index.min() < 0 or index.max() >= depth.size):
        raise InputError(f"pixel_index outside the {depth.shape[1]}x{depth.shape[0]} image", "meta.pixel_index")
    return index.astype(np.int64)


def _cloud_arrays(points: np.ndarray, intensity: np.ndarray | None, step_m: float,
                  intensity_bits: int | None = None) -> list[_Array]:
    """Points as integer steps of ``step_m`` from their minimum corner, one axis after the other, coded as
    differences from point to point (neighbours in a scan or a voxel grid's order are near: small differences),
    and intensity as float16, rounded to ``intensity_bits`` mantissa bits when given."""
    origin = np.floor(points.min(axis=0) / step_m) * step_m if len(points) else np.zeros(3)
    steps = np.rint((points - origin) / step_m)
    top = float(steps.max()) if len(points) else 0.0
    if top >= 2**32:
        raise InputError(f"the cloud spans {top * step_m:.0f} m: more than {2**32 * step_m:.0f} m", "points")
    arrays = [_Array("points", _delta(steps.T.astype(np.int64)), {"step_m": step_m, "origin_m": origin.tolist()},
                     ("delta", "shuffle"))]
    if intensity is not None:
        half = np.asarray(intensity).astype(np.float16)
        if intensity_bits is not None:  # round to nearest in the bit pattern (a carry into the exponent is right)
            drop = 10 - intensity_bits
            bits = half.view(np.uint16).astype(np.uint32) + (1 << (drop - 1))
            half = (bits & (0xFFFF ^ ((1 << drop) - 1))).astype(np.uint16).view(np.float16)
        arrays.append(_Array("intensity", half, {}, ("shuffle",)))
    return arrays


def _read_header(data: bytes, source: str) -> tuple[str, dict[str, Any], bytes]:
    """The kind, the parsed JSON header and the compressed body of a frame; refuses what is not a frame."""
    if len(data) < PREAMBLE.size:
        raise InputError(f"{len(data)} bytes: too short for a node frame", source)
    magic, version, code, header_len = PREAMBLE.unpack_from(data)
    if magic != MAGIC:
        raise InputError(f"not a node frame (starts {magic!r}, expected {MAGIC!r})", source)
    if version != VERSION:
        raise InputError(f"node frame version {version}; this studio reads version {VERSION} (update the node "
                         "agent or the studio so both match)", source)
    if code >= len(KINDS):
        raise InputError(f"unknown frame kind {code}; expected 0..{len(KINDS) - 1}", source)
    if header_len > MAX_HEADER_BYTES or PREAMBLE.size + header_len > len(data):
        raise InputError(f"header of {header_len:,} bytes in a {len(data):,}-byte frame (at most "
                         f"{MAX_HEADER_BYTES:,})", source)
    try:
        header = json.loads(data[PREAMBLE.size:PREAMBLE.size + header_len])
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise InputError("the frame's header is not JSON", source) from None
    if not isinstance(header, dict) or not isinstance(header.get("arrays"), list):
        raise InputError("the frame's header lists no arrays", source)
    return KINDS[code], header, data[PREAMBLE.size + header_len:]


def _check_arrays(kind: str, header: dict[str, Any], body_bytes: int, max_points: int, max_pixels: int,
                  source: str) -> list[dict[str, Any]]:
    """The header's array specs, each checked (name, dtype, shape, sizes) and within the limits."""
    arrays = header["arrays"]
    total = 0
    for spec in arrays:
        ok = (isinstance(spec, dict) and spec.get("name") in _ARRAYS[kind] and spec.get("dtype") in _DTYPES
              and isinstance(spec.get("shape"), list) and 1 <= len(spec["shape"]) <= 2
              and all(isinstance(n, int) and n >= 0 for n in spec["shape"])
              and all(isinstance(spec.get(k), int) and spec[k] >= 0 for k in ("raw_bytes", "zlib_bytes"))
              and isinstance(spec.get("filters", []), list) and set(spec.get("filters", [])) <= _FILTERS)
        if not ok:
            raise InputError(f"bad array in the {kind} frame's header: {shorten(spec)}", source)
        count = math.prod(spec["shape"])
        if spec["raw_bytes"] != count * np.dtype(spec["dtype"]).itemsize:
            raise InputError(f"array {spec['name']} of shape {spec['shape']} {spec['dtype']} stated as "
                             f"{spec['raw_bytes']:,} bytes", source)
        name = spec["name"]
        if name == "points" and (spec["shape"][0] != 3 or spec["shape"][-1] > max_points):
            raise InputError(f"{spec['shape'][-1]:,} points: more than the {max_points:,}-point limit", source,
                             status_code=413)
        if name in ("intensity", "image") and count > max(max_points, max_pixels) * 4:
            raise InputError(f"{name} of {count:,} values: over the frame limits", source, status_code=413)
        if name in ("depth", "amplitude") and count > max_pixels:
            raise InputError(f"{name} image of {count:,} px: more than the {max_pixels:,} px limit", source,
                             status_code=413)
        total += spec["zlib_bytes"]
    if total != body_bytes:
        raise InputError(f"the header states {total:,} compressed bytes; the frame holds {body_bytes:,}", source)
    names = [spec["name"] for spec in arrays]
    required = {"cloud": {"points"}, "depth": {"depth", "amplitude", "valid"}, "image": {"image"}}[kind]
    if len(set(names)) != len(names) or not required <= set(names):
        raise InputError(f"a {kind} frame needs arrays {sorted(required)} once each; it has {names}", source)
    return arrays


def _inflate(compressed: bytes, raw_bytes: int, name: str, source: str) -> bytes:
    """``compressed`` inflated to exactly ``raw_bytes`` bytes, never more (``max_length``)."""
    inflater = zlib.decompressobj()
    try:
        raw = inflater.decompress(compressed, raw_bytes)
    except zlib.error as exc:
        raise InputError(f"array {name} is not valid zlib data ({exc})", source) from None
    if len(raw) != raw_bytes or not inflater.eof or inflater.unconsumed_tail:
        raise InputError(f"array {name} does not inflate to its stated {raw_bytes:,} bytes", source)
    return raw


def _dequantise(steps: np.ndarray, spec: dict[str, Any], source: str) -> np.ndarray:
    """(N, 3) float64 points (m) from the (3, N) integer steps of :func:`_cloud_arrays`."""
    try:
        step_m = float(spec["step_m"])
        origin = np.asarray(spec["origin_m"], dtype=float).reshape(3)
    except (KeyError, TypeError, ValueError):
        raise InputError("the points' step_m and origin_m are missing from the header", source) from None
    return steps.T.astype(float) * step_m + origin


def _depth_sample(timestamp_s: float, values: dict[str, np.ndarray], specs: dict[str, dict[str, Any]],
                  meta: dict[str, Any], source: str) -> Sample:
    """A depth frame back as a Sample: depth (m), its valid pixels' points and amplitude, and the arrays in meta."""
    depth = (values["depth"] * float(specs["depth"].get("step_m", DEPTH_STEP_M))).astype(np.float32)
    amplitude = values["amplitude"].astype(np.float32)
    if depth.ndim != 2 or amplitude.shape != depth.shape or specs["valid"].get("pixels") != depth.size \
            or values["valid"].size != (depth.size + 7) // 8:
        raise InputError(f"depth {depth.shape}, amplitude {amplitude.shape} and valid mask disagree", source)
    index = np.flatnonzero(np.unpackbits(values["valid"], count=depth.size))
    if "points" in values:
        points = _dequantise(values["points"], specs["points"], source)
        if len(points) != len(index):
            raise InputError(f"{len(points)} points for {len(index)} valid pixels", source)
    else:
        rays = _intrinsics(depth, meta).rays().reshape(-1, 3)
        points = rays[index] * depth.ravel()[index, None].astype(float)
    meta["pixel_index"] = index
    meta["amplitude"] = amplitude
    return Sample(timestamp_s, points=points, intensity=amplitude.ravel()[index], depth=depth, meta=meta)
