"""Geometry of a 2D scanner swept into 3D by a servo (the "Hokuyo on a servo" rig).

Frames (``../shared/conventions.md``: ``T_a_b`` maps points in ``b`` into ``a``; metres, radians):

``mount``
    Fixed to the rig (the servo's housing). Its origin lies on the servo axis; the axis runs
    through it along the unit vector :attr:`SweepGeometry.axis` (default x forward, so the
    scanner rolls about x). The rig places ``mount`` with a ``T_base_mount`` of its own.
``servo``
    Turns with the servo horn about the axis. At a corrected servo angle of zero it coincides
    with ``mount``: ``T_mount_servo(angle) = Rot(axis, angle + zero_offset_rad)``, translation 0.
``scanner``
    The 2D scanner's frame (optical centre at its origin, scan plane its x-y plane, z = 0 for
    its points), bolted to the horn: ``T_servo_scanner`` is the offset between the servo axis and
    the optical centre (translation, m) plus the scanner's small mounting rotation.

So every point of a scan taken at servo reading ``angle`` (rad, what the servo reports) is
``p_mount = R_axis(angle + zero_offset_rad) @ T_servo_scanner @ p_scanner``.

What a sweep can tell about the geometry: the part of ``T_servo_scanner``'s translation along
the axis shifts the whole cloud rigidly, and a rotation of the scanner about the axis is the same
as a zero offset; the zero offset itself turns the whole cloud about the axis. A sweep of planes
pins the offset perpendicular to the axis and tilts of the scanner about the two perpendicular
directions; the zero offset needs an outside reference (a level floor) — see
:mod:`backend.calib.sweep.solver`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.transforms import make_T, rotate_about_axis

ScanAtAngle = tuple[float, np.ndarray, np.ndarray | None]
"""One step of a sweep: (servo angle as read (rad), points (N, 3) in the scanner frame (m),
intensity (N,) or None)."""


def axis_rotation(axis: np.ndarray, angle_rad: float) -> np.ndarray:
    """3x3 rotation about the unit ``axis`` by ``angle_rad`` (rad)."""
    return Rotation.from_rotvec(float(angle_rad) * np.asarray(axis, dtype=float)).as_matrix()


@dataclass
class SweepGeometry:
    """How a swept 2D scanner sits on its servo (frames in the module docstring)."""

    axis: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0]))
    """(3,) unit vector of the servo axis in the mount frame (default x forward: the scanner rolls about x)."""
    T_servo_scanner: np.ndarray = field(default_factory=lambda: np.eye(4))
    """4x4: the scanner's optical centre and orientation in the servo frame (translation in m)."""
    zero_offset_rad: float = 0.0
    """Added to every servo reading (rad): the reading at which the servo frame is not yet aligned with mount."""

    def __post_init__(self) -> None:
        axis = np.asarray(self.axis, dtype=float).reshape(3)
        norm = np.linalg.norm(axis)
        if not np.isfinite(norm) or norm < 1e-9:
            raise ValueError(f"the servo axis must be a non-zero vector, got {axis.tolist()}")
        self.axis = axis / norm
        T = np.asarray(self.T_servo_scanner, dtype=float)
        if T.shape != (4, 4) or not np.isfinite(T).all():
            raise ValueError(f"T_servo_scanner must be a finite 4x4, got shape {T.shape}")
        self.T_servo_scanner = T.copy()
        self.zero_offset_rad = float(self.zero_offset_rad)

    # ------------------------------------------------------------------ transforms
    def T_mount_servo(self, angle_rad: float) -> np.ndarray:
        """4x4 pose of the servo frame in mount at servo reading ``angle_rad`` (rad)."""
        return make_T(axis_rotation(self.axis, angle_rad + self.zero_offset_rad), np.zeros(3))

    def T_mount_scanner(self, angle_rad: float) -> np.ndarray:
        """4x4 pose of the scanner in mount at servo reading ``angle_rad`` (rad)."""
        return self.T_mount_servo(angle_rad) @ self.T_servo_scanner

    # ------------------------------------------------------------------ assembly
    def transform(self, points_scanner: np.ndarray, servo_angles_rad: np.ndarray) -> np.ndarray:
        """Map scanner-frame points (N, 3) (m), each taken at its own servo reading (N,) (rad), into mount."""
        p = np.asarray(points_scanner, dtype=float) @ self.T_servo_scanner[:3, :3].T + self.T_servo_scanner[:3, 3]
        return rotate_about_axis(self.axis, np.asarray(servo_angles_rad, dtype=float) + self.zero_offset_rad, p)

    def to_scanner(self, points_mount: np.ndarray, servo_angles_rad: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`transform`: mount-frame points (N, 3) (m), each taken at its own servo
        reading (N,) (rad), back into the scanner frame (m)."""
        p = rotate_about_axis(self.axis, -(np.asarray(servo_angles_rad, dtype=float) + self.zero_offset_rad),
                              np.asarray(points_mount, dtype=float).reshape(-1, 3))
        return (p - self.T_servo_scanner[:3, 3]) @ self.T_servo_scanner[:3, :3]

    def assemble(self, scans: Sequence[ScanAtAngle]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """One 3D cloud from a sweep, vectorised over all points.

        Args:
            scans: per servo step ``(servo angle read (rad), points (N, 3) scanner frame (m),
                intensity (N,) or None)``.

        Returns:
            ``points_mount`` (M, 3) float64 (m), ``intensity`` (M,) float32 (0 where a scan had
            none) and the servo reading of each point (M,) float64 (rad), in scan order.
        """
        points, angles, intensity = stack_scans(scans)
        return self.transform(points, angles), intensity, angles

    # ------------------------------------------------------------------ settings
    def to_dict(self) -> dict[str, Any]:
        """JSON-ready settings: ``axis``, ``T_servo_scanner`` (4x4 nested lists, m) and ``zero_offset_rad``."""
        return {"axis": self.axis.tolist(), "T_servo_scanner": self.T_servo_scanner.tolist(),
                "zero_offset_rad": self.zero_offset_rad}

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> SweepGeometry:
        """The inverse of :meth:`to_dict`; missing keys take the defaults, ``None`` gives the default geometry."""
        data = data or {}
        unknown = set(data) - {"axis", "T_servo_scanner", "zero_offset_rad"}
        if unknown:
            raise ValueError(f"unknown sweep geometry keys {sorted(unknown)}; "
                             f"expected axis, T_servo_scanner, zero_offset_rad")
        kwargs: dict[str, Any] = {}
        if "axis" in data:
            kwargs["axis"] = np.asarray(data["axis"], dtype=float)
        if "T_servo_scanner" in data:
            kwargs["T_servo_scanner"] = np.asarray(data["T_servo_scanner"], dtype=float)
        if "zero_offset_rad" in data:
            kwargs["zero_offset_rad"] = float(data["zero_offset_rad"])
        return cls(**kwargs)

    def copy(self) -> SweepGeometry:
        return SweepGeometry(self.axis.copy(), self.T_servo_scanner.copy(), self.zero_offset_rad)


def stack_scans(scans: Sequence[ScanAtAngle]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Concatenate a sweep: scanner-frame points (M, 3) (m), servo reading per point (M,) (rad),
    intensity (M,) float32 (0 where a scan had none)."""
    pts, ang, inten = [], [], []
    for k, scan in enumerate(scans):
        if len(scan) != 3:
            raise ValueError(f"scan {k}: expected (servo_angle_rad, points, intensity), got {len(scan)} items")
        angle, points, intensity = scan
        p = np.asarray(points, dtype=float).reshape(-1, 3)
        pts.append(p)
        ang.append(np.full(len(p), float(angle)))
        inten.append(np.zeros(len(p), np.float32) if intensity is None
                     else np.asarray(intensity, dtype=np.float32).reshape(len(p)))
    if not pts:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.float32)
    return np.vstack(pts), np.concatenate(ang), np.concatenate(inten)


SWEEP_META_KEYS = ("servo_angles_rad", "step_counts", "geometry")
"""The keys of a swept scanner's sample meta (:class:`~backend.devices.dynamixel_servo.SweptScanner`) a
stored capture needs to give its raw scans back."""


def scans_from_capture(points_mount: np.ndarray, intensity: np.ndarray | None,
                       meta: dict[str, Any]) -> list[ScanAtAngle]:
    """The raw sweep of a stored swept capture: per servo step ``(servo angle read (rad), points (N, 3) in
    the scanner frame (m), intensity (N,) or None)``, as :meth:`SweepGeometry.assemble` and the sweep
    calibration take it.

    Args:
        points_mount: (M, 3) the capture's points in the mount frame (m), in scan order, assembled with
            ``meta["geometry"]``. Stored as float32 they come back to about a micrometre at 30 m.
        intensity: (M,) or None.
        meta: the capture's meta with :data:`SWEEP_META_KEYS`: ``servo_angles_rad`` (per step, rad),
            ``step_counts`` (points per step) and ``geometry`` (the :class:`SweepGeometry` dict used).

    Raises ``ValueError`` naming the missing or inconsistent key.
    """
    missing = [k for k in SWEEP_META_KEYS if k not in meta]
    if missing:
        raise ValueError(f"not a swept scanner capture: its meta lacks {', '.join(missing)}")
    angles = np.asarray(meta["servo_angles_rad"], dtype=float).reshape(-1)
    counts = np.asarray(meta["step_counts"], dtype=np.int64).reshape(-1)
    points = np.asarray(points_mount, dtype=float).reshape(-1, 3)
    if len(counts) != len(angles) or (counts < 0).any() or counts.sum() != len(points):
        raise ValueError(f"step_counts ({len(counts)} steps, {int(counts.sum())} points) do not match "
                         f"servo_angles_rad ({len(angles)} steps) and the cloud ({len(points)} points)")
    geometry = SweepGeometry.from_dict(meta["geometry"])
    points_scanner = geometry.to_scanner(points, np.repeat(angles, counts))
    bounds = np.cumsum(counts)[:-1]
    inten = [None] * len(angles) if intensity is None else np.split(np.asarray(intensity, np.float32), bounds)
    return [(float(a), p, i) for a, p, i in zip(angles, np.split(points_scanner, bounds), inten, strict=True)]


@dataclass
class SweepImage:
    """A LiDAR image of a sweep: one row per servo step, one column per scan-angle bin."""

    intensity: np.ndarray
    """(H, W) uint8 mean intensity per cell, stretched so the 1st..99th percentile spans 1..255; 0 = no return."""
    range: np.ndarray
    """(H, W) uint8 range per cell, near = bright (1..255, linear in range between the 1st and 99th
    percentile); 0 = no return."""
    range_m: np.ndarray
    """(H, W) float32 mean range per cell (m, from the mount origin); NaN = no return."""
    servo_angles_rad: np.ndarray
    """(H,) servo reading at each row's centre (rad)."""
    scan_angles_rad: np.ndarray
    """(W,) scan angle at each column's centre (rad, counter-clockwise from the scanner's x)."""


def _stretch(values: np.ndarray, valid: np.ndarray, lo_hi: tuple[float, float] | None, invert: bool) -> np.ndarray:
    out = np.zeros(values.shape, np.uint8)
    if not valid.any():
        return out
    v = values[valid]
    lo, hi = lo_hi if lo_hi is not None else (float(np.percentile(v, 1)), float(np.percentile(v, 99)))
    if hi <= lo:
        hi = lo + 1e-9
    scaled = np.clip((v - lo) / (hi - lo), 0.0, 1.0)
    if invert:
        scaled = 1.0 - scaled
    out[valid] = (1 + np.round(scaled * 254)).astype(np.uint8)
    return out


def intensity_image(points: np.ndarray, intensity: np.ndarray | None, servo_angles: np.ndarray,
                    scan_angles: np.ndarray, shape: tuple[int, int],
                    servo_range_rad: tuple[float, float] | None = None,
                    scan_range_rad: tuple[float, float] | None = None,
                    intensity_range: tuple[float, float] | None = None) -> SweepImage:
    """Render a sweep as a 2D LiDAR image indexed by (servo step, scan angle).

    Args:
        points: (M, 3) points (m), mount frame (only their distance from the origin is used).
        intensity: (M,) return intensity (any units) or None (the intensity image is then empty).
        servo_angles: (M,) servo reading of each point (rad).
        scan_angles: (M,) angle of each point within its scan (rad), e.g. ``atan2(y, x)`` of the
            scanner-frame point.
        shape: ``(rows, cols)``: rows bin the servo angle (use the number of steps for one row
            per step), columns the scan angle.
        servo_range_rad, scan_range_rad: the angles (rad) the first and last row / column are
            centred on; default the min and max of the data.
        intensity_range: intensities mapped to 1 and 255; default the 1st and 99th percentile.

    Several points in one cell are averaged.
    """
    rows, cols = int(shape[0]), int(shape[1])
    if rows < 1 or cols < 1:
        raise ValueError(f"image shape must be positive, got {shape}")
    pts = np.asarray(points, dtype=float).reshape(-1, 3)
    servo = np.asarray(servo_angles, dtype=float).reshape(-1)
    scan = np.asarray(scan_angles, dtype=float).reshape(-1)
    if not (len(servo) == len(scan) == len(pts)):
        raise ValueError(f"points ({len(pts)}), servo_angles ({len(servo)}) and scan_angles ({len(scan)}) "
                         f"must have the same length")

    def centres(values: np.ndarray, n: int, given: tuple[float, float] | None) -> tuple[np.ndarray, np.ndarray]:
        lo, hi = given if given is not None else ((float(values.min()), float(values.max())) if len(values)
                                                  else (0.0, 0.0))
        c = np.linspace(lo, hi, n)
        if n == 1:
            return c, np.zeros(len(values), np.int64)
        idx = np.round((values - lo) / (hi - lo) * (n - 1)) if hi > lo else np.zeros(len(values))
        return c, idx.astype(np.int64)

    row_c, r = centres(servo, rows, servo_range_rad)
    col_c, c = centres(scan, cols, scan_range_rad)
    inside = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
    cell = r[inside] * cols + c[inside]
    counts = np.bincount(cell, minlength=rows * cols).reshape(rows, cols)
    valid = counts > 0
    rng = np.bincount(cell, np.linalg.norm(pts[inside], axis=1), minlength=rows * cols).reshape(rows, cols)
    range_m = np.full((rows, cols), np.nan, np.float32)
    range_m[valid] = rng[valid] / counts[valid]
    inten_img = np.zeros((rows, cols), np.uint8)
    if intensity is not None and len(pts):
        inten = np.asarray(intensity, dtype=float).reshape(-1)
        s = np.bincount(cell, inten[inside], minlength=rows * cols).reshape(rows, cols)
        mean = np.zeros((rows, cols))
        mean[valid] = s[valid] / counts[valid]
        inten_img = _stretch(mean, valid, intensity_range, invert=False)
    range_img = _stretch(np.nan_to_num(range_m.astype(float)), valid, None, invert=True)
    return SweepImage(intensity=inten_img, range=range_img, range_m=range_m, servo_angles_rad=row_c,
                      scan_angles_rad=col_c)
