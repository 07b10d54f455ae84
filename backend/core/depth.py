"""Depth cameras: the pinhole that turns a depth image into points, and the pose row a person types.

A depth node's frame is the paper's (and OpenCV's optical) frame: origin at the IR sensor,
X right, Y down, Z out of the lens. Its pose in the cell is ``T_world_node`` (4x4, m); a
person reads and types it as the row ``X, Y, Z`` (m) and ``RotZ, RotY, RotX`` (deg), the ROS
static-transform order: ``R = Rz(RotZ) @ Ry(RotY) @ Rx(RotX)`` about the node's axes. A
ceiling node looking down into the cell has RotZ about 0 and RotX about -150 to -140 deg
before it is turned towards the cell (``backend.core.depth_cell.PAPER_NODE_POSES``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from backend.core.errors import InputError, shorten
from backend.core.transforms import from_xyz_ypr, to_xyz_ypr

POSE_COLUMNS = ("X", "Y", "Z", "RotZ", "RotY", "RotX")
"""The pose row's columns: metres, then degrees (the paper's table and the ROS static-transform order)."""


@dataclass(frozen=True)
class DepthIntrinsics:
    """A depth camera's pinhole (px) and the range it is used to (m); depth is along the optical Z axis."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    min_range_m: float = 0.5
    max_range_m: float = 9.0
    """Depth beyond this is dropped as unreliable (the Kinect v2's noise rises quickly past it)."""

    def rays(self) -> np.ndarray:
        """(H, W, 3) direction of every pixel with Z = 1 (node frame), row-major like the image (read-only: one
        grid per pinhole, kept, since a node unprojects every frame at its camera's rate)."""
        return _rays(self)

    def unproject(self, depth_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points (N, 3, m, node frame) of the valid pixels of ``depth_m`` (H, W; Z in metres; 0 or NaN = no
        return; outside ``[min_range_m, max_range_m]`` dropped) and the flat pixel index (N,) of each (row-major),
        so per-pixel images (amplitude) index alike: ``amplitude.ravel()[index]``."""
        depth = np.asarray(depth_m, dtype=float)
        if depth.shape != (self.height, self.width):
            raise InputError(f"depth image is {depth.shape[1] if depth.ndim == 2 else '?'}x{depth.shape[0]} px; "
                             f"expected {self.width}x{self.height}", "depth")
        flat = depth.ravel()
        with np.errstate(invalid="ignore"):
            valid = np.isfinite(flat) & (flat >= self.min_range_m) & (flat <= self.max_range_m)
        index = np.flatnonzero(valid)
        points = self.rays().reshape(-1, 3)[index] * flat[index, None]
        return points, index

    def project(self, points_node: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2: u, v, px) and depth Z (N, m) of points in the node frame."""
        points = np.asarray(points_node, dtype=float).reshape(-1, 3)
        z = points[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.column_stack([self.fx * points[:, 0] / z + self.cx, self.fy * points[:, 1] / z + self.cy])
        return uv, z

    def to_dict(self) -> dict[str, float]:
        return {"width": self.width, "height": self.height, "fx": self.fx, "fy": self.fy, "cx": self.cx,
                "cy": self.cy, "min_range_m": self.min_range_m, "max_range_m": self.max_range_m}

    @classmethod
    def from_dict(cls, data: dict[str, float]) -> DepthIntrinsics:
        return cls(int(data["width"]), int(data["height"]), float(data["fx"]), float(data["fy"]), float(data["cx"]),
                   float(data["cy"]), float(data.get("min_range_m", 0.5)), float(data.get("max_range_m", 9.0)))


@functools.lru_cache(maxsize=16)
def _rays(intrinsics: DepthIntrinsics) -> np.ndarray:
    v, u = np.mgrid[0:intrinsics.height, 0:intrinsics.width].astype(float)
    rays = np.dstack([(u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy, np.ones_like(u)])
    rays.flags.writeable = False
    return rays


KINECT_V2 = DepthIntrinsics(512, 424, fx=365.6, fy=365.6, cx=255.5, cy=211.5)
"""The Kinect v2's time-of-flight depth camera: 512x424 px, about 70 x 60 deg, used out to 9 m."""


def stored_intrinsics(meta: dict) -> DepthIntrinsics:
    """The pinhole a depth capture's metadata keeps (``meta["intrinsics"]``, :meth:`DepthIntrinsics.to_dict`), or
    the Kinect v2's when it keeps none; malformed ones raise :class:`InputError`."""
    stored = meta.get("intrinsics")
    if not isinstance(stored, dict):
        return KINECT_V2
    try:
        return DepthIntrinsics.from_dict(stored)
    except (KeyError, TypeError, ValueError):
        raise InputError(f"the frame's intrinsics {shorten(stored)}: expected width, height, fx, fy, cx, cy",
                         "intrinsics") from None


def pose_from_row(row: tuple[float, float, float, float, float, float] | list[float]) -> np.ndarray:
    """``T_world_node`` from ``(X, Y, Z (m), RotZ, RotY, RotX (deg))``."""
    values = np.asarray(row, dtype=float).ravel()
    if values.shape != (6,) or not np.isfinite(values).all():
        raise InputError(f"a pose is six finite numbers {', '.join(POSE_COLUMNS)} (m, deg), got {list(row)}", "pose")
    return from_xyz_ypr(values[:3], np.radians(values[3:]))


def pose_row(T_world_node: np.ndarray) -> tuple[float, float, float, float, float, float]:
    """``(X, Y, Z (m), RotZ, RotY, RotX (deg))`` of ``T_world_node``."""
    xyz, ypr = to_xyz_ypr(np.asarray(T_world_node, dtype=float))
    return (*(float(v) for v in xyz), *(float(v) for v in np.degrees(ypr)))
