"""Rigid-body transforms following ``../shared/conventions.md``.

``T_a_b`` is a 4x4 homogeneous matrix mapping points in frame ``b`` to frame ``a``
(``p_a = T_a_b @ p_b``). Translations are in metres, angles in radians unless a
name ends in ``_deg``. Euler angles follow ROS ``static_transform_publisher``:
``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``. Quaternions are ``(x, y, z, w)``.

All rotation maths goes through :mod:`scipy.spatial.transform`; nothing here is
hand-rolled beyond assembling the 4x4 matrix and :func:`right_jacobian`, which scipy lacks
(the solvers' analytic Jacobians need it).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Assemble a 4x4 transform from a 3x3 rotation and a translation (m)."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(t, dtype=float).reshape(3)
    return T


def invert(T_a_b: np.ndarray) -> np.ndarray:
    """Return ``T_b_a`` for a rigid ``T_a_b``."""
    R = T_a_b[:3, :3]
    return make_T(R.T, -R.T @ T_a_b[:3, 3])


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
    theta = float(np.linalg.norm(omega))
    W = np.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]], [-omega[1], omega[0], 0.0]])
    if theta < 1e-6:
        a, b = 0.5, 1.0 / 6.0
    else:
        a, b = (1 - np.cos(theta)) / theta**2, (theta - np.sin(theta)) / theta**3
    return np.eye(3) - a * W + b * W @ W


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
