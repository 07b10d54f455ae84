"""Fast board detection for live preview frames: quick searches (a shrunk frame's too), refined at full resolution.

The accurate detector (:func:`backend.calib.board.detection.detect_board`) runs OpenCV's
sector-based search with ``CALIB_CB_ACCURACY | CALIB_CB_EXHAUSTIVE`` on the full frame: 0.4 to
0.8 s for a 1280x720 frame. A preview frame only needs the board's corners where the refinement
would put them, so here two quick searches find them roughly and the accurate detector's own
per-corner ``cornerSubPix`` (:func:`~backend.calib.board.detection.refine_corners`, its first
window fraction, in the untreated full frame) refines them, so both end up at the same corners:

1. OpenCV's classic ``findChessboardCorners`` on the full frame with its quick check
   (:data:`FULL_RESOLUTION_FLAGS`): a few milliseconds when it finds the board, and it gives up
   as quickly on a frame without one;
2. if that finds nothing, the sector-based search (:data:`SEARCH_FLAGS`) in the frame shrunk
   (``INTER_AREA``) until its longer side is at most :data:`SEARCH_SIDE_PX`, which finds the
   boards the classic detector misses (blur, steep tilt) in about a fifth of the full frame's
   time; its corners are scaled back to the full frame (pixel centres:
   ``u_full = (u_small + 0.5) / s - 0.5``).

Boards with squares under about 10 px (5 px shrunk) are found by the first search only, so less
often than by the accurate detector, which a capture uses. When the plain frame shows no board, the
live contrast treatments of :data:`~backend.calib.board.detection.FALLBACKS` are tried with the
second search only (the classic one is slow on a treated, noisy frame), by :class:`LiveDetector`,
which follows one camera's frames, on every :data:`FALLBACK_EVERY`-th frame without a board.

ChArUco boards go to the accurate detector's live mode: marker detection is already fast.
``benchmarks/live_detection.py`` measures the frame rate.
"""

from __future__ import annotations

import cv2
import numpy as np

from backend.calib.board.detection import (
    FALLBACKS,
    SUBPIX_WINDOW_FRACTIONS,
    Detection,
    _treat,
    detect_board,
    refine_corners,
    to_gray,
)
from backend.core.boards import BoardSpec

SEARCH_SIDE_PX = 640
"""Longest side (px) of the shrunk frame of the second search (a 1280x720 frame is searched at 640x360). On
simulated 720p frames it took about a fifth of the full frame's time and found every board whose squares
spanned at least 10.7 px in the full frame (5.4 px searched), and none of 9.2 px."""
SEARCH_FLAGS = 0
"""Flags of the second search, ``findChessboardCornersSB`` in the shrunk frame. ``CALIB_CB_NORMALIZE_IMAGE``
found the same boards on the simulated and real sets but took 3x as long on frames without a board."""
FULL_RESOLUTION_FLAGS = cv2.CALIB_CB_FAST_CHECK | cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
"""Flags of the first search, ``findChessboardCorners`` on the full frame (its defaults and the quick check)."""
FALLBACK_EVERY = 4
"""A :class:`LiveDetector` tries the contrast treatments on every 4th frame without a board only: on the
simulated textured background the treated search cost about 3.5x the plain one, and a camera whose board needs
a treatment learns so from the treatment that found it, which it then tries first."""


def detect_board_live(image: np.ndarray, board: BoardSpec, *, search_side_px: int = SEARCH_SIDE_PX
                      ) -> Detection | None:
    """Detect ``board`` in one preview frame (gray or BGR, uint8 or uint16); ``None`` if it is not seen.

    Checkerboard corners are in full-frame pixels (OpenCV convention), refined at full resolution, numbered
    from the end the accurate detector numbers from (boards of odd ``cols + rows``; see
    :func:`_numbered_like_sb`); the detection's :attr:`~Detection.preprocessing` names the treatment the
    board was found after. Every treatment is tried; :class:`LiveDetector` does the same over a stream of
    frames for less.
    ``search_side_px`` is the longest side (px) of the shrunk frame of the second search.
    """
    return LiveDetector(board, search_side_px=search_side_px, fallback_every=1).detect(image)


class LiveDetector:
    """:func:`detect_board_live` over one camera's stream of preview frames.

    The treatment that last found the board is tried first, and the other treatments only on every
    :data:`FALLBACK_EVERY`-th frame without a board (a board that needs one is found within that many frames).
    """

    def __init__(self, board: BoardSpec, *, search_side_px: int = SEARCH_SIDE_PX,
                 fallback_every: int = FALLBACK_EVERY):
        self.board = board
        self.search_side_px = search_side_px
        self.fallback_every = fallback_every
        self._last = "none"
        self._misses = 0

    def detect(self, image: np.ndarray) -> Detection | None:
        """The board in ``image`` (as :func:`detect_board_live`), or None."""
        if self.board.kind != "checkerboard":
            return detect_board(image, self.board, live=True)
        gray = to_gray(image)
        possible = _treatments(gray)
        first = self._last if self._last in possible else possible[0]
        names = (first,)
        if (self._misses + 1) % self.fallback_every == 0:
            names += tuple(name for name in possible if name != first)
        detection = _detect_checkerboard(gray, self.board, names, self.search_side_px)
        if detection is None:
            self._misses += 1
        else:
            self._last, self._misses = detection.preprocessing, 0
        return detection


def _treatments(gray: np.ndarray) -> tuple[str, ...]:
    """The treatments a preview frame of this depth is searched after, in order (``none`` only for 8 bits)."""
    return (("none",) if gray.dtype == np.uint8 else ()) + FALLBACKS[("checkerboard", True)]


def _numbered_like_sb(gray: np.ndarray, board: BoardSpec, corners_px: np.ndarray) -> np.ndarray:
    """The classic detector's (N, 2) corners (px, in its id order) numbered from the end the sector-based
    detector, and so the accurate one, numbers from.

    The two number a board from opposite ends: on 29 of 29 simulated and real frames the sector-based
    detector's first square (between corners 0, 1, ``cols`` and ``cols + 1``) was the brighter of it and
    its neighbour along the row, the classic detector's the darker. The numbering matters beyond the ids:
    the coverage's skew is measured at a numbered corner. Boards whose half turn keeps the first square's
    colour (``cols + rows`` even), or with fewer than 3 columns, are left as found.
    """
    cols, rows = board.corner_grid
    if (cols + rows) % 2 == 0 or cols < 3:
        return corners_px
    first = corners_px[[0, 1, cols, cols + 1]].mean(axis=0)
    beside = corners_px[[1, 2, cols + 1, cols + 2]].mean(axis=0)
    first_level, beside_level = (float(cv2.getRectSubPix(gray, (3, 3), (float(u), float(v))).mean())
                                 for u, v in (first, beside))
    return corners_px[::-1].copy() if first_level < beside_level else corners_px


def _detect_checkerboard(gray: np.ndarray, board: BoardSpec, names: tuple[str, ...], search_side_px: int
                         ) -> Detection | None:
    """The checkerboard in ``gray`` found after the first of the treatments ``names`` that finds it, or None."""
    height, width = gray.shape
    scale = min(1.0, search_side_px / max(width, height))
    small_size = (max(1, round(width * scale)), max(1, round(height * scale)))
    shrunk = {"none": gray if scale == 1.0 else cv2.resize(gray, small_size, interpolation=cv2.INTER_AREA)}
    for name in names:
        found, corners = False, None
        if name == "none":
            found, corners = cv2.findChessboardCorners(gray, board.corner_grid, flags=FULL_RESOLUTION_FLAGS)
            corners = _numbered_like_sb(gray, board, corners.reshape(-1, 2).astype(np.float64)) if found else None
        if not found:
            found, corners = cv2.findChessboardCornersSB(_treat(shrunk, name), board.corner_grid,
                                                         flags=SEARCH_FLAGS)
            if found:  # back to full-frame pixels, per axis, since the shrunk size is rounded to whole pixels
                corners = (corners.reshape(-1, 2).astype(np.float64) + 0.5) * (
                    np.array([width, height]) / np.array(small_size)) - 0.5
        if found:
            # In the untreated frame, with the accurate detector's first window, as it refines its corners.
            untreated = gray if gray.dtype == np.uint8 else gray.astype(np.float32)
            refined = refine_corners(untreated, board, corners, SUBPIX_WINDOW_FRACTIONS[0])
            return Detection(refined, np.arange(board.n_corners), (width, height), name)
    return None
