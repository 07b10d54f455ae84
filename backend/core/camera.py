"""Camera models: intrinsics and projection, following OpenCV.

``pinhole-radtan`` is OpenCV's standard model (``dist = [k1, k2, p1, p2, k3]``,
ROS ``plumb_bob``); ``fisheye-equidistant`` is OpenCV's fisheye model
(``dist = [k1, k2, k3, k4]``, ROS ``equidistant``); ``photogrammetric`` is the collinearity model with
self-calibration (:mod:`backend.core.photogrammetric`: ``K`` holds the principal distance ``c`` as ``fx = fy``
and the principal point, ``dist = [K1, K2, K3, P1, P2, A1, A2]`` in pixel units), which ROS cannot carry;
``splined-stereographic`` is mrcal's splined model (:mod:`backend.core.splined`: ``K`` holds its fx, fy, cx, cy,
``dist`` its control points, ``spline`` its knots and field of view), which only the camera JSON and mrcal's
``.cameramodel`` carry. Points are in the camera's
optical frame (x right, y down, z forward, metres); pixels follow OpenCV (centre
of the top-left pixel is (0, 0)).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np

from backend.core import photogrammetric, splined
from backend.core.errors import InputError
from backend.core.splined import SplineGrid

CameraModelName = Literal["pinhole-radtan", "fisheye-equidistant", "photogrammetric", "splined-stereographic"]
CAMERA_MODELS: tuple[CameraModelName, ...] = ("pinhole-radtan", "fisheye-equidistant", "photogrammetric",
                                              "splined-stereographic")
ROS_DISTORTION_NAMES: dict[str, str] = {"pinhole-radtan": "plumb_bob", "fisheye-equidistant": "equidistant"}
SPLINED_HINT = " (its splined section holds the OpenCV model fitted to the spline, with the residual between the two)"
"""What an export that refuses the splined model points to instead."""
UNDISTORT_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
DIST_NAMES: dict[str, list[str]] = {
    "pinhole-radtan": ["k1", "k2", "p1", "p2", "k3"],
    "fisheye-equidistant": ["k1", "k2", "k3", "k4"],
    "photogrammetric": photogrammetric.NAMES,
}


@dataclass
class CameraIntrinsics:
    """A calibrated (or nominal) camera: model, image size (px), K (px) and distortion."""

    model: CameraModelName
    width: int
    height: int
    K: np.ndarray
    dist: np.ndarray = field(default_factory=lambda: np.zeros(5))
    spline: SplineGrid | None = None
    """The splined model's knots and field of view (``splined-stereographic`` only)."""

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, dtype=float).reshape(3, 3)
        self.dist = np.asarray(self.dist, dtype=float).ravel()
        if (self.model == "splined-stereographic") != (self.spline is not None):
            raise ValueError("the splined-stereographic model, and only it, takes a spline grid")
        expected = len(self.dist_names)
        if self.dist.size < expected:
            self.dist = np.concatenate([self.dist, np.zeros(expected - self.dist.size)])

    @property
    def dist_names(self) -> list[str]:
        """The names of ``dist``'s entries: the model's coefficients, or the splined model's control points
        ``du_x[iy,ix]``, ``du_y[iy,ix]`` (mrcal's order)."""
        if self.spline is None:
            return DIST_NAMES[self.model]
        return [f"du_{axis}[{iy},{ix}]" for iy in range(self.spline.ny) for ix in range(self.spline.nx)
                for axis in "xy"]

    @property
    def is_fisheye(self) -> bool:
        return self.model == "fisheye-equidistant"

    @property
    def is_opencv(self) -> bool:
        """Whether OpenCV's functions take ``K`` and ``dist`` as they are (not the photogrammetric or splined
        model)."""
        return self.model in ("pinhole-radtan", "fisheye-equidistant")

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels, as OpenCV expects."""
        return self.width, self.height

    @property
    def parameters(self) -> np.ndarray:
        """``[fx, fy, cx, cy, dist...]`` (px, and the distortion coefficients' units): the order of the solvers'
        Jacobians and covariances."""
        return np.r_[self.K[0, 0], self.K[1, 1], self.K[0, 2], self.K[1, 2], self.dist]

    def with_parameters(self, parameters: np.ndarray) -> CameraIntrinsics:
        """This camera (model, size) with ``[fx, fy, cx, cy, dist...]`` set to ``parameters``."""
        fx, fy, cx, cy = parameters[:4]
        return CameraIntrinsics(self.model, self.width, self.height,
                                np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), parameters[4:], self.spline)

    def project(self, points_cam: np.ndarray) -> np.ndarray:
        """Project (N, 3) points in the optical frame (m) to (N, 2) pixels.

        Points behind the camera are projected too; callers filter on ``z > 0``.
        """
        pts = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        if self.spline is not None:  # stereographic: defined beyond 90 degrees off the axis too
            return splined.project(self.spline, self.parameters, pts)
        return self.project_normalised(pts[:, :2] / pts[:, 2:])

    def project_normalised(self, xy: np.ndarray) -> np.ndarray:
        """Pixels (N, 2) of normalised image coordinates (N, 2) (x/z, y/z: points on the z = 1 plane)."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        return np.column_stack(self.normalised_to_pixels(xy[:, 0], xy[:, 1]))

    def normalised_to_pixels(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel columns ``u`` and rows ``v`` (px) of normalised coordinates ``x = X/Z``, ``y = Y/Z`` (1-D arrays).

        OpenCV's ``projectPoints`` and ``fisheye.projectPoints`` formulas written out in
        numpy (they agree to 1e-9 px): from Python those functions always compute the
        2N x 15 Jacobian as well, which makes them about 15x slower than this. Like them,
        this ignores the skew ``K[0, 1]``. ``photogrammetric`` is :func:`backend.core.photogrammetric.distort`
        (in float64). Only the five ``pinhole-radtan`` coefficients
        of the conventions are supported. Computed in the dtype of ``x`` and ``y``
        (float32 in, float32 out: about 1e-4 px at 1280x720); ``x`` and ``y`` are not modified.
        """
        if self.spline is not None:
            q = splined.project(self.spline, self.parameters, np.column_stack([x, y, np.ones_like(x)]))
            return q[:, 0].astype(x.dtype, copy=False), q[:, 1].astype(y.dtype, copy=False)
        if self.model == "photogrammetric":
            xo, yo = photogrammetric.distort(x * float(self.K[0, 0]), y * float(self.K[1, 1]), self.dist)
            return (xo + float(self.K[0, 2])).astype(x.dtype, copy=False), (yo + float(self.K[1, 2])).astype(
                y.dtype, copy=False)
        if not self.is_fisheye and self.dist[5:].any():
            raise ValueError("pinhole-radtan takes dist = [k1, k2, p1, p2, k3]; rational terms are not supported")
        # Python floats, so that float32 arrays stay float32.
        fx, fy, cx, cy = float(self.K[0, 0]), float(self.K[1, 1]), float(self.K[0, 2]), float(self.K[1, 2])
        r2 = x * x
        r2 += y * y
        if self.is_fisheye:
            k1, k2, k3, k4 = self.dist[:4].tolist()
            r = np.sqrt(r2)
            theta = np.arctan(r)
            t2 = theta * theta
            theta_d = theta * (1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4))))
            scale = np.divide(theta_d, r, out=np.ones_like(r), where=r > 1e-8)  # OpenCV's guard on the axis
            xd, yd = x * scale, y * scale
        else:
            # x_d = x radial + 2 p1 x y + p2 (r2 + 2 x^2) = x s + p2 r2 and y_d = y s + p1 r2, with
            # s = radial + 2 (p1 y + p2 x): the same polynomial in 23 array passes instead of 31, fewer
            # when coefficients are zero (often k3, sometimes p1 and p2), and in place where possible.
            k1, k2, p1, p2, k3 = self.dist[:5].tolist()
            s = _horner(r2, (1.0, k1, k2, k3))  # radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
            if p1 or p2:
                s += x * (2.0 * p2)
                s += y * (2.0 * p1)
            xd, yd = x * s, y * s
            if p2:
                xd += r2 * p2
            if p1:
                yd += r2 * p1
        xd *= fx
        xd += cx
        yd *= fy
        yd += cy
        return xd, yd

    def undistort_points(self, pixels: np.ndarray) -> np.ndarray:
        """Normalised image coordinates (x/z, y/z) of (N, 2) distorted pixels."""
        uv = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        if self.spline is not None:
            rays = self.rays(uv.reshape(-1, 2))
            return rays[:, :2] / rays[:, 2:]
        if self.model == "photogrammetric":
            xbar, ybar = photogrammetric.undistort(uv[:, 0, 0] - self.K[0, 2], uv[:, 0, 1] - self.K[1, 2], self.dist)
            return np.column_stack([xbar / self.K[0, 0], ybar / self.K[1, 1]])
        if self.is_fisheye:
            return cv2.fisheye.undistortPoints(uv, self.K, self.dist[:4]).reshape(-1, 2)
        # The iterative variant with a tight criterion: plain undistortPoints stops after
        # 5 iterations, which leaves ~0.05 px at the corners of strongly distorted lenses.
        return cv2.undistortPointsIter(uv, self.K, self.dist, None, None, UNDISTORT_CRITERIA).reshape(-1, 2)

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Unit viewing rays (N, 3) in the optical frame for distorted pixels (N, 2)."""
        if self.spline is not None:
            return splined.unproject(self.spline, self.parameters, pixels)
        xy = self.undistort_points(pixels)
        rays = np.column_stack([xy, np.ones(len(xy))])
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)

    def rays_where_inverting(self, pixels: np.ndarray) -> np.ndarray:
        """:meth:`rays`, with NaN rays at the pixels where a splined model folds over (has no inverse) instead of
        refusing them all; the other models' inverses always give a ray."""
        if self.spline is not None:
            return splined.rays_where_inverting(self.spline, self.parameters, pixels)
        return self.rays(pixels)

    @property
    def fov_y_rad(self) -> float:
        """Vertical field of view of the undistorted pinhole (rad), for drawing frusta."""
        return float(2 * np.arctan2(self.height / 2, self.K[1, 1]))

    def to_dict(self) -> dict:
        """The conventions' camera JSON: model, width, height, K (nested), dist (list), and the splined model's
        ``spline`` (:meth:`SplineGrid.to_dict`)."""
        return {
            "model": self.model,
            "width": int(self.width),
            "height": int(self.height),
            "K": self.K.tolist(),
            "dist": self.dist.tolist(),
            **({"spline": self.spline.to_dict()} if self.spline is not None else {}),
        }

    @classmethod
    def from_dict(cls, data: dict) -> CameraIntrinsics:
        spline = data.get("spline")
        return cls(data["model"], int(data["width"]), int(data["height"]), np.array(data["K"]), np.array(data["dist"]),
                   None if spline is None else SplineGrid(int(spline["nx"]), int(spline["ny"]),
                                                          float(spline["fov_x_deg"])))


def _horner(t: np.ndarray, coefficients: tuple[float, ...]) -> np.ndarray:
    """``c0 + c1 t + c2 t^2 + ...`` by Horner's rule into one new array; zero coefficients at the top are skipped."""
    coefficients = list(coefficients)
    while len(coefficients) > 1 and coefficients[-1] == 0.0:
        coefficients.pop()
    if len(coefficients) == 1:
        return np.full_like(t, coefficients[0])
    value = t * coefficients[-1]
    for c in reversed(coefficients[1:-1]):
        value += c
        value *= t
    value += coefficients[0]
    return value


def check_image_size(image: np.ndarray, camera: CameraIntrinsics, name: str) -> None:
    """Refuse an image whose size is not the one the intrinsics were calibrated at (``name``: the input to blame)."""
    height, width = image.shape[:2]
    if (width, height) != (camera.width, camera.height):
        raise InputError(f"the image is {width}x{height} px but the camera's intrinsics are for "
                         f"{camera.width}x{camera.height}", name)


def check_camera_image(image: np.ndarray, camera: CameraIntrinsics, name: str) -> np.ndarray:
    """``image`` as an array, refused unless a uint8 gray (H, W) or BGR (H, W, 3) image at the intrinsics' size."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise InputError(f"expected a uint8 gray (H, W) or BGR (H, W, 3) image, got {image.dtype} of shape "
                         f"{image.shape}", name)
    check_image_size(image, camera, name)
    return image
