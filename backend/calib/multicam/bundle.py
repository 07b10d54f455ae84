"""Joint multi-camera calibration: one bundle adjustment over every camera and every board pose.

All cameras are solved at once, so the answer does not depend on the order in which
they are named (a camera chain, as Kalibr's ``T_cn_cnm1`` is usually estimated pair
by pair, does): the first camera only fixes the gauge, and every other ordering gives
the same rig to numerical precision.

Model. A frame is one moment at which the cameras were triggered together; the board
is at ``T_ref_board[f]`` in the reference camera's optical frame, camera ``c`` at
``T_ref_cam[c]``. Corner ``X`` (board frame, m) of frame ``f`` lands at pixel
``project_c(inv(T_ref_cam[c]) @ T_ref_board[f] @ X)``. Unknowns: every non-reference
camera's pose, every frame's board pose and, for the cameras asked for, the
intrinsics (fx, fy, cx, cy and the distortion terms in use). Each pose is perturbed
as ``[R0 Exp(phi), t0 + dt]``: translation in the reference's axes (m), rotation about
the child's own axes (rad), the order of :data:`~backend.core.result.TRANSFORM_PARAMETERS`,
so the covariance blocks are the conventions' sigmas directly.

Solve. SciPy's trust-region least squares on the sparse Jacobian (finite differences
grouped by the sparsity pattern: a board pose touches only its frame's corners), with a
soft-L1 loss. Corners whose residual exceeds :attr:`MulticamSettings.outlier_sigmas`
robust sigmas (and at least ``outlier_min_px``) are flagged and dropped, and frames
whose RMS is far above their camera's typical frame are flagged and dropped, then
the problem is solved again. A last solve re-linearised at the answer gives the
covariance ``sigma^2 (J^T J)^-1`` (``sigma^2`` from the residuals; the noise model:
independent isotropic Gaussian corner noise), from which each camera's 1-sigma and the
correlations come.

Result. :class:`MulticamResult` holds one :class:`~backend.core.result.TransformResult` per camera but the
reference (``kind`` ``multicam``, ``method`` ``bundle``, parent the reference, child the camera), so the rig
graph, the result card and the report read a camera's pose as they read any other solver's; the intrinsics, the
per-view residuals, the observation graph and the pair checks stay with the rig.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import cv2
import numpy as np
from scipy.sparse import coo_matrix, csr_matrix

from backend.calib.multicam.checks import camera_verdicts, intrinsics_projection_sigma_px, pair_checks
from backend.calib.multicam.graph import (
    Observation,
    ObservationGraph,
    check_connected,
    initial_rig,
    observation_graph,
)
from backend.core.boards import BoardSpec
from backend.core.camera import DIST_NAMES, CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import (
    ProgressCallback,
    SolveResult,
    TransformResult,
    finite_or_none,
    no_progress,
    transform_std,
)
from backend.core.transforms import apply_params_many, skew
from backend.core.uncertainty import sigmas
from backend.core.verdict import Verdict

MIN_CORNERS = 4
"""Fewest corners for an observation to be used (PnP needs 4)."""
INTRINSIC_NAMES = ["fx", "fy", "cx", "cy"]


@dataclass
class MulticamSettings:
    """How the joint solve runs."""

    estimate_intrinsics: list[str] = field(default_factory=list)
    """Cameras whose intrinsics are refined with the rig (the others keep theirs, e.g. from their own step)."""
    loss_scale_px: float = 1.0
    """Soft-L1 loss scale (px): residuals well below it count as squares, far above as absolute values."""
    outlier_sigmas: float = 5.0
    """A corner is an outlier beyond this many robust sigmas (the median residual length / sqrt(2 ln 2): a 2-D normal's
    sigma per axis)."""
    outlier_min_px: float = 1.0
    """... and never below this many pixels."""
    frame_outlier_factor: float = 3.0
    """A frame of a camera is flagged when its RMS exceeds this many times that camera's median frame RMS."""
    outlier_rounds: int = 3
    """Rounds of flagging and re-solving (each leaves out at most the worst view of every frame)."""
    max_iterations: int = 50
    """Levenberg-Marquardt steps per solve before giving up."""
    max_rms_px: float = 5.0
    """An RMS above this after the solve means the solve diverged or the data disagree: not converged."""


@dataclass
class FrameResidual:
    """One camera's view of the board in one frame after the solve."""

    camera: str
    frame: str
    rms_px: float
    """RMS (px) over the view's inlier corners at the answer (over all its corners when it was left out)."""
    corners: int
    outlier_corners: int
    flagged: bool
    """The whole view was left out (its RMS stood out, or most of its corners were outliers)."""

    def to_record(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class MulticamResult(SolveResult):
    """The rig of cameras, each relative to the reference (the first camera named): one
    :class:`~backend.core.result.TransformResult` per other camera (kind ``multicam``, method ``bundle``,
    parent the reference, child the camera), with every camera's intrinsics and the joint solve's diagnostics."""

    kind = "multicam"

    reference: str
    cameras: dict[str, CameraIntrinsics]
    transforms: dict[str, TransformResult]
    """Every non-reference camera's pose in the reference camera's optical frame, with its 6x6 covariance."""
    intrinsics_std: dict[str, dict[str, float | None]]
    """1-sigma of the refined intrinsics (px, or unitless for distortion terms) of cameras that were estimated."""
    intrinsics_projection_sigma_px: dict[str, float]
    """Worst 1-sigma (px) across the image of projecting a far point, per camera whose intrinsics were estimated."""
    rms_px: dict[str, float]
    frames: list[FrameResidual]
    T_ref_board: dict[str, np.ndarray]
    """Board pose (4x4, m) of every frame used, in the reference camera's frame."""
    graph: ObservationGraph
    correlation: dict[str, Any]
    """Correlation matrix over every camera pose parameter, with its names."""
    board: BoardSpec
    settings: MulticamSettings
    converged: bool
    seconds: float
    warnings: list[str] = field(default_factory=list)
    pairs: list[dict[str, Any]] = field(default_factory=list)
    """:func:`~backend.calib.multicam.checks.pair_checks`: baseline and epipolar RMS of each pair that shared sets."""
    reference_verdict: Verdict | None = None
    """The reference camera's verdict (its pose fixes the gauge: convergence and its pair checks); the other
    cameras' verdicts are their transforms'."""

    @property
    def T_ref_cam(self) -> dict[str, np.ndarray]:
        """4x4 (m) per camera, in camera order: maps points in its optical frame into the reference camera's
        (the identity for the reference)."""
        return {name: np.eye(4) if name == self.reference else self.transforms[name].T_parent_child
                for name in self.cameras}

    @property
    def verdicts(self) -> dict[str, Verdict]:
        """How far each camera can be trusted (:func:`~backend.calib.multicam.checks.camera_verdicts`), in camera
        order; empty until judged."""
        verdicts = {name: self.reference_verdict if name == self.reference else self.transforms[name].verdict
                    for name in self.cameras}
        return {name: v for name, v in verdicts.items() if v is not None}

    def set_verdicts(self, verdicts: dict[str, Verdict]) -> None:
        """Give the reference and every transform its verdict (one per camera)."""
        self.reference_verdict = verdicts[self.reference]
        for name, transform in self.transforms.items():
            transform.verdict = verdicts[name]

    def summary(self) -> dict[str, Any]:
        """The ``multicam`` CLI JSON of ``conventions.md``: every camera, the reference's identity and zero sigmas
        included."""
        zero = transform_std(np.zeros((6, 6)))
        return {"cameras": {name: camera.to_dict() for name, camera in self.cameras.items()},
                "T_ref_cam": {name: T.tolist() for name, T in self.T_ref_cam.items()},
                "std": {name: zero if name == self.reference else self.transforms[name].std for name in self.cameras},
                "rms_px": dict(self.rms_px),
                "seconds": self.seconds,
                "verdict": {name: verdict.to_dict() for name, verdict in self.verdicts.items()}}

    def to_record(self) -> dict[str, Any]:
        """``"transforms": {CAMERA: TransformResult record}`` with every camera's intrinsics, RMS and verdict (the
        reference's too) and the joint solve's diagnostics (frames, board poses, graph, pair checks, correlation)."""
        return {"kind": self.kind, "reference": self.reference,
                "cameras": {name: camera.to_dict() for name, camera in self.cameras.items()},
                "transforms": {name: t.to_record() for name, t in self.transforms.items()},
                "rms_px": dict(self.rms_px), "seconds": self.seconds,
                "verdict": {name: verdict.to_dict() for name, verdict in self.verdicts.items()},
                "board": str(self.board), "board_flex_mm": [1e3 * w for w in self.board.warp_m],
                "settings": asdict(self.settings), "intrinsics_std": self.intrinsics_std,
                "intrinsics_projection_sigma_px": {name: finite_or_none([sigma])[0] for name, sigma
                                                   in self.intrinsics_projection_sigma_px.items()},
                "pairs": self.pairs, "frames": [f.to_record() for f in self.frames],
                "T_ref_board": {name: T.tolist() for name, T in self.T_ref_board.items()},
                "graph": self.graph.to_record(), "correlation": self.correlation, "converged": self.converged,
                "warnings": list(self.warnings)}


def _free_intrinsics(camera: CameraIntrinsics) -> list[str]:
    """Names of a refined camera's free parameters: fx, fy, cx, cy and the distortion terms in use
    (``pinhole-radtan``: k1, k2, p1, p2, and k3 when it is not zero)."""
    dist = DIST_NAMES[camera.model]
    if not camera.is_fisheye and camera.dist[4] == 0:
        dist = dist[:4]
    return INTRINSIC_NAMES + dist


def _pixel_jacobians(camera: CameraIntrinsics, p_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels (N, 2), d pixel / d point (N, 2, 3) and d pixel / d [fx, fy, cx, cy, dist...] (N, 2, 4 + len(dist))
    of points (N, 3) in the optical frame (m), from OpenCV's analytic projection Jacobians (at rvec = tvec = 0 the
    translation columns are the derivatives by the point itself)."""
    points = np.ascontiguousarray(p_cam, dtype=np.float64).reshape(-1, 1, 3)
    if camera.is_fisheye:
        uv, J = cv2.fisheye.projectPoints(points, np.zeros(3), np.zeros(3), camera.K, camera.dist[:4])
        d_point, d_intrinsics = J[:, 11:14], J[:, :8]
    else:
        uv, J = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.K, camera.dist[:5])
        d_point, d_intrinsics = J[:, 3:6], J[:, 6:15]
    n = len(p_cam)
    return uv.reshape(n, 2), d_point.reshape(n, 2, 3), d_intrinsics.reshape(n, 2, -1)


class _Problem:
    """The stacked corners, the current rig and board poses, and the parameter layout of a step:
    ``[camera poses (but the reference's) | board poses | free intrinsics]``, each pose 6 values
    ``[dt (m), phi (rad)]`` about the current pose (every step is taken from a re-linearised state)."""

    def __init__(self, cameras: dict[str, CameraIntrinsics], board: BoardSpec, observations: list[Observation],
                 T_ref_cam: dict[str, np.ndarray], T_ref_board: dict[str, np.ndarray], estimate: list[str]):
        self.names = list(cameras)
        self.cameras = dict(cameras)
        self.frames = list(T_ref_board)
        frame_index = {f: i for i, f in enumerate(self.frames)}
        self.observations = sorted(observations, key=lambda o: self.names.index(o.camera))
        self.obs_camera = np.array([self.names.index(o.camera) for o in self.observations])
        self.obs_frame = np.array([frame_index[o.frame] for o in self.observations])
        counts = np.array([len(o.detection.ids) for o in self.observations])
        self.corner_obs = np.repeat(np.arange(len(self.observations)), counts)
        self.corner_camera = self.obs_camera[self.corner_obs]
        self.corner_frame = self.obs_frame[self.corner_obs]
        self.X = np.concatenate([o.detection.object_points(board) for o in self.observations]).astype(float)
        self.uv = np.concatenate([o.detection.corners_px for o in self.observations])
        self.camera_slices = [slice(*np.searchsorted(self.corner_camera, [c, c + 1])) for c in range(len(self.names))]
        self.free = {name: _free_intrinsics(cameras[name]) for name in estimate}
        self.free_columns = {name: [(INTRINSIC_NAMES + DIST_NAMES[cameras[name].model]).index(q) for q in free]
                             for name, free in self.free.items()}
        """Where each refined camera's free parameters sit in ``[fx, fy, cx, cy, dist...]``."""
        self.T_cam = np.stack([T_ref_cam[n] for n in self.names])
        self.T_board = np.stack([T_ref_board[f] for f in self.frames])

    @property
    def n_camera_params(self) -> int:
        return 6 * (len(self.names) - 1)

    @property
    def n_params(self) -> int:
        return self.n_camera_params + 6 * len(self.frames) + sum(len(v) for v in self.free.values())

    def intrinsics_offsets(self) -> dict[str, slice]:
        """Where each refined camera's free intrinsics sit in a step."""
        start, offsets = self.n_camera_params + 6 * len(self.frames), {}
        for name, free in self.free.items():
            offsets[name] = slice(start, start + len(free))
            start += len(free)
        return offsets

    def _points_in_cameras(self, T_cam: np.ndarray, T_board: np.ndarray) -> np.ndarray:
        """Every corner in its observing camera's optical frame (N, 3), m."""
        T_cam_board = np.linalg.inv(T_cam)[self.obs_camera] @ T_board[self.obs_frame]
        R, t = T_cam_board[self.corner_obs, :3, :3], T_cam_board[self.corner_obs, :3, 3]
        return np.einsum("nij,nj->ni", R, self.X) + t

    def residuals(self, state: tuple[np.ndarray, np.ndarray, dict[str, CameraIntrinsics]] | None = None
                  ) -> np.ndarray:
        """Projected minus detected corner (N, 2) px, at ``state`` (rig, boards, cameras) or the current one."""
        T_cam, T_board, cameras = state or (self.T_cam, self.T_board, self.cameras)
        p = self._points_in_cameras(T_cam, T_board)
        projected = np.empty_like(self.uv)
        for name, where in zip(self.names, self.camera_slices, strict=True):
            z = p[where, 2]
            projected[where, 0], projected[where, 1] = cameras[name].normalised_to_pixels(p[where, 0] / z,
                                                                                          p[where, 1] / z)
        return projected - self.uv

    def linearise(self) -> tuple[np.ndarray, csr_matrix]:
        """Residuals (N, 2) px and their sparse Jacobian (2N, n_params) by a step's parameters at the current state."""
        p = self._points_in_cameras(self.T_cam, self.T_board)
        residuals = np.empty_like(self.uv)
        d_point = np.empty((len(p), 2, 3))
        blocks = []  # (corner indices, first column, (n, 2, k) values)
        offsets = self.intrinsics_offsets()
        for name, where in zip(self.names, self.camera_slices, strict=True):
            uv, d_point[where], d_intrinsics = _pixel_jacobians(self.cameras[name], p[where])
            residuals[where] = uv - self.uv[where]
            if name in self.free:
                corners = np.arange(where.start, where.stop)
                blocks.append((corners, np.full(len(corners), offsets[name].start),
                               d_intrinsics[:, :, self.free_columns[name]]))
        R_cam_t = self.T_cam[self.corner_camera, :3, :3].transpose(0, 2, 1)
        R_board = self.T_board[self.corner_frame, :3, :3]
        d_translation = d_point @ R_cam_t  # d pixel / d t (reference axes), for the board (+) and the camera (-)
        d_board_rotation = -(d_point @ (R_cam_t @ R_board)) @ skew(self.X)
        d_camera_rotation = d_point @ skew(p)
        all_corners = np.arange(len(p))
        blocks.append((all_corners, self.n_camera_params + 6 * self.corner_frame,
                       np.concatenate([d_translation, d_board_rotation], axis=2)))
        moving = np.flatnonzero(self.corner_camera > 0)
        blocks.append((moving, 6 * (self.corner_camera[moving] - 1),
                       np.concatenate([-d_translation[moving], d_camera_rotation[moving]], axis=2)))
        rows, cols, values = [], [], []
        for corners, first, block in blocks:
            k = block.shape[2]
            rows.append(np.repeat((2 * corners[:, None] + np.arange(2)).ravel(), k))
            cols.append(np.repeat(first[:, None] + np.arange(k), 2, axis=0).ravel())
            values.append(block.ravel())
        J = coo_matrix((np.concatenate(values), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(2 * len(p), self.n_params)).tocsr()
        return residuals, J

    def stepped(self, step: np.ndarray) -> tuple[np.ndarray, np.ndarray, dict[str, CameraIntrinsics]]:
        """The state after a step: ``R <- R Exp(phi)``, ``t <- t + dt``, intrinsics plus their part."""
        camera_step = np.vstack([np.zeros((1, 6)), step[:self.n_camera_params].reshape(-1, 6)])
        board_step = step[self.n_camera_params:self.n_camera_params + 6 * len(self.frames)].reshape(-1, 6)
        cameras = dict(self.cameras)
        for name, where in self.intrinsics_offsets().items():
            vector = cameras[name].parameters
            vector[self.free_columns[name]] += step[where]
            cameras[name] = cameras[name].with_parameters(vector)
        return apply_params_many(self.T_cam, camera_step), apply_params_many(self.T_board, board_step), cameras

    def take(self, state: tuple[np.ndarray, np.ndarray, dict[str, CameraIntrinsics]]) -> None:
        self.T_cam, self.T_board, self.cameras = state[0], state[1], dict(state[2])

    def answer(self) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, CameraIntrinsics]]:
        return (dict(zip(self.names, self.T_cam, strict=True)), dict(zip(self.frames, self.T_board, strict=True)),
                dict(self.cameras))


def _soft_l1(residuals: np.ndarray, scale_px: float) -> tuple[float, np.ndarray]:
    """Robust cost ``sum 2 c^2 (sqrt(1 + |r|^2 / c^2) - 1)`` over corners and each corner's IRLS weight (its
    derivative by ``|r|^2``), for residuals (N, 2) px: a corner's two coordinates share one weight."""
    s = np.einsum("ni,ni->n", residuals, residuals) / scale_px**2
    root = np.sqrt(1 + s)
    return float(2 * scale_px**2 * np.sum(root - 1)), 1 / root


@dataclass
class _Solve:
    """Where a Levenberg-Marquardt run ended."""

    residuals: np.ndarray
    """(N, 2) px at the answer."""
    normal: _NormalEquations
    """The weighted normal equations at the answer."""
    iterations: int
    converged: bool
    message: str


class _NormalEquations:
    """``J^T W J`` and ``J^T W r`` split into the few rig parameters (camera poses and intrinsics, ``a``) and the
    many board poses (``b``, 6x6 blocks on the diagonal), solved through the Schur complement of the board blocks
    (the classic bundle-adjustment reduction: a 6x6 inverse per frame and one small dense solve)."""

    def __init__(self, problem: _Problem, J: csr_matrix, residuals: np.ndarray, weights: np.ndarray):
        W = np.repeat(weights, 2)
        JtW = J.T.multiply(W).tocsr()
        H = (JtW @ J).tocsr()
        g = JtW @ residuals.ravel()
        n_frames, first_board = len(problem.frames), problem.n_camera_params
        self.board_index = first_board + np.arange(6 * n_frames)
        self.rig_index = np.setdiff1d(np.arange(problem.n_params), self.board_index)
        blocks = self.board_index.reshape(n_frames, 6)
        self.D = np.asarray(H[np.repeat(blocks, 6, axis=1).ravel(), np.tile(blocks, (1, 6)).ravel()]).reshape(
            n_frames, 6, 6)
        self.A = H[self.rig_index][:, self.rig_index].toarray()
        self.B = H[self.rig_index][:, self.board_index].toarray().reshape(len(self.rig_index), n_frames, 6)
        self.g_rig, self.g_board = g[self.rig_index], g[self.board_index].reshape(n_frames, 6)
        self.weighted_ssr = float(W @ residuals.ravel() ** 2)
        self.n_params = problem.n_params

    def _reduced(self, damping: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A - B D^-1 B^T, D^-1, B D^-1)`` with Levenberg-Marquardt damping ``(1 + damping)`` on the diagonals."""
        A = self.A + damping * np.diag(np.maximum(np.diag(self.A), 1e-12))
        D = self.D + damping * np.einsum("fij,ij->fij", self.D, np.eye(6))
        D_inv = np.linalg.inv(D)
        BD_inv = np.einsum("afi,fij->afj", self.B, D_inv)
        return A - np.einsum("afj,bfj->ab", BD_inv, self.B), D_inv, BD_inv

    def step(self, damping: float) -> np.ndarray:
        """The damped Gauss-Newton step over all parameters (raises LinAlgError when singular)."""
        S, D_inv, BD_inv = self._reduced(damping)
        rig = np.linalg.solve(S, -(self.g_rig - np.einsum("afj,fj->a", BD_inv, self.g_board)))
        board = -np.einsum("fij,fj->fi", D_inv, self.g_board + np.einsum("afi,a->fi", self.B, rig))
        step = np.empty(self.n_params)
        step[self.rig_index], step[self.board_index] = rig, board.ravel()
        return step

    def rig_covariance(self, n_residuals: int) -> np.ndarray:
        """``sigma^2`` times the rig block of ``(J^T W J)^-1`` (the inverse Schur complement), with ``sigma^2`` the
        weighted residual variance per degree of freedom; NaN when singular."""
        sigma2 = self.weighted_ssr / max(n_residuals - self.n_params, 1)
        try:
            cov = sigma2 * np.linalg.inv(self._reduced(0.0)[0])
        except np.linalg.LinAlgError:
            return np.full(self.A.shape, np.nan)
        return 0.5 * (cov + cov.T)


def _solve(problem: _Problem, settings: MulticamSettings, report: Callable[[str], None]) -> _Solve:
    """Levenberg-Marquardt with iteratively reweighted soft-L1 on the Schur-reduced normal equations.

    Written by hand because neither library fits: OpenCV has no multi-camera bundle adjustment in its
    Python build (``calibrateMultiview`` is absent from opencv-python 4.14), and SciPy's ``least_squares``
    (trf, lsmr, sparse finite differences) took 184 s and still stopped at its evaluation limit on 6 cameras x
    245 frames. With analytic Jacobians (OpenCV's projection Jacobians chained through the poses) and the
    board poses eliminated per frame, a step takes a fraction of a second and the answer converges to the
    1e-12 level, so every camera order gives the same rig.
    """
    damping = 1e-4
    residuals, J = problem.linearise()
    cost, weights = _soft_l1(residuals, settings.loss_scale_px)
    normal = _NormalEquations(problem, J, residuals, weights)
    for iteration in range(1, settings.max_iterations + 1):
        while True:
            try:
                step = normal.step(damping)
            except np.linalg.LinAlgError:
                return _Solve(residuals, normal, iteration, False, "singular normal equations")
            trial = problem.stepped(step)
            trial_cost, _ = _soft_l1(problem.residuals(trial), settings.loss_scale_px)
            if np.isfinite(trial_cost) and trial_cost <= cost:
                break
            damping *= 10
            if damping > 1e8:
                return _Solve(residuals, normal, iteration, True, "no further decrease")
        problem.take(trial)
        damping = max(damping / 10, 1e-9)
        residuals, J = problem.linearise()
        previous, (cost, weights) = cost, _soft_l1(residuals, settings.loss_scale_px)
        normal = _NormalEquations(problem, J, residuals, weights)
        report(f"step {iteration}, cost {cost:.6g}")
        if previous - cost <= 1e-14 * previous or np.max(np.abs(step)) < 1e-12:
            return _Solve(residuals, normal, iteration, True, "converged")
    return _Solve(residuals, normal, settings.max_iterations, False,
                  f"no convergence in {settings.max_iterations} steps")


def _views(problem: _Problem, residuals: np.ndarray) -> list[tuple[Observation, np.ndarray]]:
    """Each observation with its corners' residual lengths (px), from residuals (N, 2)."""
    lengths = np.linalg.norm(residuals, axis=1)
    bounds = np.searchsorted(problem.corner_obs, np.arange(len(problem.observations) + 1))
    return [(obs, lengths[a:b]) for obs, a, b in zip(problem.observations, bounds[:-1], bounds[1:], strict=True)]


def _rms(lengths: np.ndarray) -> float:
    return float(np.sqrt(np.mean(lengths**2)))


def _judge_views(judge: _Problem, settings: MulticamSettings) -> tuple[list[Observation], list[FrameResidual]]:
    """Every view of ``judge`` (all its detected corners, at its state) judged: the observations to keep (outlier
    corners removed) and each view's outcome, the worst bad view of each frame flagged to be left out.

    Only the worst view of a frame is left out per round, since one bad view drags its frame's board pose and
    with it the frame's other views, which are judged again after a re-solve."""
    residuals = judge.residuals()
    # The median length of a 2-D isotropic normal's residual is sigma * sqrt(2 ln 2).
    sigma = np.median(np.linalg.norm(residuals, axis=1)) / np.sqrt(2 * np.log(2))
    limit = max(settings.outlier_min_px, settings.outlier_sigmas * sigma)
    views = [(obs, r, r <= limit) for obs, r in _views(judge, residuals)]
    typical = {name: np.median([_rms(r[inlier]) for o, r, inlier in views if o.camera == name and inlier.any()]
                               or [np.inf]) for name in judge.names}
    outcomes, worst = [], {}
    for obs, r, inlier in views:
        outcome = FrameResidual(obs.camera, obs.frame, _rms(r), len(r), int((~inlier).sum()), False)
        bad = (inlier.sum() < max(MIN_CORNERS, len(r) // 2) or _rms(r[inlier]) > settings.frame_outlier_factor
               * max(typical[obs.camera], settings.outlier_min_px / 3))
        if bad and (obs.frame not in worst or outcome.rms_px > worst[obs.frame].rms_px):
            worst[obs.frame] = outcome
        outcomes.append(outcome)
    kept = []
    for i, (obs, _, inlier) in enumerate(views):
        if worst.get(obs.frame) is outcomes[i]:
            outcomes[i] = replace(outcomes[i], flagged=True)
        elif obs.frame in worst:
            kept.append(obs)  # its corners were dragged by the view left out: judged again after the re-solve
        else:
            d = obs.detection
            kept.append(replace(obs, detection=replace(d, corners_px=d.corners_px[inlier], ids=d.ids[inlier])))
    return kept, outcomes


def worst_fitting_camera(outcomes: list[FrameResidual]) -> tuple[str, float, float]:
    """The camera whose views fit worst: its name, its median view RMS and the other cameras' (px)."""
    medians = {c: float(np.median([f.rms_px for f in outcomes if f.camera == c])) for c in {f.camera for f in outcomes}}
    worst = max(sorted(medians), key=medians.__getitem__)
    return worst, medians[worst], float(np.median([v for c, v in medians.items() if c != worst]))


def _check_views_left(cameras: list[str], kept: list[Observation], outcomes: list[FrameResidual]) -> None:
    """Refuse, naming the camera that fits worst, when leaving out the views that disagree leaves a camera without
    views or cut off from the others (wrong intrinsics or board spec)."""
    worst, worst_rms, others_rms = worst_fitting_camera(outcomes)
    advice = (f"camera {worst} fits worst (median RMS {worst_rms:.2f} px against {others_rms:.2f} px for the "
              f"others): check its intrinsics and the board spec")
    for name in cameras:
        if not any(o.camera == name for o in kept):
            raise InputError(f"every view of camera {name} disagrees with the other cameras; {advice}", worst)
    try:
        check_connected(observation_graph(cameras, [(o.camera, o.frame) for o in kept]))
    except InputError as exc:
        raise InputError(f"leaving out the views that disagree, {exc.message.split(' (nor')[0]}; {advice}",
                         worst) from None


def _without_outliers(problem: _Problem, board: BoardSpec, observations: list[Observation], estimate: list[str],
                      settings: MulticamSettings, solve: _Solve, report: Callable[[float, str], Callable[[str], None]]
                      ) -> tuple[_Problem, _Solve, list[FrameResidual]]:
    """Rounds of judging every remaining view at the latest answer and re-solving without the outliers, until
    nothing changes (or :attr:`MulticamSettings.outlier_rounds`)."""
    left_out: dict[tuple[str, str], FrameResidual] = {}
    outcomes: list[FrameResidual] = []
    for round_ in range(1, settings.outlier_rounds + 1):
        T_ref_cam, T_ref_board, cameras = problem.answer()
        candidates = [o for o in observations if (o.camera, o.frame) not in left_out]
        kept, outcomes = _judge_views(_Problem(cameras, board, candidates, T_ref_cam, T_ref_board, []), settings)
        left_out.update({(f.camera, f.frame): f for f in outcomes if f.flagged})
        if [(o.camera, o.frame, o.detection.ids.tolist()) for o in kept] == [
                (o.camera, o.frame, o.detection.ids.tolist()) for o in problem.observations]:
            break
        _check_views_left(problem.names, kept, outcomes)
        used_frames = {o.frame for o in kept}
        problem = _Problem(cameras, board, kept, T_ref_cam, {f: T for f, T in T_ref_board.items() if f in used_frames},
                           estimate)
        solve = _solve(problem, settings, report(0.5 + 0.1 * round_, f"solving without the outliers ({round_})"))
    judged = {(f.camera, f.frame): f for f in outcomes}
    return problem, solve, [judged.get(key, f) for key, f in left_out.items()] + [
        f for key, f in judged.items() if key not in left_out]


def _correlation(problem: _Problem, cov: np.ndarray) -> dict[str, Any]:
    """Correlations between every non-reference camera's pose parameters (``cov``: the rig covariance)."""
    n = problem.n_camera_params
    names = [f"{camera}.{p}" for camera in problem.names[1:] for p in ("t_x", "t_y", "t_z", "r_x", "r_y", "r_z")]
    std = sigmas(cov[:n, :n])
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov[:n, :n] / np.outer(std, std)
    return {"names": names, "matrix": [finite_or_none(row) for row in corr]}


def _check_observations(cameras: dict[str, CameraIntrinsics], observations: list[Observation]) -> list[Observation]:
    """The usable observations (finite, at least :data:`MIN_CORNERS`); refuses unknown or unconnected cameras."""
    if len(cameras) < 2:
        raise InputError(f"a multi-camera solve needs at least two cameras, got {list(cameras)}", "cameras")
    unknown = sorted({o.camera for o in observations} - set(cameras))
    if unknown:
        raise InputError(f"observations of camera {unknown[0]}, which is not among {list(cameras)}", unknown[0])
    usable = [o for o in observations
              if len(o.detection.ids) >= MIN_CORNERS and np.isfinite(o.detection.corners_px).all()]
    check_connected(observation_graph(list(cameras), [(o.camera, o.frame) for o in usable]))
    return usable


def calibrate_multicam(cameras: dict[str, CameraIntrinsics], board: BoardSpec, observations: list[Observation],
                       settings: MulticamSettings | None = None, progress: ProgressCallback = no_progress
                       ) -> MulticamResult:
    """Solve every camera's ``T_ref_cam`` (and the intrinsics asked for) from board views seen together.

    ``cameras`` holds each camera's intrinsics (fixed unless named in ``settings.estimate_intrinsics``,
    then the starting point), the first being the reference. Raises :class:`InputError` naming the camera
    when one never saw the board or never shares a frame with the others.
    """
    settings = settings or MulticamSettings()
    started = time.perf_counter()
    missing = sorted(set(settings.estimate_intrinsics) - set(cameras))
    if missing:
        raise InputError(f"cannot estimate the intrinsics of {missing[0]}: not among {list(cameras)}", missing[0])
    observations = _check_observations(cameras, observations)
    progress(0.05, "initial rig from PnP along the observation graph")
    T_ref_cam, T_ref_board = initial_rig(cameras, board, observations)
    observations = [o for o in observations if o.frame in T_ref_board]
    estimate = [name for name in cameras if name in settings.estimate_intrinsics]

    def report(fraction: float, message: str) -> Callable[[str], None]:
        return lambda detail: progress(fraction, f"{message}: {detail}")

    # Rig and boards first with every camera's intrinsics held: freeing the intrinsics of a roughly calibrated
    # camera from a rough rig lets them wander off to a wrong minimum (seen on the demo's wide camera).
    problem = _Problem(cameras, board, observations, T_ref_cam, T_ref_board, [])
    first = _solve(problem, settings, report(0.1, "solving the rig"))
    if estimate:
        problem = _Problem(problem.cameras, board, observations, *problem.answer()[:2], estimate)
        first = _solve(problem, settings, report(0.3, "solving the rig and the intrinsics"))
    problem, solve, outcomes = _without_outliers(problem, board, observations, estimate, settings, first, report)
    progress(0.9, "uncertainty at the answer")
    result = _result(problem, solve, outcomes, board, settings, time.perf_counter() - started)
    result.pairs = pair_checks(result, observations)
    for name, transform in result.transforms.items():
        transform.diagnostics["pairs"] = [p for p in result.pairs if name in (p["a"], p["b"])]
    result.set_verdicts(camera_verdicts(result))
    return result


def _result(problem: _Problem, solve: _Solve, outcomes: list[FrameResidual], board: BoardSpec,
            settings: MulticamSettings, seconds: float) -> MulticamResult:
    """The result of the last solve, with its covariance at the answer."""
    T_ref_cam, T_ref_board, cameras = problem.answer()
    # The rig covariance is over [camera poses | free intrinsics]: the step layout without the board poses.
    cov = solve.normal.rig_covariance(solve.residuals.size)
    board_params = 6 * len(problem.frames)
    intrinsics_std, projection_sigma_px = {}, {}
    for name, where in problem.intrinsics_offsets().items():
        rig_where = slice(where.start - board_params, where.stop - board_params)
        cov_intrinsics = cov[rig_where, rig_where]
        std = sigmas(cov_intrinsics)
        intrinsics_std[name] = dict(zip(problem.free[name], finite_or_none(std), strict=True))
        projection_sigma_px[name] = (intrinsics_projection_sigma_px(cameras[name], problem.free[name], cov_intrinsics)
                                     if np.isfinite(cov_intrinsics).all() else float("inf"))
    lengths = np.linalg.norm(solve.residuals, axis=1)
    rms_px = {name: _rms(lengths[where]) for name, where in zip(problem.names, problem.camera_slices, strict=True)}
    final_rms = {(obs.camera, obs.frame): _rms(r) for obs, r in _views(problem, solve.residuals)}
    frames = [replace(o, rms_px=final_rms.get((o.camera, o.frame), o.rms_px)) for o in outcomes]
    warnings = []
    solved = solve.converged and all(v <= settings.max_rms_px for v in rms_px.values())
    worst, worst_rms, others_rms = worst_fitting_camera([f for f in frames if not f.flagged])
    misfit = worst_rms > max(settings.outlier_min_px, settings.frame_outlier_factor * others_rms)
    converged = solved and not misfit
    if misfit:
        warnings.append(f"camera {worst} fits {worst_rms / others_rms:.1f}x worse than the others (median view RMS "
                        f"{worst_rms:.2f} px against {others_rms:.2f} px): check its intrinsics and the board spec")
    if not solved:  # a camera that only fits worse is said above; this is the solve itself failing
        warnings.append("the solve did not converge (" + solve.message + "): RMS "
                        + ", ".join(f"{n} {v:.2f} px" for n, v in rms_px.items())
                        + "; check the board spec and the intrinsics")
    flagged = [f for f in frames if f.flagged]
    if flagged:
        warnings.append(f"{len(flagged)} views left out as outliers: "
                        + ", ".join(f"{f.camera}@{f.frame}" for f in flagged[:8]) + ("..." if len(flagged) > 8 else ""))
    reference = problem.names[0]
    transforms = {}
    for i, name in enumerate(problem.names[1:]):
        views = [f for f in frames if f.camera == name]
        transforms[name] = TransformResult(
            kind="multicam", method="bundle", parent=reference, child=name, T_parent_child=T_ref_cam[name],
            covariance=cov[6 * i:6 * i + 6, 6 * i:6 * i + 6].copy(),
            residuals={"rms_px": rms_px[name], "reference_rms_px": rms_px[reference]},
            diagnostics={"views_used": sum(not f.flagged for f in views),
                         "views_flagged": sum(f.flagged for f in views), "intrinsics_estimated": name in problem.free},
            settings=asdict(settings), converged=converged, warnings=list(warnings), seconds=seconds)
    graph = observation_graph(problem.names, [(o.camera, o.frame) for o in problem.observations])
    return MulticamResult(reference, cameras, transforms, intrinsics_std, projection_sigma_px, rms_px, frames,
                          T_ref_board, graph, _correlation(problem, cov), board, settings, converged, seconds, warnings)
