"""The board's flex (mrcal's ``calobject_warp``), solved with the intrinsics.

A printed board bows, and a bow of a fraction of a millimetre moves a fitted lens by pixels in the image's corners
(mrcal's flex of 0.17 mm on OpenCV's 9x6 board moves its model by 3.4 px). The bow is mrcal's two parabolas, along
the board's x and y (:attr:`~backend.core.boards.BoardSpec.warp_basis`). OpenCV's solvers hold the board flat, so
their solve is refined here over the free intrinsics, every view's pose and the two flex terms together, by the
bundle Levenberg-Marquardt the photogrammetric model runs on (:func:`~backend.core.schur_lm.levenberg_marquardt`;
the intrinsics and the flex are the parameters every view shares) with analytic Jacobians: OpenCV's by the pose and
the intrinsics (:func:`~backend.calib.intrinsics.projection.project_board`) and, for the flex, the translation's
turned into the board's frame (:func:`flex_columns`).
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from backend.calib.board.detection import Detection
from backend.calib.intrinsics.projection import project_board
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.schur_lm import levenberg_marquardt

FLEX_MAX_STD_M = 0.5e-3
"""A flex term less certain than this (m, 1-sigma) is not determined by the views: the board is held flat, and the
result says so. On the shared real sets the flex's sigma is 0.01-0.05 mm."""


def flex_unsupported(board: object, model: str) -> str | None:
    """Why the flex cannot be solved for this target and lens model, or None when it can."""
    if not isinstance(board, BoardSpec):
        return "a surveyed test field's points are measured, not bowed"
    if model == "photogrammetric":
        return "the photogrammetric model's bundle adjustment holds the target as given"
    return None


def flex_columns(J: np.ndarray, rvec: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(2N, 2) Jacobian of a view's projected corners by the flex along x and y, from the projection's Jacobian
    ``J`` (2N, 6 + ...; :func:`project_board`'s columns) at the view's pose ``rvec`` and the corners' ``basis`` (N,
    2; :attr:`~backend.core.boards.BoardSpec.warp_basis`). A corner lifted by ``dz`` along the board's normal moves
    in the camera as a shift of ``R e_z dz`` does, so the translation's columns turned by ``R`` give it exactly."""
    normal_camera = cv2.Rodrigues(np.asarray(rvec, float))[0][:, 2]
    return (J[:, 3:6] @ normal_camera)[:, None] * np.repeat(basis, 2, axis=0)


Prior = Callable[[CameraIntrinsics], tuple[np.ndarray, np.ndarray]]
"""A lens's prior residuals and their Jacobian by ``[fx, fy, cx, cy, dist...]`` (the splined model's
regularization, :func:`backend.calib.intrinsics.splined.regularization`)."""


def refine_with_flex(camera: CameraIntrinsics, free: np.ndarray, board: BoardSpec, detections: list[Detection],
                     rvecs: list[np.ndarray], tvecs: list[np.ndarray], solve_flex: bool = True,
                     prior: Prior | None = None):
    """The least-squares solve of ``detections`` over the free intrinsics (``free``: the (n_all, n_free) map of
    their changes to ``[fx, fy, cx, cy, dist...]``), every view's pose and, with ``solve_flex``, the board's flex,
    from ``camera``, the poses and ``board.warp_m``; a ``prior``'s rows are solved with the first view's (with no
    pose columns). Returns ``(K, dist, rvecs, tvecs, board)``, the board bowed by the solved flex."""
    n_free, n_views, n_flex = free.shape[1], len(detections), 2 * solve_flex
    start_vector = camera.parameters
    flat = [board.plane_xy[d.ids] for d in detections]
    basis = [board.warp_basis[d.ids] for d in detections]

    def unpack(params: np.ndarray) -> tuple[CameraIntrinsics, np.ndarray, np.ndarray]:
        return (camera.with_parameters(start_vector + free @ params[:n_free]),
                params[n_free:n_free + 2] if solve_flex else board.warp_m, params[n_free + n_flex:].reshape(n_views, 6))

    def evaluate(params: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
        """Each view's residuals (2N,), Jacobian by the intrinsics and the flex (2N, n_free + 2) and by its pose."""
        model, warp, poses = unpack(params)
        residuals, shared, pose = [], [], []
        for xy, b, detection, p in zip(flat, basis, detections, poses, strict=True):
            pixels, J = project_board(model, np.column_stack([xy, b @ warp]), p[:3], p[3:])
            residuals.append((pixels - detection.corners_px).ravel())
            shared.append(np.column_stack([J[:, 6:] @ free, *([flex_columns(J, p[:3], b)] if solve_flex else [])]))
            pose.append(J[:, :6])
        if prior is not None:
            r, J = prior(model)
            residuals[0] = np.concatenate([residuals[0], r])
            shared[0] = np.vstack([shared[0], np.column_stack([J @ free, np.zeros((len(r), n_flex))])])
            pose[0] = np.vstack([pose[0], np.zeros((len(r), 6))])
        return residuals, shared, pose

    poses = np.column_stack([np.reshape(rvecs, (n_views, 3)), np.reshape(tvecs, (n_views, 3))])
    start = np.concatenate([np.zeros(n_free), board.warp_m if solve_flex else [], poses.ravel()])
    model, warp, poses = unpack(levenberg_marquardt(evaluate, start, n_free + n_flex))
    return (model.K, model.dist, [p[:3].reshape(3, 1) for p in poses], [p[3:].reshape(3, 1) for p in poses],
            board.with_warp(warp))


def solved_board(record: dict) -> BoardSpec:
    """The board an intrinsics result's ``record`` was solved with: its spec (``board``) bowed by the flex it
    solved (``board_flex``; flat when none was, or in a record older than the flex)."""
    board = BoardSpec.parse(record["board"])
    flex = record.get("board_flex")
    if flex is None or flex["status"] != "solved":
        return board
    return board.with_warp(np.asarray(flex["warp_mm"], float) / 1e3)
