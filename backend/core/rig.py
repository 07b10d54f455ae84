"""The rig model: frames in a tree and the sensors mounted on them.

Every frame but the root has a parent and ``T_parent_child`` (4x4, metres). A
sensor is a frame with a kind and, for cameras, intrinsics. A transform may carry
a 6x6 covariance over ``[tx, ty, tz, rx, ry, rz]`` (m, rad; rotation as a small
rotation vector in the child frame), from which the 1-sigma values in exports are
read. Plain numpy inside; the API converts with :mod:`backend.api.schemas`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError, NotFoundError
from backend.core.finite import require_finite
from backend.core.uncertainty import sigmas

SensorKind = Literal["frame", "camera", "lidar3d", "lidar2d", "depth", "imu"]

DEFAULT_MOUNT_SIGMA = (0.05, 5.0)
"""1-sigma (m, deg) of a mounting guess (tape, CAD) when none is given: a weak prior the calibrations override."""


def covariance_sigmas(covariance: np.ndarray | None) -> tuple[np.ndarray, np.ndarray] | None:
    """1-sigma translation (m, per parent axis) and rotation (deg, about the child's x, y, z) of a transform's 6x6
    covariance (``[t (m), r (rad)]``), or None without one."""
    if covariance is None:
        return None
    std = sigmas(covariance)
    return std[:3], np.degrees(std[3:])


def edge_slot(parent: str, child: str) -> str:
    """The name of the relation ``T_parent_child`` between two frames, as the session's acceptance slots call it
    (``lidar_top/T_cam_front_lidar_top``): one accepted result per relation."""
    return f"{child}/T_{parent}_{child}"


@dataclass
class Frame:
    """One node of the frame tree."""

    name: str
    parent: str | None
    T_parent_child: np.ndarray = field(default_factory=lambda: np.eye(4))
    kind: SensorKind = "frame"
    covariance: np.ndarray | None = None
    """6x6 covariance of ``[t (m), r (rad)]`` of ``T_parent_child``, or None if unknown."""
    intrinsics: CameraIntrinsics | None = None
    device: dict = field(default_factory=dict)
    """How to capture from this sensor: ``{"driver": ..., **settings}``."""
    T_mount: np.ndarray | None = None
    """The mounting guess (tape, CAD) of ``T_parent_child`` (4x4, m): a prior edge of the rig graph. It stays
    as given while calibrations move ``T_parent_child``; None takes the ``T_parent_child`` the frame is made with."""
    mount_sigma: tuple[float, float] | None = DEFAULT_MOUNT_SIGMA
    """1-sigma of the mounting guess: translation (m, per axis), rotation (deg, per axis); None when the mounting
    is unknown (then only calibrations place the frame)."""
    not_connected: bool = False
    """Added as not connected (the rig defined before the hardware is plugged in): its device has not answered
    since; the first time it does, this goes back to False."""
    clock_offset_s: float = 0.0
    """How much the sensor's clock reads more than the rig's reference clock at the same instant (s): the rig's time
    of a sample is its stamp less this. Set by accepting a time offset (:mod:`backend.calib.time_offset`) or a
    camera-IMU result; applied where samples of several sensors are matched by time."""
    clock_offset_std_s: float | None = None
    """1-sigma of :attr:`clock_offset_s` (s); None while the offset is the default 0, not measured."""

    def __post_init__(self) -> None:
        """Shape the arrays; a NaN or infinity in the transform or covariance raises :class:`InputError`."""
        self.T_parent_child = np.asarray(self.T_parent_child, dtype=float).reshape(4, 4)
        mount = self.T_parent_child if self.T_mount is None else self.T_mount
        self.T_mount = np.array(mount, dtype=float).reshape(4, 4)
        if self.covariance is not None:
            self.covariance = np.asarray(self.covariance, dtype=float).reshape(6, 6)
        require_finite({"T_parent_child": self.T_parent_child, "covariance": self.covariance, "T_mount": self.T_mount,
                        "mount_sigma": self.mount_sigma, "clock_offset_s": self.clock_offset_s,
                        "clock_offset_std_s": self.clock_offset_std_s}, f"frame {self.name!r}", self.name)
        if self.mount_sigma is not None and not all(s > 0 for s in self.mount_sigma):
            raise InputError(f"frame {self.name!r}: mounting sigma must be above 0 m and 0 deg, got "
                             f"{list(self.mount_sigma)}", "mount_sigma")

    @property
    def mount_covariance(self) -> np.ndarray | None:
        """6x6 of the mounting guess (``TRANSFORM_PARAMETERS``: m, rad), or None when the mounting is unknown."""
        if self.mount_sigma is None:
            return None
        sigma_m, sigma_deg = self.mount_sigma
        return np.diag([sigma_m**2] * 3 + [np.radians(sigma_deg) ** 2] * 3)

    def rig_time(self, stamp_s: float) -> float:
        """The rig's reference time (s) of a sample this sensor stamped ``stamp_s`` (s)."""
        return stamp_s - self.clock_offset_s

    @property
    def sigmas(self) -> tuple[np.ndarray, np.ndarray] | None:
        """1-sigma translation (m, per axis) and rotation (deg, about child x, y, z)."""
        return covariance_sigmas(self.covariance)


@dataclass
class Rig:
    """A tree of frames rooted at ``root`` (default ``base_link``)."""

    root: str = "base_link"
    frames: dict[str, Frame] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.root not in self.frames:
            self.frames[self.root] = Frame(self.root, None)

    def add(self, frame: Frame) -> Frame:
        """Add a frame under an existing parent; names are unique."""
        if not frame.name or not frame.name.replace("_", "").replace("-", "").isalnum():
            raise InputError(f"frame name {frame.name!r} must be letters, digits, '_' or '-'", "name")
        if frame.name in self.frames:
            raise InputError(f"a frame named {frame.name!r} already exists in the rig", "name", 409)
        if frame.parent not in self.frames:
            raise InputError(f"parent frame {frame.parent!r} is not in the rig; known: {sorted(self.frames)}", "parent")
        self.frames[frame.name] = frame
        return frame

    def get(self, name: str) -> Frame:
        try:
            return self.frames[name]
        except KeyError:
            raise NotFoundError(f"no sensor or frame named {name!r}; known: {sorted(self.frames)}", "sensor") from None

    def children(self, name: str) -> list[str]:
        """The frames hanging directly from ``name``, in insertion order."""
        return [f.name for f in self.frames.values() if f.parent == name]

    def subtree(self, name: str) -> list[str]:
        """``name`` and every frame below it, parents before children."""
        found = [self.get(name).name]
        for frame in found:
            found += self.children(frame)
        return found

    def remove(self, name: str) -> Frame:
        """Take the leaf frame ``name`` out of the tree; a frame others hang from (or the root) is refused, naming
        them."""
        frame = self.get(name)
        if frame.parent is None:
            raise InputError(f"{name!r} is the rig's root and cannot be removed", "sensor", 409)
        if children := self.children(name):
            raise InputError(f"{name!r} cannot be removed while {', '.join(map(repr, children))} "
                             f"{'hangs' if len(children) == 1 else 'hang'} from it: give "
                             f"{'it' if len(children) == 1 else 'them'} another parent first", "sensor", 409)
        return self.frames.pop(name)

    def reparent(self, name: str, parent: str, T_parent_child: np.ndarray | None = None) -> None:
        """Hang ``name`` (with the frames below it) from ``parent`` at ``T_parent_child`` (4x4, m; None keeps the
        frame where it is now). A parent that is not in the rig, or that is ``name`` or hangs below it (a cycle),
        is refused, naming it.

        The moved frames go to the end of the frame order, so every frame still comes after its parent (the
        order the session file is stored and read in)."""
        moved = self.subtree(name)
        if parent not in self.frames:
            raise InputError(f"parent frame {parent!r} is not in the rig; known: {sorted(self.frames)}", "parent")
        if parent in moved:
            raise InputError(f"{name!r} cannot hang from {parent!r}: {parent!r} "
                             f"{'is the frame itself' if parent == name else f'hangs below {name!r}'}, which would "
                             "make a cycle", "parent")
        T = self.T_a_b(parent, name) if T_parent_child is None else np.asarray(T_parent_child, dtype=float)
        frame = self.frames[name]
        frame.parent, frame.T_parent_child = parent, T.reshape(4, 4)
        for moved_name in moved:
            self.frames[moved_name] = self.frames.pop(moved_name)

    def sensors(self, kind: SensorKind | None = None) -> list[Frame]:
        """Frames that are sensors (optionally of one kind), in insertion order."""
        return [f for f in self.frames.values() if f.kind != "frame" and (kind is None or f.kind == kind)]

    def T_root_frame(self, name: str) -> np.ndarray:
        """Pose of a frame in the root frame, composed along the tree."""
        T = np.eye(4)
        frame = self.get(name)
        while frame.parent is not None:
            T = frame.T_parent_child @ T
            frame = self.frames[frame.parent]
        return T

    def T_a_b(self, a: str, b: str) -> np.ndarray:
        """Transform mapping points in frame ``b`` into frame ``a``."""
        return np.linalg.solve(self.T_root_frame(a), self.T_root_frame(b))

    def set_relative(self, child: str, reference: str, T_reference_child: np.ndarray,
                     covariance: np.ndarray | None = None) -> None:
        """Mount ``child`` so that ``T_a_b(reference, child)`` becomes ``T_reference_child`` (a calibration's answer).

        Only the child's ``T_parent_child`` changes (``reference`` must not hang below ``child``).
        ``covariance`` (6x6 over translation in ``reference`` axes, m, and rotation about the
        child's axes, rad) is carried into the parent's axes to first order: the translation
        block is rotated by ``R_parent_reference``; rotations stay about the child's axes, as the
        rig's convention wants. A covariance that is missing or not finite leaves none; a transform that is
        not finite raises :class:`InputError` and leaves the frame as it was.
        """
        frame = self.get(child)
        T_parent_reference = self.T_a_b(frame.parent, reference)
        T_parent_child = T_parent_reference @ np.asarray(T_reference_child, dtype=float)
        require_finite({"T_parent_child": T_parent_child}, f"frame {child!r}", child)
        frame.T_parent_child = T_parent_child
        if covariance is None or not np.all(np.isfinite(covariance)):
            frame.covariance = None
            return
        rotate = np.eye(6)
        rotate[:3, :3] = T_parent_reference[:3, :3]
        frame.covariance = rotate @ np.asarray(covariance, dtype=float) @ rotate.T
