"""Rigid-body transforms following ``../shared/conventions.md``.

``T_a_b`` is a 4x4 homogeneous matrix mapping points in frame ``b`` to frame ``a``
(``p_a = T_a_b @ p_b``). Translations are in metres, angles in radians unless a
name ends in ``_deg``. Euler angles follow ROS ``static_transform_publisher``:
``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``. Quaternions are ``(x, y, z, w)``.

A small perturbation of a transform is the 6-vector every solver, covariance and export
uses (``TRANSFORM_PARAMETERS`` of :mod:`backend.core.result`): ``[dt (m, parent axes),
dr (rad, rotation vector about the child's axes)]``, so ``T = (R Exp(dr), t + dt)``
(:func:`params_between`, :func:`apply_params`).

All rotation maths goes through :mod:`scipy.spatial.transform`; nothing here is
hand-rolled beyond assembling the 4x4 matrix, :func:`skew` and :func:`right_jacobian`,
which scipy lacks (the solvers' analytic Jacobians need them).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.errors import InputError

R_BODY_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""Rotation taking optical axes (x right, y down, z forward) to body axes (x forward, y left, z up)."""
MAX_ROTATION_DEVIATION = 0.05
"""How far (max ``|R^T R - I|``) a given 3x3 may be from a rotation and still be projected onto one."""


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Assemble a 4x4 transform from a 3x3 rotation and a translation (m)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def invert(T_a_b: np.ndarray) -> np.ndarray:
    """Return ``T_b_a`` for a rigid ``T_a_b``, or for each of a stack of them (``(..., 4, 4)``)."""
    R_b_a = np.swapaxes(T_a_b[..., :3, :3], -1, -2)
    T_b_a = np.zeros(np.shape(T_a_b))
    T_b_a[..., :3, :3] = R_b_a
    T_b_a[..., :3, 3] = -np.einsum("...ij,...j->...i", R_b_a, T_a_b[..., :3, 3])
    T_b_a[..., 3, 3] = 1.0
    return T_b_a


def from_rvec_tvec(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """4x4 from an OpenCV Rodrigues vector (rad) and translation (m)."""
    R = Rotation.from_rotvec(np.asarray(rvec, dtype=float).reshape(3)).as_matrix()
    return make_T(R, tvec)


def to_rvec_tvec(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV Rodrigues vector (rad) and translation (m) of a 4x4 transform."""
    return Rotation.from_matrix(T[:3, :3]).as_rotvec(), T[:3, 3].copy()


def from_xyz_ypr(xyz_m: np.ndarray, ypr_rad: np.ndarray) -> np.ndarray:
    """4x4 from translation (m) and ROS yaw, pitch, roll (rad)."""
    R = Rotation.from_euler("ZYX", np.asarray(ypr_rad, dtype=float)).as_matrix()
    return make_T(R, xyz_m)


def to_xyz_ypr(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translation (m) and ROS yaw, pitch, roll (rad) of a 4x4 transform."""
    return T[:3, 3].copy(), Rotation.from_matrix(T[:3, :3]).as_euler("ZYX")


def to_quaternion_xyzw(T: np.ndarray) -> np.ndarray:
    """Rotation of ``T`` as a unit quaternion ``(x, y, z, w)``."""
    return Rotation.from_matrix(T[:3, :3]).as_quat()


def from_quaternion_xyzw(q_xyzw: np.ndarray, t_m: np.ndarray) -> np.ndarray:
    """4x4 from a quaternion ``(x, y, z, w)`` and translation (m)."""
    return make_T(Rotation.from_quat(np.asarray(q_xyzw, dtype=float)).as_matrix(), t_m)


def right_jacobian(omega: np.ndarray) -> np.ndarray:
    """SO(3) right Jacobian ``J_r`` of a rotation vector (rad): ``Exp(w + dw) ~ Exp(w) Exp(J_r(w) dw)``."""
    return right_jacobians(np.asarray(omega, float)[None])[0]


def right_jacobians(omegas: np.ndarray) -> np.ndarray:
    """(N, 3, 3) :func:`right_jacobian` of each of (N, 3) rotation vectors (rad)."""
    theta = np.linalg.norm(omegas, axis=1)
    W = skew(omegas)
    small = theta < 1e-6
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 0.5, (1 - np.cos(safe)) / safe**2)
    b = np.where(small, 1.0 / 6.0, (safe - np.sin(safe)) / safe**3)
    return np.eye(3) - a[:, None, None] * W + b[:, None, None] * W @ W


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Map an (N, 3) array of points from frame ``b`` into frame ``a``."""
    return points_b @ T_a_b[:3, :3].T + T_a_b[:3, 3]


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """``T_world_optical`` of a camera at ``eye`` (m) looking at ``target`` (m).

    The returned frame is an optical frame (x right, y down, z forward) with its
    image "up" as close to ``up`` as possible.
    """
    z = np.asarray(target, float) - np.asarray(eye, float)
    z /= np.linalg.norm(z)
    x = np.cross(z, -np.asarray(up, float))
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_T(np.column_stack([x, y, z]), eye)


def rotation_angle_deg(R: np.ndarray) -> float:
    """Magnitude of the rotation ``R`` in degrees."""
    return float(np.degrees(np.linalg.norm(Rotation.from_matrix(R).as_rotvec())))


def params_between(T_ref: np.ndarray, T: np.ndarray) -> np.ndarray:
    """``[t - t_ref (m, parent axes), rotvec(R_ref^T R) (rad, child axes)]`` of ``T`` about ``T_ref``."""
    return np.r_[T[:3, 3] - T_ref[:3, 3], Rotation.from_matrix(T_ref[:3, :3].T @ T[:3, :3]).as_rotvec()]


def apply_params(T_ref: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Inverse of :func:`params_between`: ``T_ref`` moved by ``p`` (6,) (m, rad)."""
    return make_T(T_ref[:3, :3] @ Rotation.from_rotvec(p[3:]).as_matrix(), T_ref[:3, 3] + p[:3])


def apply_params_many(T: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """:func:`apply_params` over stacks: poses (n, 4, 4) moved by steps (n, 6)."""
    moved = T.copy()
    moved[:, :3, :3] = T[:, :3, :3] @ Rotation.from_rotvec(steps[:, 3:]).as_matrix()
    moved[:, :3, 3] += steps[:, :3]
    return moved


def transform_error(T_estimate: np.ndarray, T_true: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis error of an estimate in the reported parameters: translation (m, parent axes)
    and rotation (deg, about the child's axes), as ``params_between(T_true, T_estimate)``."""
    p = params_between(T_true, T_estimate)
    return p[:3], np.degrees(p[3:])


def skew(v: np.ndarray) -> np.ndarray:
    """(N, 3, 3) cross-product matrices ``[v]x`` of (N, 3) vectors."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    return S - S.transpose(0, 2, 1)


def check_transform(T: Any, name: str) -> tuple[np.ndarray, float]:
    """A rigid 4x4 transform and how far its 3x3 was from a rotation (max ``|R^T R - I|``).

    A 3x3 within :data:`MAX_ROTATION_DEVIATION` of a rotation (e.g. a rounded or slightly scaled
    matrix from a manual tool) is projected onto the nearest rotation; anything else raises
    :class:`InputError` naming ``name``.
    """
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise InputError(f"expected a finite 4x4 transform, got shape {T.shape}", name)
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6):
        raise InputError(f"the last row of the 4x4 must be 0 0 0 1, got {T[3].tolist()}", name)
    R = T[:3, :3]
    deviation = float(np.abs(R.T @ R - np.eye(3)).max())
    if deviation > MAX_ROTATION_DEVIATION or np.linalg.det(R) <= 0:
        raise InputError(f"the upper-left 3x3 is not a rotation (max |R^T R - I| = {deviation:.3g}, "
                         f"det {np.linalg.det(R):.3g}); expected an orthonormal matrix with det +1", name)
    return make_T(Rotation.from_matrix(R).as_matrix(), T[:3, 3]), deviation


def rotation_about_line(axis: np.ndarray, point: np.ndarray, angle_rad: float) -> np.ndarray:
    """4x4 rotation by ``angle_rad`` (rad) about the line through ``point`` (m) along the unit ``axis``, both in the
    frame the result acts in (a pan head turning a camera, a door on its hinge)."""
    R = Rotation.from_rotvec(float(angle_rad) * np.asarray(axis, dtype=float)).as_matrix()
    point = np.asarray(point, dtype=float)
    return make_T(R, point - R @ point)


def rotate_about_axis(axis: np.ndarray, angles_rad: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Rotate each row of ``vectors`` (N, 3) about the unit ``axis`` by its own angle (N,) (rad)."""
    rotvecs = np.outer(np.asarray(angles_rad, dtype=float), np.asarray(axis, dtype=float))
    return Rotation.from_rotvec(rotvecs).apply(np.asarray(vectors, dtype=float))
