"""A camera's projection of board points with its Jacobian by the pose and the intrinsics, for every lens model."""

from __future__ import annotations

import cv2
import numpy as np

from backend.calib.intrinsics import photogrammetric
from backend.core.camera import CameraIntrinsics
from backend.core.splined import project_with_jacobians


def project_board(camera: CameraIntrinsics, object_points: np.ndarray, rvec, tvec) -> tuple[np.ndarray, np.ndarray]:
    """Pixels (N, 2) of board points (N, 3, m) at the pose ``rvec, tvec`` (board to camera) and the projection's
    Jacobian, columns in the order [rvec(3), tvec(3), fx, fy, cx, cy, dist...] (2N rows, u and v interleaved):
    OpenCV's analytic ``projectPoints`` (or ``fisheye.projectPoints``, reordered), the photogrammetric and splined
    models' own."""
    if camera.model == "photogrammetric":
        return photogrammetric.project(camera, object_points, rvec, tvec)
    if camera.spline is not None:
        return _project_splined(camera, object_points, rvec, tvec)
    pts = object_points.astype(np.float64).reshape(-1, 1, 3)
    if camera.is_fisheye:
        uv, J = cv2.fisheye.projectPoints(pts, rvec, tvec, camera.K, camera.dist[:4])
        # fisheye order is [f(2), c(2), k(4), r(3), t(3), alpha]; reorder to the pinhole order.
        J = np.hstack([J[:, 8:14], J[:, 0:8]])
    else:
        uv, J = cv2.projectPoints(pts, rvec, tvec, camera.K, camera.dist)
        J = J[:, : 10 + camera.dist.size]
    return uv.reshape(-1, 2), J


def _project_splined(camera: CameraIntrinsics, object_points: np.ndarray, rvec, tvec) -> tuple[np.ndarray, np.ndarray]:
    """:func:`project_board` for the splined model: ``p = R X + t``, the pose's columns through ``dq/dp``
    (``dR/drvec`` from ``cv2.Rodrigues``)."""
    R, dR_drvec = cv2.Rodrigues(np.asarray(rvec, float).reshape(3, 1))
    X = np.asarray(object_points, float).reshape(-1, 3)
    q, dq_dp, dq_dintrinsics = project_with_jacobians(camera.spline, camera.parameters,
                                                      X @ R.T + np.asarray(tvec, float).ravel())
    dp_drvec = np.einsum("irc,nc->nri", dR_drvec.reshape(3, 3, 3), X)  # cv2's dR[i, 3 r + c] = dR[r, c] / drvec_i
    J = np.concatenate([dq_dp @ dp_drvec, dq_dp, dq_dintrinsics], axis=2)
    return q, J.reshape(2 * len(X), -1)
