"""The one way the API spells a pose: ``{"xyz_m": [x, y, z], "ypr_deg": [yaw, pitch, roll]}``.

Translation in metres, rotation as the ROS static-transform angles in degrees (``R = Rz(yaw) Ry(pitch) Rx(roll)``,
``../shared/conventions.md``), the same six numbers the depth procedure writes as X, Y, Z, RotZ, RotY, RotX.
Request models that carry a pose name it ``pose`` (what it is) or ``init`` (where a solve starts). The spellings
of earlier releases (``xyz_m``/``ypr_deg`` beside the other fields, ``init_xyz_m``/``init_ypr_deg``, ``pose_row``,
``init_pose_row``) are still read, marked deprecated on the OpenAPI page, and folded into the new field.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field, model_validator

from backend.core.transforms import from_xyz_ypr, to_xyz_ypr
from backend.store.schema import FiniteModel

Vector3 = tuple[float, float, float]
PoseRow = tuple[float, float, float, float, float, float]


class Pose(FiniteModel):
    """A transform as a person types it: translation (m), then ROS yaw, pitch, roll (deg)."""

    xyz_m: Vector3 = Field((0.0, 0.0, 0.0), description="translation (m)")
    ypr_deg: Vector3 = Field((0.0, 0.0, 0.0), description="ROS yaw, pitch, roll (deg): R = Rz(yaw) Ry(pitch) Rx(roll)")

    def matrix(self) -> np.ndarray:
        """The 4x4 homogeneous transform (m)."""
        return from_xyz_ypr(np.array(self.xyz_m), np.radians(self.ypr_deg))

    def row(self) -> PoseRow:
        """The six numbers X, Y, Z (m), RotZ, RotY, RotX (deg), as the depth services take a pose."""
        return (*self.xyz_m, *self.ypr_deg)

    @classmethod
    def of(cls, T: np.ndarray) -> Pose:
        """The pose of a 4x4 transform (m)."""
        xyz, ypr = to_xyz_ypr(np.asarray(T, dtype=float))
        return cls(xyz_m=tuple(float(v) for v in xyz), ypr_deg=tuple(float(v) for v in np.degrees(ypr)))


def deprecated_pair(target: str, xyz: str, ypr: str):
    """A ``mode="before"`` validator folding the old ``xyz``/``ypr`` fields into the pose field ``target``.

    Either old field alone is enough (the other is zero, as before); giving an old field together with
    ``target`` is refused, naming both.
    """

    @model_validator(mode="before")
    @classmethod
    def fold(cls, data: Any) -> Any:
        if not isinstance(data, dict) or (xyz not in data and ypr not in data):
            return data
        if data.get(target) is not None:
            raise ValueError(f"give '{target}' or the deprecated '{xyz}'/'{ypr}', not both")
        data = dict(data)
        old_xyz, old_ypr = data.pop(xyz, None), data.pop(ypr, None)
        if old_xyz is not None or old_ypr is not None:
            data[target] = {"xyz_m": old_xyz or (0.0, 0.0, 0.0), "ypr_deg": old_ypr or (0.0, 0.0, 0.0)}
        return data

    return fold


def deprecated_row(target: str, row: str):
    """A ``mode="before"`` validator folding the old six-number ``row`` (X, Y, Z m, RotZ, RotY, RotX deg) into the
    pose field ``target``."""

    @model_validator(mode="before")
    @classmethod
    def fold(cls, data: Any) -> Any:
        if not isinstance(data, dict) or row not in data:
            return data
        if data.get(target) is not None:
            raise ValueError(f"give '{target}' or the deprecated '{row}', not both")
        data = dict(data)
        values = data.pop(row)
        if values is not None:
            if not isinstance(values, (list, tuple)) or len(values) != 6:
                raise ValueError(f"'{row}' is six numbers X, Y, Z (m), RotZ, RotY, RotX (deg)")
            data[target] = {"xyz_m": list(values[:3]), "ypr_deg": list(values[3:])}
        return data

    return fold


def deprecated(description: str) -> Any:
    """An old field kept for reading: optional, shown as deprecated on the OpenAPI page."""
    return Field(None, deprecated=True, description=f"deprecated: {description}")
