"""Self-calibrating bundle adjustment in the photogrammetric model (:mod:`backend.core.photogrammetric`).

OpenCV cannot fit this model (it has no affine terms), so the solve is a Levenberg-Marquardt over the interior
orientation ``[c, xp, yp, K1, K2, K3, P1, P2, A1, A2]`` and every view's pose, with the analytic Jacobian of
:func:`project`, by the hand-written :func:`~backend.core.schur_lm.levenberg_marquardt`: SciPy's solvers do not use
the bundle's structure: with 48 views MINPACK's dense QR took 1.4 s a solve (a minute for the view jackknife) and
TRF with LSMR 5 s, where eliminating the poses (the Schur complement) takes 0.2 s to the same solution (RMS equal
to 1e-14 px).
It starts from OpenCV's five-coefficient solve with ``fx = fy``, which is this model with ``A1 = A2 = 0`` exactly,
so it can only fit better.

The report (:func:`report`) gives every parameter in pixels and, with the pixel size, in mm, with its sigma, and
the correlations of the interior orientation with each view's exterior orientation (``X0, Y0, Z0``: the
projection centre in the board's frame, m; ``omega, phi, kappa``: ``R_camera_board = Rz(kappa) Ry(phi)
Rx(omega)``, deg), as photogrammetric packages print them.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from backend.core import photogrammetric
from backend.core.camera import CameraIntrinsics
from backend.core.camera_conversion import convert, interior_orientation, photogrammetric_camera
from backend.core.schur_lm import levenberg_marquardt

INTERIOR = ["c", "xp", "yp", *photogrammetric.NAMES]
"""The interior orientation's parameters, in the order of the covariance's free intrinsics."""
EXTERIOR = ["X0", "Y0", "Z0", "omega", "phi", "kappa"]
"""A view's exterior orientation: projection centre in the board's frame (m) and rotation angles (deg)."""
STEP = 1e-7
"""Central-difference step of the exterior orientation's Jacobian by the pose (rad, m)."""


def project(camera: CameraIntrinsics, object_points: np.ndarray, rvec: np.ndarray,
            tvec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of board points (N, 3, m) at pose ``rvec, tvec`` (board to camera), and the (2N, 17)
    Jacobian with columns ``[rvec(3), tvec(3), fx, fy, cx, cy, K1, K2, K3, P1, P2, A1, A2]``, rows u, v
    interleaved (OpenCV's ``projectPoints`` layout; ``c`` is ``fx`` and ``fy`` together)."""
    points = np.asarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
    normalised, J_normalised = cv2.projectPoints(points, np.asarray(rvec, float), np.asarray(tvec, float),
                                                 np.eye(3), None)
    x, y = normalised.reshape(-1, 2).T
    fx, fy = camera.K[0, 0], camera.K[1, 1]
    xbar, ybar = fx * x, fy * y
    u, v = photogrammetric.distort(xbar, ybar, camera.dist)
    D = photogrammetric.distort_jacobian(xbar, ybar, camera.dist)  # (N, 2, 2) by (x̄, ȳ)
    n = len(x)
    J = np.zeros((n, 2, 17))
    pose = J_normalised[:, :6].reshape(n, 2, 6)  # d(x, y) / d(rvec, tvec)
    J[:, :, :6] = D[:, :, :1] * fx * pose[:, None, 0] + D[:, :, 1:] * fy * pose[:, None, 1]
    J[:, :, 6] = D[:, :, 0] * x[:, None]
    J[:, :, 7] = D[:, :, 1] * y[:, None]
    J[:, 0, 8] = 1.0
    J[:, 1, 9] = 1.0
    J[:, :, 10:] = photogrammetric.coefficient_jacobian(xbar, ybar)
    pixels = np.column_stack([u + camera.K[0, 2], v + camera.K[1, 2]])
    return pixels, J.reshape(2 * n, 17)


def bundle_adjust(camera: CameraIntrinsics, object_points: list[np.ndarray], image_points: list[np.ndarray],
                  rvecs: list[np.ndarray], tvecs: list[np.ndarray], fix_interior: bool = False):
    """Least-squares pixel residuals over the interior orientation (unless ``fix_interior``) and the poses.

    ``camera`` (photogrammetric) and the poses are the start. Returns ``(K, dist, rvecs, tvecs)`` as OpenCV's
    solvers do (``rvecs``, ``tvecs``: lists of (3, 1) arrays).
    """
    n_views = len(object_points)
    n_interior = 0 if fix_interior else len(INTERIOR)
    observed = [np.asarray(p, float).reshape(-1, 2) for p in image_points]

    def unpack(params: np.ndarray) -> tuple[CameraIntrinsics, np.ndarray]:
        poses = params[n_interior:].reshape(n_views, 6)
        if fix_interior:
            return camera, poses
        return photogrammetric_camera(camera, params[:n_interior]), poses

    def evaluate(params: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
        """Each view's residuals (2N,), Jacobian by the interior orientation (2N, 10 or 0) and by its pose (2N, 6)."""
        model, poses = unpack(params)
        residuals, interior, pose = [], [], []
        for i, (obj, img) in enumerate(zip(object_points, observed, strict=True)):
            pixels, J = project(model, obj, poses[i, :3], poses[i, 3:])
            residuals.append((pixels - img).ravel())
            interior.append(np.zeros((len(J), 0)) if fix_interior else np.column_stack([J[:, 6] + J[:, 7], J[:, 8:]]))
            pose.append(J[:, :6])
        return residuals, interior, pose

    start = np.concatenate([
        [] if fix_interior else interior_orientation(camera),
        np.column_stack([np.reshape(rvecs, (n_views, 3)), np.reshape(tvecs, (n_views, 3))]).ravel()])
    solution_x = levenberg_marquardt(evaluate, start, n_interior)
    model, poses = unpack(solution_x)
    return model.K, model.dist, [p[:3].reshape(3, 1) for p in poses], [p[3:].reshape(3, 1) for p in poses]


def start_from_opencv(K: np.ndarray, dist: np.ndarray, size: tuple[int, int]) -> CameraIntrinsics:
    """The photogrammetric camera of an OpenCV ``pinhole-radtan`` solve (exact when ``fx = fy``)."""
    return convert(CameraIntrinsics("pinhole-radtan", size[0], size[1], K, dist), "photogrammetric").camera


def exterior_orientation(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """``[X0, Y0, Z0 (m), omega, phi, kappa (deg)]`` of a board-to-camera pose (:data:`EXTERIOR`)."""
    R = Rotation.from_rotvec(np.ravel(rvec))
    kappa, phi, omega = R.as_euler("ZYX", degrees=True)
    return np.r_[-R.inv().apply(np.ravel(tvec)), omega, phi, kappa]


def _exterior_jacobian(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """(6, 6) derivatives of :func:`exterior_orientation` by ``[rvec, tvec]`` (central differences)."""
    pose = np.r_[np.ravel(rvec), np.ravel(tvec)]
    columns = []
    for k in range(6):
        step = np.zeros(6)
        step[k] = STEP
        plus, minus = exterior_orientation(*np.split(pose + step, 2)), exterior_orientation(*np.split(pose - step, 2))
        columns.append((plus - minus) / (2 * STEP))
    return np.column_stack(columns)


def interior_exterior_correlation(cov_all: np.ndarray, rvecs: list[np.ndarray], tvecs: list[np.ndarray]) -> np.ndarray:
    """(views, 10, 6) correlations of the interior orientation (:data:`INTERIOR`) with each view's exterior
    orientation (:data:`EXTERIOR`), from the covariance over ``[free intrinsics (10), rvec and tvec per view]``."""
    n = len(INTERIOR)
    interior_sigma = np.sqrt(np.diag(cov_all)[:n])
    tables = []
    for i, (rvec, tvec) in enumerate(zip(rvecs, tvecs, strict=True)):
        G = _exterior_jacobian(rvec, tvec)
        block = slice(n + 6 * i, n + 6 * i + 6)
        cross = cov_all[:n, block] @ G.T
        exterior_sigma = np.sqrt(np.diag(G @ cov_all[block, block] @ G.T))
        tables.append(cross / np.outer(interior_sigma, exterior_sigma))
    return np.clip(np.array(tables), -1.0, 1.0)


def report(camera: CameraIntrinsics, std: np.ndarray, correlation: np.ndarray, cov_all: np.ndarray,
           rvecs: list[np.ndarray], tvecs: list[np.ndarray], view_names: list[str],
           pixel_size_um: float | None) -> dict[str, Any]:
    """The photogrammetric block of an intrinsics result.

    ``std`` is the reported 1-sigma of :data:`INTERIOR` (px units), ``correlation`` their (10, 10) correlation,
    ``cov_all`` the analytic covariance over the interior orientation and the used views' poses. Gives each
    parameter in px and, with ``pixel_size_um``, in mm (``xp``, ``yp`` from the image centre); the correlation
    table; the interior-exterior correlations per view and the largest of each pair over the views; and the
    nearest OpenCV camera with the residual over the image.
    """
    values = interior_orientation(camera)
    powers = np.array([1, 1, 1, *(photogrammetric.PIXEL_POWERS[n] for n in photogrammetric.NAMES)], float)
    centre = np.array([0.0, (camera.width - 1) / 2, (camera.height - 1) / 2, *np.zeros(7)])
    parameters = {}
    for k, name in enumerate(INTERIOR):
        entry = {"value_px": float(values[k]), "sigma_px": float(std[k]), "unit_px": _unit("px", powers[k])}
        if pixel_size_um:
            scale = (pixel_size_um / 1000.0) ** powers[k]
            entry |= {"value_mm": float((values[k] - centre[k]) * scale), "sigma_mm": float(std[k] * scale),
                      "unit_mm": _unit("mm", powers[k])}
        parameters[name] = entry
    per_view = interior_exterior_correlation(cov_all, rvecs, tvecs)
    largest = np.take_along_axis(per_view, np.abs(per_view).argmax(axis=0)[None], axis=0)[0]
    return {
        "pixel_size_um": pixel_size_um,
        "axes": "pixel axes (x right, y down); xp, yp in mm are from the image centre",
        "parameters": parameters,
        "correlation": {"names": INTERIOR, "matrix": np.round(correlation, 4).tolist()},
        "interior_exterior": {
            "interior": INTERIOR, "exterior": EXTERIOR,
            "largest": np.round(largest, 4).tolist(),
            "per_view": [{"image": name, "matrix": np.round(table, 4).tolist()}
                         for name, table in zip(view_names, per_view, strict=True)],
        },
        "opencv": convert(camera, "pinhole-radtan").to_dict(),
    }


def _unit(length: str, power: float) -> str:
    return "1" if power == 0 else length if power == 1 else f"{length}^{int(power)}"
