"""The photogrammetric camera model: collinearity with self-calibration (Brown's and Fraser's parameters).

An ideal image point, relative to the principal point ``(xp, yp)`` and in pixels, is ``x̄ = c X/Z``,
``ȳ = c Y/Z`` (``c`` the principal distance in px; X, Y, Z in the camera's optical frame: x right, y down,
z forward). Its observed pixel is ``u = xp + x̄ + Δx``, ``v = yp + ȳ + Δy`` with::

    Δx = x̄ (K1 r² + K2 r⁴ + K3 r⁶) + P1 (r² + 2 x̄²) + 2 P2 x̄ ȳ + A1 x̄ + A2 ȳ
    Δy = ȳ (K1 r² + K2 r⁴ + K3 r⁶) + P2 (r² + 2 ȳ²) + 2 P1 x̄ ȳ            (r² = x̄² + ȳ²)

The corrections are applied in the projection direction, to the ideal coordinates, as Agisoft Metashape's
frame model and OpenCV do; Australis-style software applies the same terms to the measured coordinates
instead, which changes the coefficients' values (to first order their signs) but not the correlations'
structure. With ``A1 = A2 = 0`` the model is OpenCV's five-coefficient one exactly (:func:`opencv_coefficients`);
``A1`` (affinity) and ``A2`` (shear) act on the ideal coordinates, which OpenCV's ``fx != fy`` and skew do not.

The image axes are the pixel axes (x right, y down) in both units: a y-up package reports ``yp``, ``P2`` and the
y-related correlations with the other sign. Coefficients are stored in pixel units (``K1`` in px⁻², ``K2`` px⁻⁴,
``K3`` px⁻⁶, ``P1``, ``P2`` px⁻¹, ``A1``, ``A2`` unitless) in the order :data:`NAMES`.
"""

from __future__ import annotations

import numpy as np

NAMES = ["K1", "K2", "K3", "P1", "P2", "A1", "A2"]
"""The distortion coefficients in the order ``dist`` holds them."""
PIXEL_POWERS = {"K1": -2, "K2": -4, "K3": -6, "P1": -1, "P2": -1, "A1": 0, "A2": 0}
"""Each coefficient's unit as a power of length: a value in px^p is ``value / pixel_size^p`` in mm^p."""


def distort(xbar: np.ndarray, ybar: np.ndarray, dist: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Observed offsets from the principal point ``(x̄ + Δx, ȳ + Δy)`` (px) of ideal ones (1-D arrays, px)."""
    K1, K2, K3, P1, P2, A1, A2 = np.asarray(dist, dtype=float)[:7].tolist()
    r2 = xbar * xbar + ybar * ybar
    radial = r2 * (K1 + r2 * (K2 + r2 * K3))
    xy2 = 2.0 * xbar * ybar
    x_obs = xbar * (1.0 + radial + A1) + P1 * (r2 + 2.0 * xbar * xbar) + P2 * xy2 + A2 * ybar
    y_obs = ybar * (1.0 + radial) + P2 * (r2 + 2.0 * ybar * ybar) + P1 * xy2
    return x_obs, y_obs


def distort_jacobian(xbar: np.ndarray, ybar: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """(N, 2, 2) derivatives of :func:`distort`'s ``(u - xp, v - yp)`` by ``(x̄, ȳ)``."""
    K1, K2, K3, P1, P2, A1, A2 = np.asarray(dist, dtype=float)[:7].tolist()
    r2 = xbar * xbar + ybar * ybar
    radial = r2 * (K1 + r2 * (K2 + r2 * K3))
    slope = K1 + r2 * (2.0 * K2 + 3.0 * K3 * r2)  # d radial / d r²
    cross = 2.0 * xbar * ybar * slope + 2.0 * P1 * ybar + 2.0 * P2 * xbar
    J = np.empty((len(xbar), 2, 2))
    J[:, 0, 0] = 1.0 + radial + 2.0 * xbar * xbar * slope + 6.0 * P1 * xbar + 2.0 * P2 * ybar + A1
    J[:, 0, 1] = cross + A2
    J[:, 1, 0] = cross
    J[:, 1, 1] = 1.0 + radial + 2.0 * ybar * ybar * slope + 6.0 * P2 * ybar + 2.0 * P1 * xbar
    return J


def coefficient_jacobian(xbar: np.ndarray, ybar: np.ndarray) -> np.ndarray:
    """(N, 2, 7) derivatives of :func:`distort`'s output by the coefficients :data:`NAMES` (px per unit)."""
    r2 = xbar * xbar + ybar * ybar
    xy2 = 2.0 * xbar * ybar
    zero = np.zeros_like(xbar)
    du = [xbar * r2, xbar * r2 * r2, xbar * r2 ** 3, r2 + 2.0 * xbar * xbar, xy2, xbar, ybar]
    dv = [ybar * r2, ybar * r2 * r2, ybar * r2 ** 3, xy2, r2 + 2.0 * ybar * ybar, zero, zero]
    return np.stack([np.stack(du, axis=1), np.stack(dv, axis=1)], axis=1)


def undistort(x_obs: np.ndarray, y_obs: np.ndarray, dist: np.ndarray, iterations: int = 20,
              tolerance_px: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Ideal offsets ``(x̄, ȳ)`` (px) of observed ones, by Newton steps on :func:`distort` from the observed.

    There is no closed form in this direction. Points where the model folds over keep their last iterate.
    """
    xbar, ybar = np.array(x_obs, dtype=float), np.array(y_obs, dtype=float)
    for _ in range(iterations):
        u, v = distort(xbar, ybar, dist)
        du, dv = x_obs - u, y_obs - v
        if not len(du) or max(np.max(np.abs(du)), np.max(np.abs(dv))) < tolerance_px:
            break
        J = distort_jacobian(xbar, ybar, dist)
        det = J[:, 0, 0] * J[:, 1, 1] - J[:, 0, 1] * J[:, 1, 0]
        xbar = xbar + (J[:, 1, 1] * du - J[:, 0, 1] * dv) / det
        ybar = ybar + (J[:, 0, 0] * dv - J[:, 1, 0] * du) / det
    return xbar, ybar


def opencv_coefficients(c: float, dist: np.ndarray) -> np.ndarray:
    """OpenCV's ``[k1, k2, p1, p2, k3]`` (unitless) of the radial and decentring terms, exact when ``A1 = A2 = 0``.

    OpenCV writes the same polynomial in coordinates normalised by the focal length, so ``k1 = K1 c²``,
    ``k2 = K2 c⁴``, ``k3 = K3 c⁶``; its ``p1`` multiplies ``2 x y`` in x as ``P2`` does here, so ``p1 = P2 c``
    and ``p2 = P1 c``.
    """
    K1, K2, K3, P1, P2 = np.asarray(dist, dtype=float)[:5]
    return np.array([K1 * c**2, K2 * c**4, P2 * c, P1 * c, K3 * c**6])


def from_opencv_coefficients(c: float, opencv_dist: np.ndarray) -> np.ndarray:
    """:data:`NAMES` coefficients (px units, ``A1 = A2 = 0``) of OpenCV's ``[k1, k2, p1, p2, k3]`` at focal ``c``."""
    k1, k2, p1, p2, k3 = (list(np.asarray(opencv_dist, dtype=float).ravel()) + [0.0] * 5)[:5]
    return np.array([k1 / c**2, k2 / c**4, k3 / c**6, p2 / c, p1 / c, 0.0, 0.0])
