"""The coarse stage of edge-based LiDAR-camera calibration: grid searches that score edge overlap.

A candidate ``T_camera_lidar`` scores how many projected LiDAR edge points land near an image
edge: ``sum max(0, 1 - d / radius)`` over the points, with ``d`` the distance transform of the
image's edges at the point's pixel (px) and ``radius`` the search step's size in pixels, so the
grid point nearest the optimum (within half a step) still scores. Candidates are scored in
batches: their camera-frame points are stacked and projected by one
:func:`~backend.core.projection.project_cloud` call.

A camera translation and a rotation shift distant points alike, so the errors of ``T_init`` trade
off against each other and the score has long ridges along such combinations: a search over
one kind of parameter at a time stalls on them. The search is therefore:

1. a 3-D grid of rotations about ``T_init`` (rotation errors move the edges most, and far more
   than the few-centimetre translation errors of a measured mounting), whose best *distinct*
   rotations (greedy non-maximum suppression, :func:`distinct_peaks`) are the starts of
2. pattern searches, coarse to fine (:attr:`CoarseSearchSettings.levels`): the 3^6 joint moves of
   one step (or none) in each rotation and translation are scored, the best is taken, and this
   repeats until not moving is best. Translations are *pivoted* (:func:`pivoted_moves`):
   each turns the camera so that the edges' centroid stays put, so that a translation step
   changes only how near and far edges move against each other.

Several starts, because the score can have more than one peak of about the same height: a
repeating pattern in view (a checkerboard, a fence) fits again when shifted by one period, and a
pattern search from one start climbs whichever peak is nearest. The caller refines each distinct
result and compares their fits.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from backend.core.camera import CameraIntrinsics
from backend.core.projection import project_cloud
from backend.core.transforms import params_between

BATCH_POINTS = 1_000_000
"""Candidate points projected per call (memory: about 100 bytes each)."""


@dataclass
class CoarseSearchSettings:
    """Search ranges and steps: rotations in degrees (about the LiDAR's axes), translations in metres (camera axes)."""

    rotation_range_deg: float = 6.0
    rotation_step_deg: float = 1.0
    """The first, rotation-only grid: +-range in steps (deg). It must cover the initial guess's rotation error."""
    levels: tuple[tuple[float, float], ...] = ((1.0, 0.05), (0.5, 0.02), (0.2, 0.01))
    """Pattern-search levels, each ``(rotation step (deg), translation step (m))``."""
    candidates: int = 3
    """Pattern searches run, from the best rotations of the grid that are distinct (:func:`distinct_peaks`); their
    distinct results are returned. 1 for the single best."""
    candidate_separation_deg: float = 2.0
    """A rotation of the grid within this (deg) of a better start on every axis is no other start: it lies on the
    same peak (the score's kernel is one grid step wide)."""
    max_moves: int = 10
    """Moves per pattern-search level at most (each by up to one step per parameter)."""
    max_translation_m: float | None = None
    """Candidates whose translation is further than this from ``T_init``'s on any axis (m) are not considered;
    None for no limit. For scenes whose edges are all far, where translation hardly changes the score."""
    points_per_pair: int = 1500
    """LiDAR edge points per pair scored (a random subset)."""
    min_radius_px: float = 2.0
    """Narrowest scoring kernel (px)."""
    seed: int = 0
    """Seeds the subsets, so a search is repeatable."""


def pivoted_moves(T: np.ndarray, steps: np.ndarray, pivot_camera: np.ndarray) -> np.ndarray:
    """(K, 4, 4) candidates: ``T`` moved by each of (K, 6) ``steps`` (m along the camera's axes, then a rotation
    vector in rad about the LiDAR's axes), each translation pivoted so that ``pivot_camera`` (m, camera frame)
    stays where it is in the image: the camera also turns by the rotation taking ``pivot + t`` to ``pivot``."""
    moved = pivot_camera + steps[:, :3]
    axis = np.cross(moved, pivot_camera)
    norm = np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.arctan2(norm, moved @ pivot_camera[:, None])
    turn = Rotation.from_rotvec(axis / np.maximum(norm, 1e-12) * angle).as_matrix()
    candidates = np.repeat(np.eye(4)[None], len(steps), axis=0)
    candidates[:, :3, :3] = turn @ T[:3, :3] @ Rotation.from_rotvec(steps[:, 3:]).as_matrix()
    candidates[:, :3, 3] = np.einsum("kij,kj->ki", turn, T[:3, 3] + steps[:, :3])
    return candidates


def cube_grid(half: float, step: float, dims: int = 3) -> np.ndarray:
    """(K, dims) offsets of a grid with ``2 * round(half / step) + 1`` values per axis, nearest the centre first."""
    n = int(round(half / step))
    offsets = np.array(list(itertools.product(step * np.arange(-n, n + 1), repeat=dims)))
    return offsets[np.argsort(np.abs(offsets).sum(axis=1), kind="stable")]


def score_candidates(candidates: np.ndarray, samples: list[np.ndarray], distances: list[np.ndarray],
                     camera: CameraIntrinsics, radius_px: float,
                     progress: Callable[[float], None] = lambda fraction: None) -> np.ndarray:
    """(K,) scores of (K, 4, 4) candidate ``T_camera_lidar``: over pairs, the kernel-weighted count of their
    (N_i, 3) LiDAR edge points (m) that land near an edge of the image with distance transform (H, W) (px)."""
    scores = np.zeros(len(candidates))
    batch = max(1, BATCH_POINTS // max(sum(len(s) for s in samples), 1))
    for start in range(0, len(candidates), batch):
        progress(start / len(candidates))
        chunk = candidates[start:start + batch]
        for points, distance in zip(samples, distances, strict=True):
            points_camera = np.matmul(points, chunk[:, :3, :3].transpose(0, 2, 1)) + chunk[:, None, :3, 3]
            projection = project_cloud(points_camera.reshape(-1, 3), np.eye(4), camera)
            cols, rows = np.rint(projection.uv).astype(np.int64).T
            d = distance[np.clip(rows, 0, camera.height - 1), np.clip(cols, 0, camera.width - 1)]
            weight = np.clip(1.0 - d / radius_px, 0.0, None)
            scores[start:start + len(chunk)] += np.bincount(projection.index // len(points), weight, len(chunk))
    return scores


def distinct_peaks(offsets: np.ndarray, scores: np.ndarray, count: int, separation: float) -> np.ndarray:
    """Indices of up to ``count`` of the (K, D) ``offsets``, best ``scores`` first, none within ``separation`` of a
    better chosen one on every axis (greedy non-maximum suppression)."""
    chosen: list[int] = []
    for index in np.argsort(-scores, kind="stable"):
        if all(np.abs(offsets[index] - offsets[c]).max() >= separation - 1e-9 for c in chosen):
            chosen.append(int(index))
            if len(chosen) == count:
                break
    return np.array(chosen)


@dataclass
class _Scorer:
    """Scores candidates on fixed subsets of each pair's LiDAR edge points, keeping to the translation limit."""

    samples: list[np.ndarray]
    """Each pair's (n_i, 3) scored LiDAR edge points (m, LiDAR frame)."""
    distances: list[np.ndarray]
    """Each pair's (H, W) distance transform of its image's edges (px)."""
    camera: CameraIntrinsics
    T_init: np.ndarray
    settings: CoarseSearchSettings

    def radius(self, rotation_step_deg: float) -> float:
        """The kernel's radius (px) for a search step: how far the step moves an edge at the image centre."""
        focal_px = float(np.mean(np.diag(self.camera.K)[:2]))
        return max(self.settings.min_radius_px, focal_px * np.radians(rotation_step_deg))

    def scores(self, candidates: np.ndarray, rotation_step_deg: float, report: Callable[[float], None]
               ) -> np.ndarray:
        """(K,) scores of (K, 4, 4) candidates; -inf beyond the translation limit, except the first (where the
        search is)."""
        scores = score_candidates(candidates, self.samples, self.distances, self.camera,
                                  self.radius(rotation_step_deg), report)
        if self.settings.max_translation_m is not None:
            far = np.abs(candidates[:, :3, 3] - self.T_init[:3, 3]).max(axis=1) > self.settings.max_translation_m
            scores[far & (np.arange(len(candidates)) > 0)] = -np.inf
        return scores

    def pattern_search(self, T: np.ndarray, report: Callable[[float, str], None]) -> tuple[np.ndarray, float]:
        """The pattern searches of all levels from ``T``: where they end and its score at the finest level."""
        stencil = cube_grid(1.0, 1.0, dims=6)
        levels, max_moves = self.settings.levels, self.settings.max_moves
        score = -np.inf
        for level, (rotation_step_deg, translation_step_m) in enumerate(levels):
            steps = stencil * np.repeat([translation_step_m, np.radians(rotation_step_deg)], 3)
            for move in range(max_moves):
                centre = np.mean(np.vstack([p @ T[:3, :3].T + T[:3, 3] for p in self.samples]), axis=0)
                candidates = pivoted_moves(T, steps, centre)
                scores = self.scores(candidates, rotation_step_deg, lambda f, level=level, move=move: report(
                    (level + min(move + f, max_moves) / max_moves) / len(levels),
                    f"level {level + 1} of {len(levels)}, move {move + 1}"))
                chosen = int(np.argmax(scores))
                score = float(scores[chosen])
                if chosen == 0:  # the stencil's first offset is zero: staying is best
                    break
                T = candidates[chosen]
        return T, score


def coarse_search(T_init: np.ndarray, edge_points: list[np.ndarray], distances: list[np.ndarray],
                  camera: CameraIntrinsics, settings: CoarseSearchSettings,
                  progress: Callable[[float, str], None]) -> tuple[np.ndarray, list[str]]:
    """(K, 4, 4) distinct ``T_camera_lidar`` found about ``T_init``, best score first (K <= ``settings.candidates``),
    and warnings (the best rotation on the grid's border).

    ``edge_points`` are each pair's (N_i, 3) LiDAR edge points (m, LiDAR frame) and ``distances`` its image's
    distance transform (px); ``progress`` gets the fraction of the search done and a message. Two results are one
    when they are within a step of the finest level on every parameter.
    """
    rng = np.random.default_rng(settings.seed)
    scorer = _Scorer([p[rng.permutation(len(p))[:settings.points_per_pair]] for p in edge_points], distances,
                     camera, T_init, settings)
    turns = cube_grid(np.radians(settings.rotation_range_deg), np.radians(settings.rotation_step_deg))
    grid = pivoted_moves(T_init, np.hstack([np.zeros_like(turns), turns]), np.zeros(3))
    stages = 1 + settings.candidates
    scores = scorer.scores(grid, settings.rotation_step_deg, lambda f: progress(f / stages, "coarse search: rotation"))
    starts = distinct_peaks(turns, scores, settings.candidates, np.radians(settings.candidate_separation_deg))
    warnings = []
    if np.max(np.abs(turns[starts[0]])) >= np.radians(settings.rotation_range_deg) - 1e-9:
        warnings.append("coarse search: the best rotation is on the border of the search range; the initial guess "
                        "may be further off than it covers")
    found = [scorer.pattern_search(grid[start], lambda f, message, k=k: progress(
        (1 + k + f) / stages, f"coarse search: start {k + 1} of {len(starts)}, {message}"))
             for k, start in enumerate(starts)]
    found.sort(key=lambda t_score: -t_score[1])
    finest_rotation_deg, finest_translation_m = settings.levels[-1]
    step = np.repeat([finest_translation_m, np.radians(finest_rotation_deg)], 3)
    kept: list[np.ndarray] = []
    for T, _ in found:
        if all(np.any(np.abs(params_between(other, T)) > step + 1e-9) for other in kept):
            kept.append(T)
    return np.array(kept), warnings
