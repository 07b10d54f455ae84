"""A camera's intrinsics' own uncertainty, carried into the board poses of a target LiDAR-to-camera solve.

The board poses come from PnP with the camera's intrinsics; intrinsics that are only loosely known (a fisheye
calibrated from 8 views of a small board) move every pose together, which no per-pose spread can see. Each
intrinsic parameter is moved by its 1-sigma, every pose is found again by PnP with it, and the solve is re-run at
fixed board points (:func:`backend.calib.lidar_camera.target.solve_target`): the moves, combined with the
parameters' correlation, are the lens's share of the result's covariance (first-order propagation by finite
differences, as a Jacobian through PnP would give it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from backend.calib.board.detection import Detection
from backend.calib.board.pose import board_pose
from backend.core.boards import BoardSpec
from backend.core.camera import DIST_NAMES, CameraIntrinsics
from backend.core.errors import InputError

K_ENTRIES = {"fx": ((0, 0),), "fy": ((1, 1),), "cx": ((0, 2),), "cy": ((1, 2),)}
"""Where each pinhole parameter sits in K."""
PHOTOGRAMMETRIC_K_ENTRIES = {"c": ((0, 0), (1, 1)), "xp": ((0, 2),), "yp": ((1, 2),)}
"""Where the photogrammetric model's principal distance (both focal entries) and principal point sit in K."""


def k_entries(model: str) -> dict[str, tuple[tuple[int, int], ...]]:
    """The parameters of ``model`` that sit in K, and where."""
    return PHOTOGRAMMETRIC_K_ENTRIES if model == "photogrammetric" else K_ENTRIES


@dataclass
class LensUncertainty:
    """The 1-sigma of some of a camera's intrinsic parameters and their correlation."""

    names: list[str]
    """Parameter names: ``fx``, ``fy``, ``cx``, ``cy`` (px; ``c``, ``xp``, ``yp`` in the photogrammetric model) and
    the model's distortion coefficients (``k1``...)."""
    sigma: np.ndarray
    """(P,) their 1-sigma (px; the coefficients unitless)."""
    correlation: np.ndarray
    """(P, P) their correlation; the identity when only the sigmas are known."""
    source: str
    """Where the numbers come from (an accepted result's id, ``--intrinsics-std``)."""

    @classmethod
    def from_sigmas(cls, camera: CameraIntrinsics, sigmas: list[float], source: str) -> LensUncertainty:
        """From ``fx, fy, cx, cy`` (photogrammetric: ``c, xp, yp``) and each of ``camera``'s distortion coefficients'
        1-sigma, in that order (uncorrelated); :class:`InputError` naming ``source`` for a wrong count or a negative
        sigma, or a splined lens (its control points are not given one by one)."""
        if camera.spline is not None:
            raise InputError("a splined lens's sigmas cannot be given one by one: solve its intrinsics in the session "
                             "and accept them", source)
        names = [*k_entries(camera.model), *DIST_NAMES[camera.model]]
        if len(sigmas) != len(names) or not all(np.isfinite(s) and s >= 0 for s in sigmas):
            raise InputError(f"expected {len(names)} sigmas of 0 or more, for {', '.join(names)} ({camera.model}); got "
                             f"{sigmas}", source)
        return cls(names, np.asarray(sigmas, float), np.eye(len(names)), source)

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> LensUncertainty | None:
        """From an intrinsics result's record (its ``std`` and ``correlation``); None when it holds no sigma, or for a
        splined lens, whose hundreds of control points are not moved one by one (its result's sigma map speaks for
        it)."""
        std, model = record.get("std") or {}, record["camera"]["model"]
        if model == "splined-stereographic":
            return None
        pinhole = {name: std.get(name) for name in K_ENTRIES}
        if model == "photogrammetric":  # c is fx and fy together
            pinhole = {"c": std.get("fx"), "xp": std.get("cx"), "yp": std.get("cy")}
        values = pinhole | dict(zip(DIST_NAMES[model], std.get("dist") or [],
                                                                        strict=False))
        names = [name for name, value in values.items() if value is not None and np.isfinite(value) and value > 0]
        if not names:
            return None
        stored = record.get("correlation") or {}
        order = {name: i for i, name in enumerate(stored.get("names", []))}
        matrix = np.asarray(stored.get("matrix", []), float)
        correlation = np.eye(len(names))
        if all(name in order for name in names) and matrix.size:
            index = [order[name] for name in names]
            correlation = matrix[np.ix_(index, index)]
        return cls(names, np.array([values[name] for name in names], float), correlation, record.get("id", "result"))

    def moved(self, camera: CameraIntrinsics) -> list[CameraIntrinsics]:
        """``camera`` with each parameter moved by its 1-sigma, one at a time (in :attr:`names` order)."""
        cameras = []
        for name, sigma in zip(self.names, self.sigma, strict=True):
            K, dist = camera.K.copy(), camera.dist.copy()
            entries = k_entries(camera.model)
            if name in entries:
                for entry in entries[name]:
                    K[entry] += sigma
            else:
                dist[DIST_NAMES[camera.model].index(name)] += sigma
            cameras.append(CameraIntrinsics(camera.model, camera.width, camera.height, K, dist))
        return cameras

    def board_poses(self, camera: CameraIntrinsics, board: BoardSpec, detection: Detection) -> np.ndarray | None:
        """(P, 4, 4) the board's pose (PnP on ``detection``) with each parameter moved by its 1-sigma; None when
        PnP fails for one."""
        poses = [board_pose(moved, board, detection) for moved in self.moved(camera)]
        return None if any(T is None for T in poses) else np.array(poses)
