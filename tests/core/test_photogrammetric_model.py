"""The photogrammetric camera model: projection and its inverse, and the conversion to and from OpenCV's model."""

from __future__ import annotations

import numpy as np
import pytest

from backend.core.camera import CameraIntrinsics
from backend.core.camera_conversion import convert

C = 4.0 / 0.0048
"""The disaster-response robot's FLIR Blackfly: a 4 mm lens on 4.8 um pixels (px)."""


def blackfly(A1: float = 0.0, A2: float = 0.0) -> CameraIntrinsics:
    """A 1280x1024 photogrammetric camera with a moderate barrel lens and decentring, and the given affine terms."""
    return CameraIntrinsics("photogrammetric", 1280, 1024, [[C, 0, 646.3], [0, C, 508.9], [0, 0, 1]],
                            [-0.22 / C**2, 0.09 / C**4, -0.012 / C**6, 2e-4 / C, -3e-4 / C, A1, A2])


def image_pixels(camera: CameraIntrinsics, count: int = 2000) -> np.ndarray:
    return np.random.default_rng(0).uniform([0, 0], [camera.width - 1, camera.height - 1], (count, 2))


def test_the_model_follows_its_equations():
    """One point worked by hand from the issue's equations: Δx, Δy added to the ideal offsets from (xp, yp)."""
    camera = blackfly(A1=4e-4, A2=-2.5e-4)
    K1, K2, K3, P1, P2, A1, A2 = camera.dist
    X, Y, Z = 0.3, -0.2, 1.5
    x, y = C * X / Z, C * Y / Z
    r2 = x * x + y * y
    radial = K1 * r2 + K2 * r2**2 + K3 * r2**3
    dx = x * radial + P1 * (r2 + 2 * x * x) + 2 * P2 * x * y + A1 * x + A2 * y
    dy = y * radial + P2 * (r2 + 2 * y * y) + 2 * P1 * x * y
    np.testing.assert_allclose(camera.project(np.array([[X, Y, Z]]))[0], [646.3 + x + dx, 508.9 + y + dy],
                               rtol=0, atol=1e-9)


@pytest.mark.parametrize(("A1", "A2"), [(0.0, 0.0), (4e-4, -2.5e-4)])
def test_undistortion_inverts_the_projection_over_the_image(A1: float, A2: float):
    camera = blackfly(A1, A2)
    pixels = image_pixels(camera)
    np.testing.assert_allclose(camera.project_normalised(camera.undistort_points(pixels)), pixels, rtol=0, atol=1e-7)
    rays = camera.rays(pixels)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)
    np.testing.assert_allclose(camera.project(rays), pixels, rtol=0, atol=1e-7)


def test_without_the_affine_terms_the_conversion_to_opencv_is_exact_both_ways():
    camera = blackfly()
    opencv = convert(camera, "pinhole-radtan")
    assert opencv.exact and opencv.max_residual_px < 1e-9 and opencv.note.startswith("exact")
    K = opencv.camera.K
    assert K[0, 0] == K[1, 1] == C and (K[0, 2], K[1, 2]) == (646.3, 508.9)
    # OpenCV's k1 = K1 c^2 ..., and its p1 is the photogrammetric P2 (and p2 is P1), times c
    np.testing.assert_allclose(opencv.camera.dist, [-0.22, 0.09, -3e-4, 2e-4, -0.012], rtol=1e-12)
    pixels = image_pixels(camera)
    xy = camera.undistort_points(pixels)
    np.testing.assert_allclose(opencv.camera.project_normalised(xy), pixels, rtol=0, atol=1e-7)
    back = convert(opencv.camera, "photogrammetric")
    assert back.exact
    np.testing.assert_allclose(back.camera.K, camera.K, rtol=1e-12)
    np.testing.assert_allclose(back.camera.dist, camera.dist, rtol=1e-9, atol=1e-24)


def test_the_affine_terms_have_no_opencv_counterpart_and_the_residual_is_stated():
    camera = blackfly(A1=4e-4, A2=-2.5e-4)
    opencv = convert(camera, "pinhole-radtan")
    assert not opencv.exact and "A1 and A2 have no OpenCV counterpart" in opencv.note
    pixels = image_pixels(camera)
    difference = np.linalg.norm(opencv.camera.project_normalised(camera.undistort_points(pixels)) - pixels, axis=1)
    # the stated residual is the grid's worst; a random pixel is no worse than it (within the grid's spacing)
    assert 0.05 < opencv.max_residual_px < 0.5 and difference.max() <= 1.05 * opencv.max_residual_px
    assert opencv.rms_residual_px < opencv.max_residual_px
    # the shear alone: an x offset of A2 * y that no OpenCV parameter makes, about A2 * 512 px at the top and bottom
    shear = convert(blackfly(A2=-2.5e-4), "pinhole-radtan")
    assert shear.max_residual_px > 0.5 * 2.5e-4 * 512


def test_conversion_between_other_models_is_refused():
    fisheye = CameraIntrinsics("fisheye-equidistant", 640, 480, [[300, 0, 320], [0, 300, 240], [0, 0, 1]])
    with pytest.raises(ValueError, match="no conversion from fisheye-equidistant to photogrammetric"):
        convert(fisheye, "photogrammetric")
