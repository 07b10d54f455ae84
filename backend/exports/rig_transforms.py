"""The rig's transforms as YAML, with a ready ``static_transform_publisher`` line per frame.

Layout (``format: calib-studio-rig-transforms``, ``version: 1``)::

    format: calib-studio-rig-transforms
    version: 1
    root: base_link
    convention: optical                           # or body (see backend/exports/frame_tree.py)
    frames:
    - parent: base_link
      child: lidar
      translation_m: {x: 0.1, y: 0.0, z: 0.3}
      quaternion_xyzw: {x: 0.0, y: 0.0, z: 0.0, w: 1.0}
      yaw_pitch_roll_deg: {yaw: 0.0, pitch: 0.0, roll: 0.0}
      sigma: {trans_m: [...], rot_deg: [...]}     # or null
      static_transform_publisher: ros2 run tf2_ros static_transform_publisher --x ...

Each entry is ``T_parent_child`` of ``../shared/conventions.md`` (maps points in
``child`` into ``parent``; ROS ``frame_id = parent``, ``child_frame_id =
child``): translation in metres, rotation as a quaternion ``(x, y, z, w)`` with
``w >= 0`` and as ROS yaw, pitch, roll in degrees (``R = Rz(yaw) Ry(pitch)
Rx(roll)``). ``sigma`` holds 1-sigma translation (m, per axis) and rotation (deg,
about the child's x, y, z). Frames are listed parents first, in the ``convention``
chosen (:func:`~backend.exports.frame_tree.export_frames`: cameras as optical frames,
or as body frames with a ``CAM_optical_frame`` child). A frame other than the root
without a parent is refused (:class:`InputError` naming it), never left out. The command uses the
ROS 2 Humble+ flag form of tf2_ros ``static_transform_publisher`` (flags as in
ros2/geometry2 ``tf2_ros/src/static_transform_broadcaster_program.cpp``), with
angles in radians as tf2 expects. Floats are written at full precision; a NaN or
infinity is refused (:class:`InputError` naming the frame), never written.
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Any

import numpy as np

from backend.core.errors import shorten
from backend.core.finite import require_finite
from backend.core.rig import Rig
from backend.core.transforms import (
    from_quaternion_xyzw,
    from_xyz_ypr,
    rotation_angle_deg,
    to_quaternion_xyzw,
    to_xyz_ypr,
)
from backend.exports.formats import CONVENTIONS, Convention
from backend.exports.frame_tree import export_frames
from backend.exports.text_file import read_text
from backend.exports.yaml_fields import YamlFields, dump_yaml, floats, parse_yaml

FORMAT = "calib-studio-rig-transforms"
VERSION = 1
_ANGLE_TOLERANCE_DEG = 1e-6
"""How far ``yaw_pitch_roll_deg`` may disagree with ``quaternion_xyzw`` on load (deg)."""
_NORM_TOLERANCE = 1e-6
"""How far a quaternion's norm may be from 1 on load."""


def dump_rig_transforms(rig: Rig, convention: Convention = "optical") -> str:
    """YAML text listing ``T_parent_child`` of every non-root frame of ``rig``, parents first, in ``convention``."""
    frames = []
    for frame in export_frames(rig, convention):
        T = frame.T_parent_child
        xyz_m, ypr_rad = to_xyz_ypr(T)
        sigmas = frame.sigmas
        require_finite({"sigma": sigmas}, f"rig transforms: frame {frame.child!r}", frame.sensor)
        frames.append(
            {
                "parent": frame.parent,
                "child": frame.child,
                "translation_m": dict(zip("xyz", floats(xyz_m), strict=True)),
                "quaternion_xyzw": dict(zip("xyzw", floats(quaternion_xyzw(T)), strict=True)),
                "yaw_pitch_roll_deg": dict(zip(("yaw", "pitch", "roll"), floats(np.degrees(ypr_rad)), strict=True)),
                "sigma": None if sigmas is None else {"trans_m": floats(sigmas[0]), "rot_deg": floats(sigmas[1])},
                "static_transform_publisher": static_transform_publisher(frame.parent, frame.child, T),
            }
        )
    document = {"format": FORMAT, "version": VERSION, "root": rig.root, "convention": convention, "frames": frames}
    return dump_yaml(document)


def quaternion_xyzw(T: np.ndarray) -> np.ndarray:
    """The rotation of ``T`` as the unit quaternion ``(x, y, z, w)`` with ``w >= 0`` that the exports write."""
    q = to_quaternion_xyzw(T)
    return -q if q[3] < 0 else q


def static_transform_publisher(parent: str, child: str, T_parent_child: np.ndarray) -> str:
    """The ROS 2 command publishing ``T_parent_child`` (translation m, yaw/pitch/roll rad); a NaN or
    infinity in it raises :class:`InputError` naming ``child``."""
    require_finite({"T_parent_child": T_parent_child}, f"static_transform_publisher: frame {child!r}", child)
    (x, y, z), (yaw, pitch, roll) = (floats(v) for v in to_xyz_ypr(T_parent_child))
    values = {"x": x, "y": y, "z": z, "yaw": yaw, "pitch": pitch, "roll": roll}
    flags = " ".join(f"--{name} {value!r}" for name, value in values.items())
    return (
        f"ros2 run tf2_ros static_transform_publisher {flags} "
        f"--frame-id {shlex.quote(parent)} --child-frame-id {shlex.quote(child)}"
    )


def load_rig_transforms(source: str | Path) -> list[dict[str, Any]]:
    """Read a rig transforms document: a :class:`~pathlib.Path` is read as a file, a ``str`` is the YAML text.

    ``convention`` (optional, ``optical`` when absent) is checked, not returned: the frames are read as
    written. Returns one dict per frame, in file order: ``parent``, ``child``,
    ``T_parent_child`` (4x4, metres) and ``sigma`` (``None`` or ``{"trans_m":
    (3,) m, "rot_deg": (3,) deg}``). Either rotation field may be omitted; if both
    are given they must agree. ``static_transform_publisher`` is derived and not
    read. Raises :class:`InputError` naming the file (or "rig transforms text")
    and the field for anything malformed, including a parent that is neither the
    root nor an earlier child and a child listed twice.
    """
    if isinstance(source, Path):
        origin, text = str(source), read_text(source, f"a {FORMAT} YAML file")
    else:
        origin, text = "rig transforms text", source
    document = parse_yaml(text, origin, f"a {FORMAT} document")
    fields = _Fields(origin)
    top = fields.mapping(document, "(document)", f"a {FORMAT} mapping with format, version, root and frames")
    if fields.get(top, "format", "format", repr(FORMAT)) != FORMAT:
        raise fields.error("format", f"is {shorten(top['format'])}", repr(FORMAT))
    version = fields.get(top, "version", "version", str(VERSION))
    if isinstance(version, bool) or version != VERSION:
        raise fields.error("version", f"is {shorten(version)}", f"{VERSION} (the only version this reader knows)")
    root = fields.name(top, "root", "root")
    convention = top.get("convention", "optical")
    if not isinstance(convention, str) or convention not in CONVENTIONS:
        raise fields.error("convention", f"is {shorten(convention)}", f"one of {list(CONVENTIONS)}")
    entries = fields.get(top, "frames", "frames", "a list of frames")
    if not isinstance(entries, list):
        raise fields.error("frames", f"is {shorten(entries)}", "a list of frames")
    known = {root}
    result = []
    for i, entry in enumerate(entries):
        where = f"frames[{i}]"
        entry = fields.mapping(entry, where, "a mapping with parent, child, translation_m and a rotation")
        parent = fields.name(entry, "parent", f"{where}.parent")
        child = fields.name(entry, "child", f"{where}.child")
        if parent not in known:
            raise fields.error(f"{where}.parent", f"is {shorten(parent)}",
                               f"the root or an earlier child: {shorten(sorted(known))}")
        if child in known:
            raise fields.error(f"{where}.child", f"is {shorten(child)}, which is already in the rig",
                               "a new frame name")
        known.add(child)
        result.append(
            {
                "parent": parent,
                "child": child,
                "T_parent_child": fields.transform(entry, where),
                "sigma": fields.sigma(entry, where),
            }
        )
    return result


class _Fields(YamlFields):
    """Typed, checked access to the fields of one rig transforms document."""

    def name(self, mapping: dict[str, Any], key: str, field: str) -> str:
        value = self.get(mapping, key, field, "a frame name")
        if not isinstance(value, str) or not value:
            raise self.error(field, f"is {shorten(value)}", "a non-empty frame name")
        return value

    def numbers(self, mapping: dict[str, Any], key: str, field: str, names: tuple[str, ...], unit: str) -> np.ndarray:
        """The finite numbers ``mapping[key][name]`` for each of ``names``."""
        expected = f"a mapping {{{', '.join(names)}}} of numbers ({unit})"
        node = self.mapping(self.get(mapping, key, field, expected), field, expected)
        return np.array([self.number(self.get(node, n, f"{field}.{n}", expected), f"{field}.{n}") for n in names])

    def transform(self, entry: dict[str, Any], where: str) -> np.ndarray:
        """``T_parent_child`` from ``translation_m`` and ``quaternion_xyzw`` and/or ``yaw_pitch_roll_deg``."""
        t_m = self.numbers(entry, "translation_m", f"{where}.translation_m", ("x", "y", "z"), "m")
        T_q = T_ypr = None
        if "quaternion_xyzw" in entry:
            field = f"{where}.quaternion_xyzw"
            q = self.numbers(entry, "quaternion_xyzw", field, ("x", "y", "z", "w"), "unit quaternion")
            if abs(np.linalg.norm(q) - 1.0) > _NORM_TOLERANCE:
                raise self.error(field, f"has norm {np.linalg.norm(q)!r}", "a unit quaternion (norm 1)")
            T_q = from_quaternion_xyzw(q, t_m)
        if "yaw_pitch_roll_deg" in entry:
            field = f"{where}.yaw_pitch_roll_deg"
            ypr_deg = self.numbers(entry, "yaw_pitch_roll_deg", field, ("yaw", "pitch", "roll"), "deg")
            T_ypr = from_xyz_ypr(t_m, np.radians(ypr_deg))
        if T_q is None and T_ypr is None:
            raise self.error(f"{where}.quaternion_xyzw", "is missing", "quaternion_xyzw and/or yaw_pitch_roll_deg")
        if T_q is not None and T_ypr is not None:
            angle_deg = rotation_angle_deg(T_q[:3, :3].T @ T_ypr[:3, :3])
            if angle_deg > _ANGLE_TOLERANCE_DEG:
                raise self.error(
                    f"{where}.yaw_pitch_roll_deg",
                    f"differs from quaternion_xyzw by {angle_deg:.6g} deg",
                    "the same rotation in both (edit both, or delete one)",
                )
        return T_q if T_q is not None else T_ypr

    def sigma(self, entry: dict[str, Any], where: str) -> dict[str, np.ndarray] | None:
        """``{"trans_m": (3,), "rot_deg": (3,)}`` non-negative 1-sigma values, or None."""
        node = entry.get("sigma")
        if node is None:
            return None
        expected = "null or a mapping {trans_m: [3 numbers, m], rot_deg: [3 numbers, deg]}"
        node = self.mapping(node, f"{where}.sigma", expected)
        result = {}
        for key in ("trans_m", "rot_deg"):
            field = f"{where}.sigma.{key}"
            values = self.get(node, key, field, expected)
            if not isinstance(values, list) or len(values) != 3:
                raise self.error(field, f"is {shorten(values)}", "a list of 3 non-negative numbers")
            numbers = np.array([self.number(v, f"{field}[{i}]") for i, v in enumerate(values)])
            if np.any(numbers < 0):
                raise self.error(field, f"is {shorten(values)}", "a list of 3 non-negative numbers")
            result[key] = numbers
        return result
