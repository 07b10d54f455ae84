"""The result type every solver returns.

As in Open3D's registration pipelines, every solver hands back the same shape of
result so the session store, the API, the studio and the CLI treat them alike:
``kind`` says which solver, ``summary()`` is the CLI's JSON (the contract in
``../shared/conventions.md``), ``to_record()`` is everything worth keeping in the
session history (inputs, settings, statistics, diagnostics).
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from backend.core.uncertainty import sigmas
from backend.core.verdict import Verdict

ProgressCallback = Callable[[float, str], None]
"""Called with (fraction done in [0, 1], what is happening) during long work."""


class SolveResult(abc.ABC):
    kind: ClassVar[str]

    @abc.abstractmethod
    def summary(self) -> dict[str, Any]:
        """The exact JSON object the CLI prints with ``--json``."""

    @abc.abstractmethod
    def to_record(self) -> dict[str, Any]:
        """Everything kept in the session's result history (JSON-serialisable)."""


def no_progress(fraction: float, message: str) -> None:
    """A :data:`ProgressCallback` that ignores progress."""


def finite_or_none(values: Any) -> list[float | None] | None:
    """Values (any shape, flattened) as plain floats for a JSON record, None where not finite (an
    undetermined parameter: strict JSON has no inf or NaN); None stays None."""
    if values is None:
        return None
    return [float(v) if np.isfinite(v) else None for v in np.asarray(values, dtype=float).ravel()]


def jackknife_std(estimates: np.ndarray) -> np.ndarray:
    """Leave-one-out jackknife standard deviation per parameter of ``n`` re-solves, each without one unit
    (a view, a pose, a pair, a sector): ``var = (n - 1) / n * sum((theta_i - mean)^2)``; ``estimates`` is (n, p)."""
    estimates = np.asarray(estimates, dtype=float)
    n = len(estimates)
    return np.sqrt((n - 1) / n * np.sum((estimates - estimates.mean(axis=0)) ** 2, axis=0))


TRANSFORM_PARAMETERS = ["t_x_m", "t_y_m", "t_z_m", "r_x_rad", "r_y_rad", "r_z_rad"]
"""Order of a transform result's covariance: translation (m, parent axes), rotation about the child's axes (rad)."""


def transform_std(covariance: np.ndarray) -> dict[str, list[float | None]]:
    """A transform result's reported 1-sigma from its 6x6 covariance (order :data:`TRANSFORM_PARAMETERS`):
    ``trans_m`` (m, parent axes) and ``rot_deg`` (deg, about the child's axes); None where undetermined."""
    std = sigmas(covariance)
    return {"trans_m": finite_or_none(std[:3]), "rot_deg": finite_or_none(np.degrees(std[3:]))}


@dataclass
class TransformResult(SolveResult):
    """What every transform solver returns, as Open3D's registration returns one ``RegistrationResult``.

    ``T_parent_child`` (4x4, m) maps points in ``child`` into ``parent`` (``../shared/conventions.md``);
    ``covariance`` is 6x6 over :data:`TRANSFORM_PARAMETERS` (translation in m along the parent's axes,
    rotation in rad about the child's axes; NaN where the data do not determine it). The session
    store, the accept service, the rig graph, the studio's result card, the report and the CLI all
    read this one shape.
    """

    kind: str
    """The solver family: ``lidar_lidar``, ``lidar_camera``, ``multicam``, ``sweep``, ``depth_node``."""
    method: str
    """How it was solved within the family (``gicp``, ``target``, ``edges``, ``intensity``, ``bundle``,
    ``manual``, ...)."""
    parent: str
    child: str
    T_parent_child: np.ndarray
    covariance: np.ndarray
    residuals: dict[str, Any] = field(default_factory=dict)
    """Residual statistics, with their units in the key names (``rmse_m``, ``rms_px``, ``fitness``, ...)."""
    diagnostics: dict[str, Any] = field(default_factory=dict)
    """JSON-ready detail behind the numbers: per-view or per-scene solves, the initial guess, spreads."""
    settings: dict[str, Any] = field(default_factory=dict)
    """The solver's settings as used (a dataclass's ``asdict``)."""
    converged: bool = True
    """False when the solver did not reach a good fit: such a result is kept but cannot be accepted."""
    verdict: Verdict | None = None
    """How far it can be trusted; None until judged (some services judge after the solver)."""
    warnings: list[str] = field(default_factory=list)
    seconds: float = 0.0
    """Wall-clock seconds of the solve."""

    def __post_init__(self) -> None:
        self.T_parent_child = np.asarray(self.T_parent_child, dtype=float).reshape(4, 4)
        self.covariance = np.asarray(self.covariance, dtype=float).reshape(6, 6)

    @property
    def std(self) -> dict[str, list[float | None]]:
        """Reported 1-sigma: ``trans_m`` (m, parent axes) and ``rot_deg`` (deg, about the child's axes)."""
        return transform_std(self.covariance)

    @property
    def std_vector(self) -> np.ndarray:
        """(6,) 1-sigma in :data:`TRANSFORM_PARAMETERS` order (m, rad); NaN where undetermined."""
        return sigmas(self.covariance)

    def summary(self) -> dict[str, Any]:
        """``{"kind", "method", "parent", "child", "T_parent_child", "std", "residuals", "converged", "verdict",
        "warnings", "seconds"}``; each CLI command names the transform as its contract says (``T_target_source``,
        ``T_camera_lidar``, ...) from this."""
        return {"kind": self.kind, "method": self.method, "parent": self.parent, "child": self.child,
                "T_parent_child": self.T_parent_child.tolist(), "std": self.std, "residuals": dict(self.residuals),
                "converged": self.converged, "verdict": None if self.verdict is None else self.verdict.to_dict(),
                "warnings": list(self.warnings), "seconds": self.seconds}

    def to_record(self) -> dict[str, Any]:
        """The summary with the covariance (and its order), the diagnostics and the settings."""
        return self.summary() | {"covariance": [finite_or_none(row) for row in self.covariance],
                                 "covariance_order": TRANSFORM_PARAMETERS,
                                 "diagnostics": dict(self.diagnostics), "settings": dict(self.settings)}

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> TransformResult:
        """Read back :meth:`to_record` (a covariance entry stored as None is NaN: undetermined)."""
        covariance = record.get("covariance")
        return cls(
            kind=record["kind"], method=record.get("method", ""), parent=record["parent"], child=record["child"],
            T_parent_child=np.array(record["T_parent_child"], dtype=float),
            covariance=np.full((6, 6), np.nan) if covariance is None else
            np.array([[np.nan if v is None else v for v in row] for row in covariance], dtype=float),
            residuals=dict(record.get("residuals", {})), diagnostics=dict(record.get("diagnostics", {})),
            settings=dict(record.get("settings", {})), converged=bool(record.get("converged", False)),
            verdict=Verdict.from_record(record) if record.get("verdict") else None,
            warnings=list(record.get("warnings", [])), seconds=float(record.get("seconds", 0.0)))

    def named(self, parent: str, child: str) -> TransformResult:
        """The same result between frames called ``parent`` and ``child`` (a solver names them by role, the
        service by the rig's sensors)."""
        return TransformResult(**{**self.__dict__, "parent": parent, "child": child})


def jacobian_covariance(result: Any, n_params: int = 6) -> np.ndarray:
    """``sigma^2 (J^T J)^-1`` of a :func:`scipy.optimize.least_squares` result, with ``J`` its robust-loss-scaled
    Jacobian and ``sigma^2 = 2 cost / (m - n_params)`` (the robust cost: about the residual variance when most
    residuals are inliers); NaN when ``J^T J`` is singular."""
    J = result.jac
    dof = max(len(result.fun) - n_params, 1)
    sigma2 = 2 * result.cost / dof
    try:
        cov = sigma2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return np.full((n_params, n_params), np.nan)
    return 0.5 * (cov + cov.T)


def widen_covariance(cov_hessian: np.ndarray, std_spread: np.ndarray | None) -> np.ndarray:
    """``cov_hessian`` with each sigma raised to ``std_spread`` where that is larger, keeping its correlations.

    How the solvers combine their two uncertainty estimates: the Jacobian's (or Hessian's)
    covariance, which sees the model's noise, and a leave-one-out spread, which sees what
    moves whole views or poses together.
    """
    std_h = sigmas(cov_hessian)
    std = std_h if std_spread is None else np.fmax(std_h, std_spread)
    if not np.isfinite(cov_hessian).all():
        return np.diag(std**2)
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_hessian / np.outer(std_h, std_h)
    corr = np.where(np.isfinite(corr), np.clip(corr, -1, 1), 0.0)
    np.fill_diagonal(corr, 1.0)
    return np.outer(std, std) * corr


EDGE_KINDS = ("lidar_lidar", "lidar_camera", "multicam", "depth_node", "camera_imu", "lidar_imu")
"""Result kinds whose transforms are edges between rig frames (a sweep's geometry is inside its sensor)."""


@dataclass(frozen=True)
class StoredResult:
    """A result from the session's history as every consumer reads it (the rig, the result card, the report, the
    CLI), whatever solver made it and whenever it was stored: they ask it, and never look for keys in the record.

    Intrinsics keep their camera model beside this (:attr:`camera`); every other payload stays in :attr:`record`.
    """

    record: dict[str, Any]

    @property
    def kind(self) -> str:
        return str(self.record.get("kind"))

    @property
    def id(self) -> str:
        return str(self.record.get("id"))

    @property
    def sensor(self) -> str | None:
        return self.record.get("sensor")

    @property
    def method(self) -> str:
        return str(self.record.get("method") or "")

    @property
    def seconds(self) -> float:
        return float(self.record.get("seconds", 0.0))

    @property
    def converged(self) -> bool:
        """False only when the solver said so (a record without the flag, e.g. hand-set, counts as converged)."""
        return bool(self.record.get("converged", True))

    @property
    def warnings(self) -> list[str]:
        return list(self.record.get("warnings", []))

    @property
    def verdict(self) -> Verdict:
        """The stored verdict (one per camera folded into one for a multi-camera result); ``check`` without one."""
        return Verdict.from_record(self.record)

    @property
    def residuals(self) -> dict[str, Any]:
        """The result's own residual statistics (each transform carries its own too)."""
        return dict(self.record.get("residuals", {}))

    @property
    def rms_px(self) -> float | None:
        """The reprojection RMS (px) of a result that has one (intrinsics)."""
        value = self.record.get("rms_px")
        return float(value) if isinstance(value, int | float) else None

    @property
    def camera(self) -> dict[str, Any] | None:
        """The camera model an intrinsics result solved (``model``, ``width``, ``height``, ``K``, ``dist``)."""
        return self.record.get("camera") if self.kind == "intrinsics" else None

    @property
    def edges(self) -> list[TransformResult]:
        """The transforms it holds between rig frames (one per camera for a multi-camera result; none for
        intrinsics or a sweep geometry), with their covariances, verdicts and residuals."""
        if self.kind not in EDGE_KINDS:
            return []
        if "transforms" in self.record:  # multicam: one per camera
            return [TransformResult.from_record(t) for t in self.record["transforms"].values()]
        if "T_parent_child" not in self.record:
            return [TransformResult.from_record(t) for t in _legacy_transforms(self.record)]
        return [TransformResult.from_record(self.record)]

    @property
    def transforms(self) -> list[TransformResult]:
        """Every transform it holds: its :attr:`edges`, or a swept scanner's geometry inside its sensor."""
        if self.kind == "sweep" and "transform" in self.record:
            return [TransformResult.from_record(self.record["transform"])]
        return self.edges


def _legacy_transforms(record: dict[str, Any]) -> list[dict[str, Any]]:
    """Records stored before every solver returned a :class:`TransformResult` (their transform under its own
    name), read as transform records so sessions accepted then still form their tree."""
    kind, common = record["kind"], {"converged": record.get("converged", False), "method": record.get("method", "")}
    if kind == "multicam":
        return [{**common, "kind": kind, "parent": record["reference"], "child": name, "T_parent_child": T,
                 "covariance": record["covariance"][name]}
                for name, T in record["T_ref_cam"].items() if name != record["reference"]]
    parent, T = ((record["target"], record["T_target_source"]) if kind == "lidar_lidar"
                 else (record["camera"], record["T_camera_lidar"]))
    return [{**common, "kind": kind, "parent": parent, "child": record["sensor"], "T_parent_child": T,
             "covariance": record.get("covariance")}]
