"""Find a calibration board in an image.

Checkerboards use OpenCV's sector-based detector (``findChessboardCornersSB``),
which is sub-pixel accurate on its own; ChArUco boards use ``CharucoDetector`` so
partial views give usable corners. Corner ``ids`` index the rows of
:attr:`BoardSpec.object_points`.

Thermal cameras show a heated or cooled board with weak, often inverted contrast,
and may deliver 16-bit raw counts. When the plain 8-bit image gives no board (or
the image is not 8-bit), a short fixed list of contrast treatments is tried, and
the first that finds the board is named in :attr:`Detection.preprocessing`:
a robust percentile stretch (``normalised``), inversion (``inverted``, which ArUco
markers need; the checkerboard detector finds either polarity by itself) and
contrast-limited local equalisation (``clahe``, against temperature gradients).
The treatments change grey levels only, so the corners stay in the image's own
pixel coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from backend.core.boards import BoardSpec

MIN_CHARUCO_CORNERS = 6
"""Fewest ChArUco corners for a partial view to be worth keeping (PnP needs >= 4 non-collinear)."""
STRETCH_PERCENTILES = (1.0, 99.0)
"""Percentiles of the image's grey levels that ``normalised`` maps to 0 and 255."""
CLAHE_CLIP_LIMIT = 6.0
"""Contrast limit of ``clahe`` (times the slope of a uniform histogram's mapping). On simulated thermal
checkerboards with 6 grey levels between squares under a 60-level gradient, 3.0 found 8 of 12, 6.0 all 12."""
CLAHE_TILES = (8, 8)
"""Tiles (columns, rows) over which ``clahe`` equalises the image."""

FALLBACKS: dict[tuple[str, bool], tuple[str, ...]] = {
    ("checkerboard", False): ("normalised+clahe",),
    ("checkerboard", True): ("normalised+clahe",),
    ("charuco", False): ("normalised", "normalised+inverted", "normalised+clahe", "normalised+clahe+inverted"),
    ("charuco", True): ("normalised", "normalised+inverted"),
}
"""Treatments tried, in order, per (board kind, live) when the plain image gives no board.

A name is its steps joined by ``+``, applied left to right; every treatment starts
with ``normalised``, which also turns images of any depth into 8 bits. The
checkerboard detector normalises the image itself (``CALIB_CB_NORMALIZE_IMAGE``)
and finds either polarity with the same corner numbering up to its usual half
turn; on simulated thermal boards (of every parity) a global stretch or an
inversion found no board that ``normalised+clahe`` missed, so checkerboards try
only that: each failed attempt costs a whole detector run (about 0.8 s on a
1280x720 frame without a board, 0.2 s live).
"""


@dataclass
class Detection:
    """Board corners found in one image."""

    corners_px: np.ndarray
    """(N, 2) float64 corner positions in pixels (OpenCV convention)."""
    ids: np.ndarray
    """(N,) int corner ids, rows of ``board.object_points``."""
    image_size: tuple[int, int]
    """(width, height) of the image the corners were found in (px)."""
    preprocessing: str = "none"
    """Contrast treatment the board was found after: ``none`` or a name from :data:`FALLBACKS`."""

    def object_points(self, board: BoardSpec) -> np.ndarray:
        """(N, 3) float32 board-frame positions (m) of the detected corners."""
        return board.object_points[self.ids]

    def to_dict(self) -> dict:
        return {"corners_px": self.corners_px.tolist(), "ids": self.ids.tolist(), "image_size": list(self.image_size),
                "preprocessing": self.preprocessing}

    @classmethod
    def from_dict(cls, data: dict) -> Detection:
        """Inverse of :meth:`to_dict`; dicts stored before ``preprocessing`` existed read as ``none``."""
        return cls(np.asarray(data["corners_px"], float).reshape(-1, 2), np.asarray(data["ids"], int),
                   tuple(data["image_size"]), data.get("preprocessing", "none"))


def common_corners(a: Detection, b: Detection) -> tuple[np.ndarray, np.ndarray]:
    """The corners (px) both detections found, as two (N, 2) arrays in corner-id order (for a stereo pair)."""
    _, in_a, in_b = np.intersect1d(a.ids, b.ids, return_indices=True)
    return a.corners_px[in_a], b.corners_px[in_b]


def to_gray(image: np.ndarray) -> np.ndarray:
    """Single-channel view of a gray or BGR image, keeping its depth."""
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)


def detect_board(image: np.ndarray, board: BoardSpec, *, live: bool = False) -> Detection | None:
    """Detect ``board`` in ``image`` (gray or BGR, uint8 or uint16); ``None`` if it is not seen.

    An 8-bit image is searched as it is first; only if that finds nothing (or the
    image is not 8-bit) are the :data:`FALLBACKS` tried, fewer of them for
    ``live``. ``live=True`` also trades a little accuracy for speed, for preview
    frames; captures are always re-detected at full accuracy.
    """
    gray = to_gray(image)
    size = (gray.shape[1], gray.shape[0])
    attempts = (("none",) if gray.dtype == np.uint8 else ()) + FALLBACKS[(board.kind, live)]
    treated: dict[str, np.ndarray] = {"none": gray}
    for name in attempts:
        found = _find_corners(_treat(treated, name), board, live)
        if found is not None:
            return Detection(*found, size, name)
    return None


def _find_corners(gray: np.ndarray, board: BoardSpec, live: bool) -> tuple[np.ndarray, np.ndarray] | None:
    """Corners (N, 2) float64 px and ids (N,) int of ``board`` in the uint8 ``gray``, or None."""
    if board.kind == "checkerboard":
        flags = cv2.CALIB_CB_NORMALIZE_IMAGE | (0 if live else cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
        found, corners = cv2.findChessboardCornersSB(gray, board.corner_grid, flags=flags)
        if not found:
            return None
        return corners.reshape(-1, 2).astype(np.float64), np.arange(board.n_corners)
    detector = cv2.aruco.CharucoDetector(board.charuco_board())
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
        return None
    return corners.reshape(-1, 2).astype(np.float64), ids.ravel().astype(int)


def _treat(treated: dict[str, np.ndarray], name: str) -> np.ndarray:
    """The image after treatment ``name`` (steps joined by ``+``), memoised in ``treated`` (which holds ``none``)."""
    if name not in treated:
        head, _, step = name.rpartition("+")
        treated[name] = _STEPS[step](_treat(treated, head or "none"))
    return treated[name]


def _normalised(gray: np.ndarray) -> np.ndarray:
    """uint8 image with the :data:`STRETCH_PERCENTILES` of ``gray`` (any depth) stretched to 0..255."""
    low, high = np.percentile(gray, STRETCH_PERCENTILES)
    if high <= low:
        return np.zeros(gray.shape, np.uint8)
    stretched = (gray.astype(np.float32) - np.float32(low)) * np.float32(255.0 / (high - low))
    return np.clip(np.rint(stretched), 0, 255).astype(np.uint8)


def _inverted(gray: np.ndarray) -> np.ndarray:
    """The uint8 ``gray`` with dark and bright swapped (a heated black print looks bright in a white-hot palette)."""
    return cv2.bitwise_not(gray)


def _clahe(gray: np.ndarray) -> np.ndarray:
    """The uint8 ``gray`` equalised tile by tile (contrast-limited), evening out temperature gradients."""
    return cv2.createCLAHE(CLAHE_CLIP_LIMIT, CLAHE_TILES).apply(gray)


_STEPS = {"normalised": _normalised, "inverted": _inverted, "clahe": _clahe}
"""The single steps a treatment name is made of."""


def draw_detection(image: np.ndarray, board: BoardSpec, detection: Detection | None) -> np.ndarray:
    """BGR uint8 copy of ``image`` with the detected corners drawn (or a red 'no board' banner).

    Images deeper than 8 bits (thermal raw counts) are shown ``normalised``.
    """
    if image.dtype != np.uint8:
        image = _normalised(to_gray(image))
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    if detection is None:
        cv2.putText(canvas, "board not found", (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.2, (0, 0, 255), 3)
        return canvas
    if board.kind == "checkerboard":
        cv2.drawChessboardCorners(canvas, board.corner_grid, detection.corners_px.astype(np.float32).reshape(-1, 1, 2),
                                  True)
    else:
        cv2.aruco.drawDetectedCornersCharuco(canvas, detection.corners_px.astype(np.float32).reshape(-1, 1, 2),
                                             detection.ids.reshape(-1, 1))
    return canvas
