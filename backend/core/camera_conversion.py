"""Converting a camera between the photogrammetric model and OpenCV's ``pinhole-radtan``, with the residual stated.

The two models share the radial and decentring polynomial (:func:`backend.core.photogrammetric.opencv_coefficients`),
so a photogrammetric camera with ``A1 = A2 = 0`` is an OpenCV camera exactly, and an OpenCV camera with
``fx = fy`` is a photogrammetric one exactly. Otherwise the closed form is the start and the target model's
parameters are fitted by least squares to the source's projection over the image (a 33 x 25 grid of pixels),
and the conversion says how far apart the two still are there: ``A1`` scales the ideal x where OpenCV's ``fx``
also scales the distortion, and OpenCV's model has no shear at all (it ignores ``K[0, 1]``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from backend.core import photogrammetric
from backend.core.camera import CameraIntrinsics, CameraModelName

GRID = (33, 25)
"""Pixels (columns x rows, corners included) where the two models are compared."""
EXACT_PX = 1e-9
"""A conversion whose closed form agrees within this (px) everywhere is exact and is not fitted further."""


@dataclass(frozen=True)
class Conversion:
    """A camera in another model, and how far its projection is from the original's over the image (px)."""

    camera: CameraIntrinsics
    exact: bool
    max_residual_px: float
    rms_residual_px: float
    note: str

    def to_dict(self) -> dict:
        return {"camera": self.camera.to_dict(), "exact": self.exact, "max_residual_px": self.max_residual_px,
                "rms_residual_px": self.rms_residual_px, "note": self.note}


def convert(camera: CameraIntrinsics, model: CameraModelName) -> Conversion:
    """``camera`` in ``model`` (``pinhole-radtan`` from ``photogrammetric`` or the other way round).

    Raises ``ValueError`` for any other pair.
    """
    pair = (camera.model, model)
    if pair == ("photogrammetric", "pinhole-radtan"):
        start, unpack = _opencv_start(camera), opencv_camera
        note = "A1 and A2 have no OpenCV counterpart: fx, fy and the distortion were fitted over the image"
    elif pair == ("pinhole-radtan", "photogrammetric"):
        start, unpack = _photogrammetric_start(camera), photogrammetric_camera
        note = "fx != fy has no exact photogrammetric counterpart: c, A1 and the distortion were fitted over the image"
    else:
        raise ValueError(f"no conversion from {camera.model} to {model}")
    xy = camera.undistort_points(pixel_grid(camera))
    target = camera.project_normalised(xy)

    def residual(params: np.ndarray) -> np.ndarray:
        return (unpack(camera, params).project_normalised(xy) - target).ravel()

    if np.max(np.abs(residual(start))) > EXACT_PX:
        start = least_squares(residual, start, x_scale="jac", method="lm", xtol=1e-15, ftol=1e-15).x
    difference = np.linalg.norm(residual(start).reshape(-1, 2), axis=1)
    exact = bool(difference.max() <= EXACT_PX)
    return Conversion(unpack(camera, start), exact, float(difference.max()), float(np.sqrt(np.mean(difference**2))),
                      "exact: the models share these terms" if exact else note)


def pixel_grid(camera: CameraIntrinsics, columns: int = GRID[0], rows: int = GRID[1]) -> np.ndarray:
    """(columns * rows, 2) pixels spread evenly over ``camera``'s image, its edges included, row by row."""
    u, v = np.meshgrid(np.linspace(0, camera.width - 1, columns), np.linspace(0, camera.height - 1, rows))
    return np.column_stack([u.ravel(), v.ravel()])


def _opencv_start(camera: CameraIntrinsics) -> np.ndarray:
    """[fx, fy, cx, cy, k1, k2, p1, p2, k3] of a photogrammetric camera by the closed form."""
    c = float(camera.K[1, 1])
    A1 = float(camera.dist[5])
    return np.r_[c * (1.0 + A1), c, camera.K[0, 2], camera.K[1, 2], photogrammetric.opencv_coefficients(c, camera.dist)]


def opencv_camera(source: CameraIntrinsics, params: np.ndarray) -> CameraIntrinsics:
    """The ``pinhole-radtan`` camera of ``[fx, fy, cx, cy, k1, k2, p1, p2, k3]`` ``params`` at ``source``'s size."""
    fx, fy, cx, cy = params[:4]
    return CameraIntrinsics("pinhole-radtan", source.width, source.height,
                            np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), params[4:9])


def _photogrammetric_start(camera: CameraIntrinsics) -> np.ndarray:
    """[c, xp, yp, K1, K2, K3, P1, P2, A1, A2] of an OpenCV camera by the closed form (A1 from fx / fy)."""
    fx, fy = float(camera.K[0, 0]), float(camera.K[1, 1])
    coefficients = photogrammetric.from_opencv_coefficients(fy, camera.dist)
    coefficients[5] = fx / fy - 1.0
    return np.r_[fy, camera.K[0, 2], camera.K[1, 2], coefficients]


def interior_orientation(camera: CameraIntrinsics) -> np.ndarray:
    """``[c, xp, yp, K1, K2, K3, P1, P2, A1, A2]`` (px units) of a photogrammetric camera."""
    return np.r_[camera.K[0, 0], camera.K[0, 2], camera.K[1, 2], camera.dist[:7]]


def photogrammetric_camera(source: CameraIntrinsics, params: np.ndarray) -> CameraIntrinsics:
    """The photogrammetric camera of :func:`interior_orientation` ``params``, at ``source``'s image size."""
    c, xp, yp = params[:3]
    return CameraIntrinsics("photogrammetric", source.width, source.height,
                            np.array([[c, 0.0, xp], [0.0, c, yp], [0.0, 0.0, 1.0]]), params[3:10])
