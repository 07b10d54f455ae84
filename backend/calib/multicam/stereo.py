"""Checks of a calibrated stereo pair: rectification, a rectified preview and epipolar errors.

Frames and units follow ``../shared/conventions.md``: both cameras have optical
frames (x right, y down, z forward), ``T_left_right`` (4x4, metres) maps points in
the right camera's frame into the left camera's, pixels follow OpenCV (centre of
the top-left pixel is (0, 0)) and every error is in pixels.

OpenCV's convention is the other way round: ``cv2.stereoCalibrate`` and
``cv2.stereoRectify`` take and return ``R, T`` mapping points in the *first*
camera's frame into the *second*'s, i.e. ``T_right_left = inv(T_left_right)``.
This module converts at the OpenCV boundary and nowhere else.

- :func:`rectify` wraps ``cv2.stereoRectify`` / ``cv2.initUndistortRectifyMap``
  (``cv2.fisheye.stereoRectify`` / ``cv2.fisheye.initUndistortRectifyMap`` for
  ``fisheye-equidistant``) with ``CALIB_ZERO_DISPARITY``;
- :func:`rectified_preview` is the picture of OpenCV's ``samples/cpp/stereo_calib.cpp``:
  both rectified images side by side with lines along the rows, on which matching
  features should sit;
- :func:`epipolar_errors` is that sample's check without rectifying: the distance
  of each point to the epipolar line of its partner, on undistorted pixels,
  through ``F = K_r^-T [t]x R K_l^-1`` built from ``T_right_left = (R, t)``;
- :func:`rectified_row_errors` is the same question asked after rectification:
  how far apart the two rows of a correspondence are.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.transforms import invert

LINE_COLOUR_BGR = (0, 255, 0)
"""Colour of the preview's epipolar lines (green, as in OpenCV's stereo_calib sample)."""


@dataclass
class Rectification:
    """A stereo pair's rectification: rotations, projections and remap tables.

    ``R1`` (``R2``) rotates points in the left (right) optical frame into the left
    (right) rectified frame; ``P1`` and ``P2`` (3x4, px; the translation column in
    px times metres) project rectified-frame points into the rectified images, and
    ``Q`` (4x4) maps ``[u, v, disparity_px, 1]`` to homogeneous points in the left
    rectified frame (metres). ``*_map_x``/``*_map_y`` (float32, height x width) give
    for each rectified pixel the source pixel, for ``cv2.remap``.
    """

    left: CameraIntrinsics
    right: CameraIntrinsics
    T_left_right: np.ndarray
    """Maps points in the right optical frame into the left one (m)."""
    alpha: float
    """Free scaling (``stereoRectify``'s ``alpha``, the fisheye ``balance``): 0 keeps only valid pixels, 1 all."""
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    Q: np.ndarray
    left_map_x: np.ndarray
    left_map_y: np.ndarray
    right_map_x: np.ndarray
    right_map_y: np.ndarray
    baseline_m: float
    """Distance between the two optical centres (m)."""

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) of both rectified images (px)."""
        return self.left.image_size

    @property
    def vertical(self) -> bool:
        """True if the cameras sit one above the other (rectified columns, not rows, correspond)."""
        return bool(abs(self.P2[1, 3]) > abs(self.P2[0, 3]))

    def rectify_images(self, left_image: np.ndarray, right_image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Both images remapped into the rectified views (bilinear); sizes must match the cameras."""
        for image, camera, side in ((left_image, self.left, "left"), (right_image, self.right, "right")):
            height, width = np.asarray(image).shape[:2]
            if (width, height) != camera.image_size:
                raise InputError(
                    f"the {side} image is {width}x{height} px but its camera is {camera.width}x{camera.height}",
                    f"{side}_image",
                )
        left = cv2.remap(left_image, self.left_map_x, self.left_map_y, cv2.INTER_LINEAR)
        right = cv2.remap(right_image, self.right_map_x, self.right_map_y, cv2.INTER_LINEAR)
        return left, right

    def rectify_points(self, left_px: np.ndarray, right_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rectified pixels (N, 2) of distorted left and right pixels (N, 2).

        Same as ``cv2.undistortPoints(px, K, D, R1, P1)``, but through the camera's
        own converged undistortion (:meth:`CameraIntrinsics.undistort_points`).
        """
        return _rectified(self.left, self.R1, self.P1, left_px), _rectified(self.right, self.R2, self.P2, right_px)


def rectify(left: CameraIntrinsics, right: CameraIntrinsics, T_left_right: np.ndarray,
            alpha: float = 0) -> Rectification:
    """Rectify a calibrated pair whose right camera sits at ``T_left_right`` (maps right into left, m).

    Both cameras must have the same model and image size. ``alpha`` in [0, 1] is
    ``cv2.stereoRectify``'s free scaling (0: every rectified pixel is valid, 1: every
    source pixel is kept; -1: OpenCV's default) and, for fisheye cameras,
    ``cv2.fisheye.stereoRectify``'s ``balance`` (-1 is then 0). Principal points
    are made equal (``CALIB_ZERO_DISPARITY``), so disparity is ``u_left - u_right``.
    """
    if left.model != right.model:
        raise InputError(f"both cameras must have one model; left is {left.model}, right is {right.model}", "right")
    if left.image_size != right.image_size:
        raise InputError(
            f"both cameras must have one image size; left is {left.width}x{left.height} px, "
            f"right is {right.width}x{right.height} px", "right")
    if not (alpha == -1 or 0 <= alpha <= 1):
        raise InputError(f"alpha is {alpha!r}; expected a number in [0, 1] or -1 (OpenCV's default)", "alpha")
    T_left_right = np.asarray(T_left_right, dtype=float).reshape(4, 4)
    T_right_left = invert(T_left_right)  # OpenCV's (R, T): first (left) camera into the second (right)
    R, t = np.ascontiguousarray(T_right_left[:3, :3]), T_right_left[:3, 3].reshape(3, 1).copy()
    size = left.image_size
    if left.is_fisheye:
        R1, R2, P1, P2, Q = cv2.fisheye.stereoRectify(
            left.K, left.dist[:4], right.K, right.dist[:4], size, R, t, cv2.CALIB_ZERO_DISPARITY,
            newImageSize=size, balance=max(float(alpha), 0.0), fov_scale=1.0)
        init = cv2.fisheye.initUndistortRectifyMap
    else:
        R1, R2, P1, P2, Q, _, _ = cv2.stereoRectify(
            left.K, left.dist, right.K, right.dist, size, R, t, flags=cv2.CALIB_ZERO_DISPARITY, alpha=float(alpha))
        init = cv2.initUndistortRectifyMap
    left_map_x, left_map_y = init(left.K, _cv_dist(left), R1, P1, size, cv2.CV_32FC1)
    right_map_x, right_map_y = init(right.K, _cv_dist(right), R2, P2, size, cv2.CV_32FC1)
    return Rectification(
        left=left, right=right, T_left_right=T_left_right, alpha=float(alpha),
        R1=R1, R2=R2, P1=P1, P2=P2, Q=Q,
        left_map_x=left_map_x, left_map_y=left_map_y, right_map_x=right_map_x, right_map_y=right_map_y,
        baseline_m=float(np.linalg.norm(t)),
    )


def rectified_preview(rect: Rectification, left_image: np.ndarray, right_image: np.ndarray,
                      line_spacing_px: int = 40) -> np.ndarray:
    """Both rectified images side by side (BGR uint8, height x 2 width) with a line every ``line_spacing_px`` rows.

    Lines are :data:`LINE_COLOUR_BGR`, one pixel wide, on rows 0, spacing, 2 spacing, ...
    A vertical pair is stacked (2 height x width) with lines along the columns
    instead, as OpenCV's stereo_calib sample does. Gray or BGR input images.
    """
    if int(line_spacing_px) < 1:
        raise InputError(f"line_spacing_px is {line_spacing_px!r}; expected a positive number of pixels",
                         "line_spacing_px")
    spacing = int(line_spacing_px)
    left, right = (_bgr(image) for image in rect.rectify_images(left_image, right_image))
    if rect.vertical:
        canvas = np.vstack([left, right])
        canvas[:, ::spacing] = LINE_COLOUR_BGR
    else:
        canvas = np.hstack([left, right])
        canvas[::spacing, :] = LINE_COLOUR_BGR
    return canvas


def epipolar_errors(left: CameraIntrinsics, right: CameraIntrinsics, T_left_right: np.ndarray,
                    left_px: np.ndarray, right_px: np.ndarray) -> np.ndarray:
    """Symmetric epipolar distance (px) of each correspondence: (N,) for (N, 2) distorted left and right pixels.

    Both pixels are undistorted (into the pixel frame of their own ``K``); the value is
    the mean of the right point's distance to the epipolar line of the left point in
    the right image and the left point's distance to the line of the right point in
    the left image, through ``F = K_r^-T [t]x R K_l^-1`` with ``(R, t) = inv(T_left_right)``
    (``T_left_right`` maps points in the right optical frame into the left one, m).
    OpenCV's ``samples/cpp/stereo_calib.cpp`` sums the two distances instead: its
    "average epipolar err" is twice the mean of these values.
    """
    left_px = np.asarray(left_px, dtype=float).reshape(-1, 2)
    right_px = np.asarray(right_px, dtype=float).reshape(-1, 2)
    if len(left_px) != len(right_px):
        raise ValueError(f"{len(left_px)} left pixels but {len(right_px)} right pixels; expected pairs")
    F = fundamental_matrix(left, right, T_left_right)
    x_left = _homogeneous_undistorted(left, left_px)
    x_right = _homogeneous_undistorted(right, right_px)
    lines_right = x_left @ F.T  # l_r = F x_l, in the right image
    lines_left = x_right @ F  # l_l = F^T x_r, in the left image
    d_right = np.abs(np.sum(lines_right * x_right, axis=1)) / np.hypot(lines_right[:, 0], lines_right[:, 1])
    d_left = np.abs(np.sum(lines_left * x_left, axis=1)) / np.hypot(lines_left[:, 0], lines_left[:, 1])
    return 0.5 * (d_left + d_right)


def fundamental_matrix(left: CameraIntrinsics, right: CameraIntrinsics, T_left_right: np.ndarray) -> np.ndarray:
    """``F`` (3x3, scaled so its Frobenius norm is 1) with ``x_r^T F x_l = 0`` for undistorted pixels ``x``."""
    T_right_left = invert(np.asarray(T_left_right, dtype=float).reshape(4, 4))
    R, t = T_right_left[:3, :3], T_right_left[:3, 3]
    t_cross = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    F = np.linalg.inv(right.K).T @ t_cross @ R @ np.linalg.inv(left.K)
    return F / np.linalg.norm(F)


def rectified_row_errors(rect: Rectification, left_px: np.ndarray, right_px: np.ndarray) -> np.ndarray:
    """``|v_left - v_right|`` (px) of each correspondence after rectification: (N,) for (N, 2) distorted pixels.

    For a vertical pair (:attr:`Rectification.vertical`) it is ``|u_left - u_right|``.
    """
    left_px = np.asarray(left_px, dtype=float).reshape(-1, 2)
    right_px = np.asarray(right_px, dtype=float).reshape(-1, 2)
    if len(left_px) != len(right_px):
        raise ValueError(f"{len(left_px)} left pixels but {len(right_px)} right pixels; expected pairs")
    left_rect, right_rect = rect.rectify_points(left_px, right_px)
    axis = 0 if rect.vertical else 1
    return np.abs(left_rect[:, axis] - right_rect[:, axis])


def _homogeneous_undistorted(camera: CameraIntrinsics, pixels: np.ndarray) -> np.ndarray:
    """(N, 3) homogeneous undistorted pixels ``K [x, y, 1]`` of distorted pixels (N, 2)."""
    xy = camera.undistort_points(pixels)
    return np.column_stack([xy, np.ones(len(xy))]) @ camera.K.T


def _rectified(camera: CameraIntrinsics, R: np.ndarray, P: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Rectified pixels ``P[:, :3] R [x, y, 1]`` (dehomogenised) of distorted pixels (N, 2)."""
    xy = camera.undistort_points(pixels)
    projected = np.column_stack([xy, np.ones(len(xy))]) @ (P[:, :3] @ R).T
    return projected[:, :2] / projected[:, 2:]


def _cv_dist(camera: CameraIntrinsics) -> np.ndarray:
    return camera.dist[:4] if camera.is_fisheye else camera.dist


def _bgr(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise InputError(f"preview images must be 8-bit; got {image.dtype}", "image")
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
    if image.ndim == 3 and image.shape[2] == 1:
        return cv2.cvtColor(image[:, :, 0], cv2.COLOR_GRAY2BGR)
    if image.ndim == 3 and image.shape[2] == 3:
        return image
    raise InputError(f"preview images must be gray or BGR; got shape {image.shape}", "image")
