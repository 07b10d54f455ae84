"""mrcal's splined stereographic lens model (``LENSMODEL_SPLINED_STEREOGRAPHIC``, order 3), in numpy.

A point ``p`` (camera's optical frame) goes to its stereographic coordinates ``u = 2 p_xy / (|p| + p_z)`` (``|u| = 2
tan(theta / 2)`` at ``theta`` off the axis), a cubic B-spline surface over ``u`` adds a correction ``du(u)``, and the
pixel is ``q = f (u + du) + c`` per axis. The spline's control points sit on a square grid of ``Nx`` by ``Ny`` knots
centred on the axis; the field of view ``fov_x_deg`` puts the edge of the field along x on the second knot from each
end. Outside the grid the edge patches extrapolate. Written by hand because no Python package has the model (mrcal
has no wheel for this Python); it follows mrcal 2.2's ``mrcal.c`` (``_project_point_splined`` and the model's
precomputed knot spacing), and matches ``mrcal.project`` to 1e-12 px, so a model written here loads in mrcal
unchanged (:mod:`backend.exports.mrcal_cameramodel`).

The intrinsics vector is mrcal's: ``[fx, fy, cx, cy, C]`` with the control point ``C[iy, ix] = (du_x, du_y)`` at
``4 + 2 (iy Nx + ix)``. :class:`~backend.core.camera.CameraIntrinsics` carries ``fx, fy, cx, cy`` in ``K`` and ``C``
in ``dist``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEWTON_ITERATIONS = 50
"""Newton steps at most when unprojecting (:func:`unproject`)."""
UNPROJECT_TOLERANCE_PX = 1e-9
"""A pixel is unprojected when its ray projects back within this (px)."""


@dataclass(frozen=True)
class SplineGrid:
    """The knots of a splined model: ``nx`` by ``ny`` (cubic: at least 4 each), the field of view across (deg)."""

    nx: int
    ny: int
    fov_x_deg: float

    def __post_init__(self) -> None:
        if self.nx < 4 or self.ny < 4:
            raise ValueError(f"a cubic spline needs at least 4x4 knots, not {self.nx}x{self.ny}")
        if not 0.0 < self.fov_x_deg < 360.0:
            raise ValueError(f"the field of view across is {self.fov_x_deg} deg; expected between 0 and 360")

    @property
    def n_control(self) -> int:
        """Spline values (2 per knot: du_x, du_y)."""
        return 2 * self.nx * self.ny

    @property
    def mrcal_name(self) -> str:
        """mrcal's name of the model, e.g. ``LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=12_Ny=10_fov_x_deg=80``."""
        fov = int(self.fov_x_deg) if float(self.fov_x_deg).is_integer() else self.fov_x_deg
        return f"LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx={self.nx}_Ny={self.ny}_fov_x_deg={fov}"

    @classmethod
    def from_mrcal_name(cls, name: str) -> SplineGrid:
        """The grid of mrcal's model name (order 3 only); ``ValueError`` for any other."""
        prefix = "LENSMODEL_SPLINED_STEREOGRAPHIC_"
        fields = dict(part.split("=", 1) for part in name.removeprefix(prefix).replace("fov_x_deg", "fov").split("_")
                      if "=" in part) if name.startswith(prefix) else {}
        if fields.get("order") != "3" or not {"Nx", "Ny", "fov"} <= set(fields):
            raise ValueError(f"{name!r} is not mrcal's order-3 splined stereographic model")
        return cls(int(fields["Nx"]), int(fields["Ny"]), float(fields["fov"]))

    def to_dict(self) -> dict:
        return {"order": 3, "nx": self.nx, "ny": self.ny, "fov_x_deg": self.fov_x_deg, "mrcal": self.mrcal_name}

    @property
    def knots_per_u(self) -> float:
        """Knot spans per unit of ``u``: ``nx - 3`` spans cover the field across, ``2 * 2 tan(fov / 4)``."""
        return (self.nx - 3) / (4.0 * np.tan(np.radians(self.fov_x_deg) / 4.0))

    def support(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """For each ``u`` (N, 2): the 16 knots under it as flat indices ``iy nx + ix`` (N, 16), their weights (N,
        16) and the weights' derivatives by ``u_x`` and ``u_y`` (N, 16 each)."""
        ix = u[:, 0] * self.knots_per_u + (self.nx - 1) / 2
        iy = u[:, 1] * self.knots_per_u + (self.ny - 1) / 2
        ix0 = np.clip(np.floor(ix), 1, self.nx - 3).astype(int)
        iy0 = np.clip(np.floor(iy), 1, self.ny - 3).astype(int)
        wx, dwx = _bspline3(ix - ix0)
        wy, dwy = _bspline3(iy - iy0)
        offsets = np.arange(4) - 1
        index = ((iy0[:, None] + offsets)[:, :, None] * self.nx + (ix0[:, None] + offsets)[:, None, :]).reshape(-1, 16)
        weights = (wy[:, :, None] * wx[:, None, :]).reshape(-1, 16)
        d_ux = (wy[:, :, None] * dwx[:, None, :]).reshape(-1, 16) * self.knots_per_u
        d_uy = (dwy[:, :, None] * wx[:, None, :]).reshape(-1, 16) * self.knots_per_u
        return index, weights, d_ux, d_uy

    def touched_knots(self, u: np.ndarray) -> np.ndarray:
        """(ny, nx) bool: the knots under some of the points ``u`` (N, 2)."""
        index, weights, _, _ = self.support(np.asarray(u, float).reshape(-1, 2))
        touched = np.zeros(self.nx * self.ny, bool)
        touched[index[weights > 0]] = True
        return touched.reshape(self.ny, self.nx)


def _bspline3(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The uniform cubic B-spline's 4 weights (N, 4) at ``t`` in [0, 1] between the 2nd and 3rd knot, and their
    derivatives by ``t``."""
    t = np.asarray(t, float)[:, None]
    t2, t3 = t * t, t * t * t
    weights = np.hstack([(1 - t) ** 3 / 6, (3 * t3 - 6 * t2 + 4) / 6, (-3 * t3 + 3 * t2 + 3 * t + 1) / 6, t3 / 6])
    derivatives = np.hstack([-(1 - t) ** 2 / 2, 1.5 * t2 - 2 * t, -1.5 * t2 + t + 0.5, t2 / 2])
    return weights, derivatives


def stereographic(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``u`` (N, 2) of camera points (N, 3, any unit) and ``du/dp`` (N, 2, 3)."""
    p = np.asarray(points, float).reshape(-1, 3)
    norm = np.linalg.norm(p, axis=1)
    with np.errstate(divide="ignore"):  # a point straight behind the camera has no projection: infinite
        s = 2.0 / (norm + p[:, 2])
    u = p[:, :2] * s[:, None]
    ds = -s * s / 2  # ds/d(norm + z)
    du_dp = p[:, :2, None] * (ds / norm)[:, None, None] * p[:, None, :]
    du_dp[:, :, 2] += p[:, :2] * ds[:, None]
    du_dp[:, 0, 0] += s
    du_dp[:, 1, 1] += s
    return u, du_dp


def rays_of_u(u: np.ndarray) -> np.ndarray:
    """Unit rays (N, 3) whose stereographic coordinates are ``u`` (N, 2)."""
    n2 = np.sum(u * u, axis=1)
    return np.column_stack([4 * u, 4 - n2]) / (4 + n2)[:, None]


def _correction(grid: SplineGrid, control: np.ndarray, u: np.ndarray):
    """``du`` (N, 2), ``d du / du`` (N, 2, 2), the knots (N, 16) and weights (N, 16) at ``u``."""
    C = np.asarray(control, float).reshape(-1, 2)
    index, weights, d_ux, d_uy = grid.support(u)
    c = C[index]
    du = np.einsum("nk,nkj->nj", weights, c)
    D = np.stack([np.einsum("nk,nkj->nj", d_ux, c), np.einsum("nk,nkj->nj", d_uy, c)], axis=2)
    return du, D, index, weights


def project(grid: SplineGrid, intrinsics: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of camera points (N, 3) under ``intrinsics`` ``[fx, fy, cx, cy, C...]``."""
    u, _ = stereographic(points)
    du, _, _, _ = _correction(grid, intrinsics[4:], u)
    return (u + du) * intrinsics[:2] + intrinsics[2:4]


def project_with_jacobians(grid: SplineGrid, intrinsics: np.ndarray, points: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels (N, 2), ``dq/dp`` (N, 2, 3) and ``dq/dintrinsics`` (N, 2, 4 + control) of camera points (N, 3)."""
    f = np.asarray(intrinsics[:2], float)
    u, du_dp = stereographic(points)
    du, D, index, weights = _correction(grid, intrinsics[4:], u)
    q = (u + du) * f + intrinsics[2:4]
    dq_dp = f[None, :, None] * np.einsum("nij,njk->nik", np.eye(2)[None] + D, du_dp)
    n = len(u)
    J = np.zeros((n, 2, 4 + grid.n_control))
    J[:, 0, 0], J[:, 1, 1] = u[:, 0] + du[:, 0], u[:, 1] + du[:, 1]
    J[:, 0, 2] = J[:, 1, 3] = 1.0
    rows = np.arange(n)[:, None]
    J[rows, 0, 4 + 2 * index] = f[0] * weights
    J[rows, 1, 5 + 2 * index] = f[1] * weights
    return q, dq_dp, J


def unproject(grid: SplineGrid, intrinsics: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Unit rays (N, 3) of pixels (N, 2) (:func:`rays_where_inverting`); ``ValueError`` when some pixel has no
    inverse (the spline folds over there)."""
    rays = rays_where_inverting(grid, intrinsics, pixels)
    if not np.all(np.isfinite(rays)):
        raise ValueError(f"the splined model cannot be inverted at {int(np.sum(~np.isfinite(rays[:, 0])))} of "
                         f"{len(rays)} pixels")
    return rays


def rays_where_inverting(grid: SplineGrid, intrinsics: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """Unit rays (N, 3) of pixels (N, 2) by Newton's method on ``u + du(u) = (q - c) / f``, NaN for a pixel whose
    ray does not project back within :data:`UNPROJECT_TOLERANCE_PX` (the spline folds over there)."""
    f, c = np.asarray(intrinsics[:2], float), np.asarray(intrinsics[2:4], float)
    target = (np.asarray(pixels, float).reshape(-1, 2) - c) / f
    u = target.copy()
    with np.errstate(invalid="ignore", over="ignore"):
        for _ in range(NEWTON_ITERATIONS):
            du, D, _, _ = _correction(grid, intrinsics[4:], u)
            error = u + du - target
            if not np.max(np.abs(error * f), initial=0.0) >= UNPROJECT_TOLERANCE_PX / 10:
                break
            step = np.linalg.solve(np.eye(2)[None] + D, error[..., None])[..., 0]
            u = u - np.where(np.isfinite(step), step, 0.0)
        du, _, _, _ = _correction(grid, intrinsics[4:], u)
        converged = np.linalg.norm((u + du - target) * f, axis=1) < UNPROJECT_TOLERANCE_PX
    rays = rays_of_u(u)
    rays[~converged] = np.nan
    return rays
