"""A uniform B-spline whose values and time derivatives are linear maps of its coefficients.

The camera-IMU solve models the IMU's pose as such a spline of six values (position in m, rotation vector in rad),
as Kalibr's ``BSplinePose`` does, so the IMU's angular rate and acceleration at any instant are its derivatives.
Evaluation is a sparse design matrix (SciPy's ``BSpline.design_matrix``) times the coefficients; the derivatives'
matrices follow from differencing the coefficients (for uniform knots ``c'_i = (c_{i+1} - c_i) / h``), which SciPy
does not offer as a design matrix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.interpolate import BSpline


@dataclass(frozen=True)
class UniformSpline:
    """A degree-``degree`` B-spline with knots every ``spacing_s`` covering ``[start_s, end_s]``."""

    start_s: float
    end_s: float
    spacing_s: float
    degree: int = 5

    @property
    def knots(self) -> np.ndarray:
        """The knot vector (s), extended by ``degree`` knots past each end so the whole interval is supported."""
        count = int(np.ceil((self.end_s - self.start_s) / self.spacing_s))
        return self.start_s + self.spacing_s * np.arange(-self.degree, count + self.degree + 1)

    @property
    def n_coefficients(self) -> int:
        return len(self.knots) - self.degree - 1

    def basis(self, times_s: np.ndarray, derivative: int = 0) -> sp.csr_array:
        """(len(times_s), n_coefficients) matrix mapping coefficients to the ``derivative``-th time derivative
        (value units per s^derivative) at ``times_s``, which must lie in ``[start_s, end_s]``."""
        times_s = np.clip(np.asarray(times_s, float), self.start_s, self.knots[-self.degree - 1])
        knots, degree = self.knots, self.degree
        design = BSpline.design_matrix(times_s, knots[derivative: len(knots) - derivative], degree - derivative)
        difference = sp.identity(self.n_coefficients, format="csr")
        for order in range(derivative):
            n = self.n_coefficients - order
            step = sp.diags_array([-np.ones(n - 1), np.ones(n - 1)], offsets=[0, 1], shape=(n - 1, n))
            difference = (step / self.spacing_s) @ difference
        return sp.csr_array(design @ difference)

    def fit(self, times_s: np.ndarray, values: np.ndarray, smoothing: float = 1e-6) -> np.ndarray:
        """Coefficients (n_coefficients, dim) of the least-squares fit to ``values`` (N, dim) at ``times_s``, with a
        small penalty on the second difference of the coefficients so knots without samples stay defined."""
        B = self.basis(times_s)
        n = self.n_coefficients
        second = sp.diags_array([np.ones(n - 2), -2 * np.ones(n - 2), np.ones(n - 2)], offsets=[0, 1, 2],
                                shape=(n - 2, n))
        system = sp.csc_array(B.T @ B + smoothing * len(times_s) / n * (second.T @ second))
        return sp.linalg.spsolve(system, B.T @ np.asarray(values, float)).reshape(n, -1)
