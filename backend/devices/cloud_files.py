"""Point-cloud files read into one shape, and a folder of them replayed as a LiDAR (driver ``"cloud_files"``).

:func:`read_cloud` reads ``.pcd`` (ascii, binary, binary_compressed; via pypcd4),
``.ply`` (ascii and binary; vertex x, y, z and an optional intensity property),
``.las``/``.laz`` (via laspy; scaled x, y, z and intensity), ``.npy`` (N×3, or
N×4 with intensity as the 4th column, or a structured array with x, y, z fields)
and ``.lvx`` (a Livox recording of one LiDAR, every frame accumulated, reflectivity
as intensity: :func:`~backend.devices.lvx_file.read_lvx_cloud`)
into a :class:`CloudFile`: (N, 3) float64 points in metres in the file's own frame.

Bad input never escapes as a library exception: unknown extensions, missing,
empty, truncated or corrupt files and files without finite points all raise
:class:`~backend.core.errors.InputError` naming the file and saying what was
expected. Points with NaN/inf coordinates are dropped and counted
(:attr:`CloudFile.dropped_non_finite`), never silently.

Clouds with more points than :data:`~backend.core.limits.MAX_CLOUD_POINTS` are refused, naming the file:
on the count the header declares (PCD ``POINTS``, the PLY vertex count, the LAS/LAZ header, the NPY
shape) before the points are read, and on the count read as a backstop.

Units are not guessed silently either: :func:`read_cloud` never rescales, and the solvers refuse a cloud that
looks like millimetres, naming it (:func:`backend.core.clouds.check_cloud`).

PLY is parsed here with numpy rather than Open3D for the usual layouts (the
vertex element's properties are scalars and, in binary files, every element
before it is fixed-size): Open3D reads a truncated PLY as zero-filled points
with only a console warning. Other layouts fall back to Open3D with a point
count check.
"""

from __future__ import annotations

import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from backend.core.errors import InputError
from backend.core.limits import MAX_CLOUD_POINTS
from backend.devices.base import Sample, register_driver
from backend.devices.file_sequence import FileSequence
from backend.devices.lvx_file import read_lvx_cloud

CLOUD_EXTENSIONS = (".pcd", ".ply", ".las", ".laz", ".npy", ".lvx")
"""File extensions read as point clouds (compared case-insensitively)."""

INTENSITY_FIELDS = ("intensity", "i", "scalar_intensity")
"""Field names (case-insensitive) taken as the intensity channel, first match wins."""



@dataclass
class CloudFile:
    """One point cloud read from a file."""

    points: np.ndarray
    """(N, 3) float64 finite points in the file's frame (m), N >= 1."""
    intensity: np.ndarray | None
    """(N,) float32 intensity of each point in the file's own units, or None when the file has none."""
    dropped_non_finite: int
    """Points dropped because x, y or z was NaN or infinite."""
    source: str
    """The file path as given to :func:`read_cloud`."""
    fields: list[str] = field(default_factory=list)
    """The per-point fields the file holds (e.g. ``["x", "y", "z", "intensity", "ring"]``)."""


def read_cloud(path: Path | str) -> CloudFile:
    """Read a point-cloud file by its extension (one of :data:`CLOUD_EXTENSIONS`).

    Raises :class:`InputError` naming the file for an unknown extension, a
    missing, truncated or corrupt file, missing x/y/z data, or a cloud with no
    finite point. NaN/inf points are dropped and counted, not rescaled or repaired.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    readers = {".pcd": _read_pcd, ".ply": _read_ply, ".las": _read_las, ".laz": _read_las, ".npy": _read_npy,
               ".lvx": _read_lvx}
    if suffix not in readers:
        raise InputError(
            f"{path.name}: unknown point-cloud file type {path.suffix or '(no extension)'!r}; "
            f"expected one of {', '.join(CLOUD_EXTENSIONS)}",
            input=str(path),
        )
    if not path.is_file():
        what = "is a folder, not a file" if path.is_dir() else "does not exist"
        raise InputError(f"{path.name}: {what} (expected a {suffix} point-cloud file)", input=str(path))
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise InputError(f"{path.name}: cannot read file ({exc.strerror or exc})", input=str(path)) from None
    if size == 0:
        raise InputError(f"{path.name}: file is empty (0 bytes); expected a {suffix} point cloud", input=str(path))

    xyz, intensity, fields = readers[suffix](path)
    return _finish(path, xyz, intensity, fields)


# --- helpers -------------------------------------------------------------------------------------


def check_point_count(path: Path, count: int) -> None:
    """Refuse (422, naming the file) a cloud of more than :data:`MAX_CLOUD_POINTS` points."""
    if count > MAX_CLOUD_POINTS.value():
        raise InputError(f"{path.name}: the cloud holds {count:,} points, more than {MAX_CLOUD_POINTS.describe()}",
                         input=str(path))


def _finish(path: Path, xyz: np.ndarray, intensity: np.ndarray | None, fields: list[str]) -> CloudFile:
    """Drop non-finite points, convert dtypes and refuse clouds with no finite point or too many points."""
    xyz = np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
    total = len(xyz)
    check_point_count(path, total)
    finite = np.isfinite(xyz).all(axis=1)
    kept = int(finite.sum())
    if kept == 0:
        detail = "0 points" if total == 0 else f"all {total} points have NaN/inf coordinates"
        raise InputError(f"{path.name}: the cloud holds no finite points ({detail})", input=str(path))
    if kept < total:
        xyz = xyz[finite]
    if intensity is not None:
        intensity = np.asarray(intensity, dtype=np.float32).reshape(-1)
        if kept < total:
            intensity = intensity[finite]
    return CloudFile(
        points=np.ascontiguousarray(xyz),
        intensity=None if intensity is None else np.ascontiguousarray(intensity),
        dropped_non_finite=total - kept,
        source=str(path),
        fields=list(fields),
    )


def _intensity_name(names: list[str] | tuple[str, ...]) -> str | None:
    lower = {n.lower(): n for n in names}
    for candidate in INTENSITY_FIELDS:
        if candidate in lower:
            return lower[candidate]
    return None


def _need_xyz(path: Path, names: list[str] | tuple[str, ...], what: str) -> None:
    missing = [axis for axis in ("x", "y", "z") if axis not in names]
    if missing:
        raise InputError(
            f"{path.name}: {what} has no {'/'.join(missing)} field (fields: {', '.join(names) or 'none'}); "
            f"expected x, y, z per point",
            input=str(path),
        )


def _corrupt(path: Path, expected: str, exc: BaseException | str) -> InputError:
    reason = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
    reason = " ".join(str(reason).split())[:200]
    return InputError(f"{path.name}: truncated or corrupt file ({reason}); expected {expected}", input=str(path))


# --- PCD -----------------------------------------------------------------------------------------

_PCD_EXPECTED = "a PCD file (ascii, binary or binary_compressed) with x, y, z fields"
_PCD_POINTS = re.compile(rb"^POINTS[ \t]+(\d+)", re.MULTILINE)


def _read_pcd(path: Path) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    from pypcd4 import PointCloud

    with path.open("rb") as fh:
        head = fh.read(1 << 16)
    if not head[:256].lstrip().startswith((b"#", b"VERSION", b"FIELDS")):
        raise _corrupt(path, _PCD_EXPECTED, "no PCD header")
    header_points = _PCD_POINTS.search(head.split(b"\nDATA", 1)[0])
    if header_points:
        check_point_count(path, int(header_points[1]))
    try:
        pc = PointCloud.from_path(path)
        data = pc.pc_data
        fields = list(pc.fields)
        declared = int(pc.metadata.points)
    except InputError:
        raise
    except Exception as exc:  # pypcd4 raises ValueError, pydantic ValidationError, UnicodeDecodeError...
        raise _corrupt(path, _PCD_EXPECTED, exc) from None
    if len(data) != declared:
        raise _corrupt(path, _PCD_EXPECTED, f"header declares {declared} points, file holds {len(data)}")
    _need_xyz(path, fields, "the PCD file")
    xyz = np.column_stack([data["x"], data["y"], data["z"]]) if len(data) else np.zeros((0, 3))
    name = _intensity_name(fields)
    intensity = data[name] if name is not None else None
    return xyz, intensity, fields


# --- PLY -----------------------------------------------------------------------------------------

_PLY_EXPECTED = "a PLY file (ascii or binary) with a vertex element holding x, y, z"
_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


@dataclass
class _PlyElement:
    name: str
    count: int
    props: list[tuple[str, str | None]]
    """(name, numpy type code) per property; None for a list property."""

    @property
    def fixed(self) -> bool:
        return all(code is not None for _, code in self.props)


def _parse_ply_header(path: Path, data: bytes) -> tuple[str | None, list[_PlyElement], int]:
    """Parse a PLY header: (byte-order char or None for ascii, elements, offset of the body)."""
    match = re.search(rb"end_header[ \t]*\r?\n", data[:1 << 20])
    if not data.startswith(b"ply") or match is None:
        raise _corrupt(path, _PLY_EXPECTED, "no PLY header (missing 'ply' or 'end_header')")
    fmt: str | None = "?"
    elements: list[_PlyElement] = []
    try:
        for raw in data[: match.start()].decode("ascii").splitlines()[1:]:
            words = raw.split()
            if not words or words[0] in ("comment", "obj_info"):
                continue
            if words[0] == "format":
                if words[1] not in _PLY_FORMATS:
                    raise ValueError(f"unknown format {words[1]!r}")
                fmt = _PLY_FORMATS[words[1]]
            elif words[0] == "element":
                elements.append(_PlyElement(words[1], int(words[2]), []))
            elif words[0] == "property":
                if words[1] == "list":
                    elements[-1].props.append((words[4], None))
                else:
                    elements[-1].props.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise ValueError(f"unexpected header line {raw!r}")
    except (ValueError, IndexError, KeyError, UnicodeDecodeError) as exc:
        raise _corrupt(path, _PLY_EXPECTED, f"bad PLY header: {exc}") from None
    if fmt == "?":
        raise _corrupt(path, _PLY_EXPECTED, "PLY header has no format line")
    return fmt, elements, match.end()


def _read_ply(path: Path) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError(f"{path.name}: cannot read file ({exc.strerror or exc})", input=str(path)) from None
    byte_order, elements, body = _parse_ply_header(path, data)
    vertex_index = next((i for i, e in enumerate(elements) if e.name == "vertex"), None)
    if vertex_index is None:
        raise _corrupt(path, _PLY_EXPECTED, "no 'vertex' element")
    vertex = elements[vertex_index]
    check_point_count(path, vertex.count)
    names = [n for n, _ in vertex.props]
    _need_xyz(path, names, "the PLY vertex element")
    before = elements[:vertex_index]
    if not vertex.fixed or (byte_order is not None and not all(e.fixed for e in before)):
        return _read_ply_open3d(path, vertex, names)

    n = vertex.count
    if byte_order is None:  # ascii: one line per element instance
        lines = data[body:].splitlines()
        skip = sum(e.count for e in before)
        rows = lines[skip : skip + n]
        if len(rows) < n:
            raise _corrupt(path, _PLY_EXPECTED, f"header declares {n} vertices, file holds {len(rows)}")
        try:
            values = np.array(b" ".join(rows).split(), dtype=np.float64).reshape(n, len(names))
        except ValueError as exc:
            raise _corrupt(path, _PLY_EXPECTED, f"bad vertex values: {exc}") from None
        columns = {name: values[:, i] for i, name in enumerate(names)}
    else:
        dtype = np.dtype([(name, byte_order + code) for name, code in vertex.props])  # type: ignore[operator]
        offset = body + sum(e.count * np.dtype([(p, byte_order + c) for p, c in e.props]).itemsize  # type: ignore[operator]
                            for e in before)
        needed = offset + n * dtype.itemsize
        if len(data) < needed:
            held = max(0, (len(data) - offset) // dtype.itemsize)
            raise _corrupt(path, _PLY_EXPECTED, f"header declares {n} vertices, file holds {held}")
        records = np.frombuffer(data, dtype=dtype, count=n, offset=offset)
        columns = {name: records[name] for name in names}
    xyz = np.column_stack([columns["x"], columns["y"], columns["z"]]) if n else np.zeros((0, 3))
    name = _intensity_name(names)
    return xyz, (columns[name] if name is not None else None), names


def _read_ply_open3d(
    path: Path, vertex: _PlyElement, names: list[str]
) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    """Layouts the numpy reader skips (list properties): Open3D, with the vertex count checked."""
    import open3d as o3d

    try:
        cloud = o3d.t.io.read_point_cloud(str(path))
        attributes = cloud.point
        xyz = attributes["positions"].numpy() if "positions" in attributes else np.zeros((0, 3))
        name = next((key for key in ("intensity", "scalar_intensity") if key in attributes), None)
        intensity = attributes[name].numpy().reshape(-1) if name is not None else None
    except Exception as exc:
        raise _corrupt(path, _PLY_EXPECTED, exc) from None
    if len(xyz) != vertex.count:
        raise _corrupt(path, _PLY_EXPECTED, f"header declares {vertex.count} vertices, Open3D read {len(xyz)}")
    return xyz, intensity, names


# --- LAS / LAZ -----------------------------------------------------------------------------------


def _read_las(path: Path) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    import laspy

    expected = f"a {path.suffix.lower().lstrip('.').upper()} point-cloud file"
    try:
        with laspy.open(path) as reader:
            declared = int(reader.header.point_count)
    except Exception as exc:  # laspy's LaspyException, a header cut short...
        raise _corrupt(path, expected, exc) from None
    check_point_count(path, declared)
    try:
        las = laspy.read(path)
        declared = int(las.header.point_count)
        held = len(las.points)
        xyz = np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)]) if held else np.zeros((0, 3))
        names = list(las.point_format.dimension_names)
        intensity = np.asarray(las.intensity) if "intensity" in names and held else None
    except Exception as exc:  # laspy's LaspyException, lazrs errors, numpy buffer errors...
        raise _corrupt(path, expected, exc) from None
    if held != declared:
        raise _corrupt(path, expected, f"header declares {declared} points, file holds {held}")
    fields = ["x", "y", "z"] + [n for n in names if n not in ("X", "Y", "Z")]
    return xyz, intensity, fields


# --- NPY -----------------------------------------------------------------------------------------

_NPY_EXPECTED = "a numeric .npy array of shape (N, 3) or (N, 4) (x, y, z[, intensity]) or with x, y, z fields"


def _npy_points(path: Path) -> int | None:
    """Points an .npy file declares (its rows, or its elements when structured), from the header alone;
    None when the header cannot be read (``np.load`` then says why)."""
    readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
    try:
        with path.open("rb") as fh:
            shape, _, dtype = readers[np.lib.format.read_magic(fh)](fh)
    except Exception:  # not an .npy, an unknown version, a header cut short...
        return None
    return int(np.prod(shape if dtype.names or len(shape) != 2 else shape[:1]))


def _read_npy(path: Path) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    declared = _npy_points(path)
    if declared is not None:
        check_point_count(path, declared)
    try:
        array = np.load(path, allow_pickle=False)
    except ValueError as exc:
        if "Object arrays" in str(exc):
            raise InputError(f"{path.name}: array of dtype object (needs pickle, refused); "
                             f"expected numbers (float or int)", input=str(path)) from None
        raise _corrupt(path, _NPY_EXPECTED, exc) from None
    except Exception as exc:  # truncated data, not an npy file at all...
        raise _corrupt(path, _NPY_EXPECTED, exc) from None
    if not isinstance(array, np.ndarray):
        raise _corrupt(path, _NPY_EXPECTED, f"holds a {type(array).__name__}, not one array")
    if array.dtype.names:  # structured: fields x, y, z[, intensity]
        names = list(array.dtype.names)
        _need_xyz(path, names, "the structured array")
        flat = array.reshape(-1)
        name = _intensity_name(names)
        xyz = np.column_stack([flat["x"], flat["y"], flat["z"]]) if len(flat) else np.zeros((0, 3))
        return _as_float(path, xyz), (_as_float(path, flat[name]) if name else None), names
    if array.ndim != 2 or array.shape[1] not in (3, 4):
        raise InputError(
            f"{path.name}: array of shape {array.shape}; expected (N, 3) x, y, z or (N, 4) x, y, z, intensity",
            input=str(path),
        )
    array = _as_float(path, array)
    if array.shape[1] == 4:
        return array[:, :3], array[:, 3], ["x", "y", "z", "intensity"]
    return array, None, ["x", "y", "z"]


def _as_float(path: Path, array: np.ndarray) -> np.ndarray:
    kind = array.dtype.kind
    if kind not in "iuf":
        raise InputError(f"{path.name}: array of dtype {array.dtype}; expected numbers (float or int)", input=str(path))
    return array.astype(np.float64, copy=False)


# --- LVX ------------------------------------------------------------------------------------------


def _read_lvx(path: Path) -> tuple[np.ndarray, np.ndarray | None, list[str]]:
    cloud = read_lvx_cloud(path)
    return cloud.points, cloud.reflectivity, ["x", "y", "z", "reflectivity"]


# --- the capture driver --------------------------------------------------------------------------


@register_driver
class CloudFolder(FileSequence):
    """Replays point-cloud files, one per :meth:`read`, as a range sensor.

    ``path`` is a folder (its files matching the glob ``pattern`` with a
    :data:`CLOUD_EXTENSIONS` extension, in natural order: ``scan2`` before
    ``scan10``) or a single cloud file. With ``loop`` the recording restarts
    from the first file instead of ending.

    Samples carry ``points`` (N, 3) float64 in metres, ``intensity`` (or None),
    the read time as ``timestamp_s`` and meta ``{"source": file name,
    "frame_index": position of the file, "dropped_non_finite": NaN/inf points
    dropped}``. A corrupt file raises :class:`InputError` naming it, and the next
    ``read()`` continues with the following file.
    """

    driver = "cloud_files"
    extensions = CLOUD_EXTENSIONS
    noun = "point clouds"
    end_message = "end of recording after {count} clouds"

    def load(self, file: Path, index: int) -> Sample:
        cloud = read_cloud(file)
        return Sample(
            timestamp_s=time.time(),
            points=cloud.points,
            intensity=cloud.intensity,
            meta={"source": file.name, "frame_index": index, "dropped_non_finite": cloud.dropped_non_finite},
        )
