"""Normal equations of the camera-IMU fit, assembled through the spline's sparse basis, and their damped solve.

Written by hand because SciPy's least-squares solvers take a Jacobian, and this one would be 450,000 rows by 40,000
columns for a minute of EuRoC (13 million non-zeros from the corners alone). Each measurement touches only the
spline's values (and their rates) at its instant, so the normal matrix is built per instant, then lifted through the
basis: a banded block in the coefficients (a coefficient meets only its ``degree`` neighbours), bordered by the
shared parameters. A step eliminates the coefficients with LAPACK's banded Cholesky (``solveh_banded``) and solves
the shared parameters' Schur complement; SuperLU on the whole matrix took minutes and gigabytes on the same problem.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.linalg import solveh_banded

from backend.calib.camera_imu.spline import UniformSpline
from backend.calib.camera_imu.trajectory import VALUES, Linearised


@dataclass(frozen=True)
class NormalEquations:
    """``J^T J`` and ``J^T r`` over ``[coefficients (V n), shared]`` (V = :data:`VALUES`), in blocks."""

    H_cc: np.ndarray
    """The coefficients' block in LAPACK's upper banded form ``(bandwidth + 1, V n)``."""
    H_cs: np.ndarray
    """(V n, S), S the shared parameters."""
    H_ss: np.ndarray
    g_c: np.ndarray
    g_s: np.ndarray

    def step(self, damping: float) -> np.ndarray:
        """The Levenberg-Marquardt step ``-(H + damping diag(H))^-1 g`` (Marquardt's scaling), coefficients
        eliminated first."""
        H_cc = self.H_cc.copy()
        H_cc[-1] += damping * np.maximum(H_cc[-1], 1e-12 * max(H_cc[-1].max(), 1.0))
        H_ss = self.H_ss + np.diag(damping * np.maximum(np.diag(self.H_ss), 1e-12))
        solved = solveh_banded(H_cc, np.column_stack([self.H_cs, self.g_c]), check_finite=False)
        schur = H_ss - self.H_cs.T @ solved[:, :-1]
        step_s = np.linalg.solve(schur, -(self.g_s - self.H_cs.T @ solved[:, -1]))
        step_c = -solved[:, -1] - solved[:, :-1] @ step_s
        return np.concatenate([step_c, step_s])

    def shared_covariance(self) -> np.ndarray:
        """The shared parameters' block of ``H^-1``: their covariance with the coefficients marginalised."""
        solved = solveh_banded(self.H_cc, self.H_cs, check_finite=False)
        covariance = np.linalg.inv(self.H_ss - self.H_cs.T @ solved)
        return 0.5 * (covariance + covariance.T)


def assemble(parts: list[Linearised], spline: UniformSpline) -> NormalEquations:
    """The Gauss-Newton normal equations of ``parts`` over ``[coefficients (V n), shared]``."""
    n = spline.n_coefficients * VALUES
    H_cc = sp.csr_array((n, n))
    n_shared = parts[0].by_shared.shape[1]
    H_cs = np.zeros((n, n_shared))
    H_ss = np.zeros((n_shared, n_shared))
    g_c = np.zeros(n)
    g_s = np.zeros(n_shared)
    for part in parts:
        H_ss += part.by_shared.T @ part.by_shared
        g_s += part.by_shared.T @ part.residuals
        times, _, time_index, _ = part.by_values[0]
        local = np.concatenate([J for *_, J in part.by_values], axis=2)  # (G, rows, V q)
        groups, rows, width = local.shape
        residuals = part.residuals.reshape(groups, rows)
        shared = part.by_shared.reshape(groups, rows, n_shared)
        H_local = _sum_by_time(time_index, np.einsum("gri,grj->gij", local, local), len(times))
        H_cross = _sum_by_time(time_index, np.einsum("gri,grj->gij", local, shared), len(times))
        g_local = _sum_by_time(time_index, np.einsum("gri,gr->gi", local, residuals), len(times))
        lift = _lift(spline, times, [order for _, order, _, _ in part.by_values])
        blocks = sp.bsr_array((H_local, np.arange(len(times)), np.arange(len(times) + 1)),
                              shape=(len(times) * width, len(times) * width))
        H_cc = H_cc + lift.T @ (blocks @ lift)
        H_cs += lift.T @ H_cross.reshape(-1, n_shared)
        g_c += lift.T @ g_local.ravel()
    bandwidth = VALUES * (spline.degree + 1) - 1
    return NormalEquations(_upper_band(sp.coo_array(H_cc), bandwidth), H_cs, H_ss, g_c, g_s)


def _lift(spline: UniformSpline, times: np.ndarray, orders: list[int]) -> sp.csr_array:
    """(T V q, V n): the local values ``[d^o s(t) for o in orders]`` of every time from the coefficients."""
    per_order = [sp.kron(spline.basis(times, order), sp.identity(VALUES), format="csr") for order in orders]
    stacked = sp.vstack(per_order, format="csr")  # rows (order, time, component)
    T, q = len(times), len(orders)
    order, time, component = np.meshgrid(np.arange(q), np.arange(T), np.arange(VALUES), indexing="ij")
    wanted = np.empty(T * VALUES * q, int)
    wanted[(time * VALUES * q + order * VALUES + component).ravel()] = (
        order * T * VALUES + time * VALUES + component).ravel()
    return sp.csr_array(stacked[wanted])


def _sum_by_time(time_index: np.ndarray, values: np.ndarray, n_times: int) -> np.ndarray:
    """(n_times, ...) sums of ``values`` over the groups of each time; ``time_index`` is sorted."""
    if len(time_index) == n_times and (time_index == np.arange(n_times)).all():
        return values
    starts = np.searchsorted(time_index, np.arange(n_times))
    sums = np.add.reduceat(values, np.minimum(starts, len(values) - 1), axis=0)
    sums[np.append(starts[1:], len(values)) == starts] = 0.0  # times with no group
    return sums


def _upper_band(H: sp.coo_array, bandwidth: int) -> np.ndarray:
    """A symmetric sparse matrix's upper band in LAPACK's form: ``band[bandwidth + i - j, j] = H[i, j]``."""
    band = np.zeros((bandwidth + 1, H.shape[0]))
    upper = H.row <= H.col
    np.add.at(band, (bandwidth + H.row[upper] - H.col[upper], H.col[upper]), H.data[upper])
    return band
