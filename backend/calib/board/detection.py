"""Find a calibration board in an image.

Checkerboards use OpenCV's sector-based detector (``findChessboardCornersSB`` with
``CALIB_CB_ACCURACY | CALIB_CB_EXHAUSTIVE``; its ``CALIB_CB_NORMALIZE_IMAGE`` moves
corners, so it is only a fallback); ChArUco boards use ``CharucoDetector`` so
partial views give usable corners. Corner ``ids`` index the rows of
:attr:`BoardSpec.object_points`.

Full-accuracy checkerboard detections also carry :attr:`Detection.refined_px`: the
same corners refined by ``cornerSubPix`` with windows sized to each corner's own
spacing, one refinement per fraction in :data:`SUBPIX_WINDOW_FRACTIONS`
(:func:`refine_corners`). No OpenCV pipeline wins on every set (a fixed 11x11
window is best on large squares and worst on small ones), and no one fraction
either; the intrinsics solve picks, per set, the corners that fit the model best,
which beat SB and every fixed window on both real OpenCV stereo sets and on
rendered mild and wide lenses (``benchmarks/intrinsics_accuracy.py``).

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

from dataclasses import dataclass, field

import cv2
import numpy as np

from backend.core.boards import BoardSpec
from backend.core.markers import MarkerDetections, detect_markers

MIN_CHARUCO_CORNERS = 6
"""Fewest ChArUco corners for a partial view to be worth keeping (PnP needs >= 4 non-collinear)."""
STRETCH_PERCENTILES = (1.0, 99.0)
"""Percentiles of the image's grey levels that ``normalised`` maps to 0 and 255."""
CLAHE_CLIP_LIMIT = 6.0
"""Contrast limit of ``clahe`` (times the slope of a uniform histogram's mapping). On simulated thermal
checkerboards with 6 grey levels between squares under a 60-level gradient, 3.0 found 8 of 12, 6.0 all 12."""
CLAHE_TILES = (8, 8)
"""Tiles (columns, rows) over which ``clahe`` equalises the image."""

SUBPIX_WINDOW_FRACTIONS = (0.3, 0.4, 0.5)
"""Half-widths of a corner's ``cornerSubPix`` window, as fractions of the distance to its nearest neighbour,
each giving one candidate refinement (the first is the one the neighbour check uses). Measured against rendered
truth (20 views each, corner RMS error px at 0.2 / 0.3 / 0.4 / 0.5 / 0.6): a mild lens with large squares
0.036 / 0.032 / 0.030 / 0.030 / 0.033, a 116-degree lens 0.034 / 0.032 / 0.034 / 0.57 / 1.6; OpenCV's real
640x480 sets fit best at 0.3 (RMS 0.18 px against 0.25-0.32 at 0.4). On every set the best-fitting candidate
was within 5 % of the most accurate, and a window reaching the next corner shows as a fit several times worse."""
SUBPIX_WINDOW_PX = (2, 20)
"""Smallest and largest half-width (px) of the refinement window."""
SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)
NEIGHBOUR_RADIUS = 2
"""Grid steps around a corner whose corners predict it (a homography of up to 24 neighbours)."""
MAX_NEIGHBOUR_DEVIATION = 0.25
"""A corner farther than this fraction of its nearest-neighbour spacing (and :data:`MIN_DEVIATION_PX`) from
where its neighbours put it is dropped: on a rendered wide-lens view at 80 deg of tilt SB placed one corner
10.5 px off (half a square); lens curvature over 5 squares moved good corners by less than 0.05 of a square."""
MIN_DEVIATION_PX = 1.5
SB_FLAGS = cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE
"""Full-accuracy flags of ``findChessboardCornersSB``: the most accurate of OpenCV's own on every set measured."""
LIVE_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE
"""Preview flags: fast, and the corners of preview frames are not kept."""
CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
"""Flags of the classic detector's fallback (:func:`detect_checkerboard_classic`)."""
CROP_MARGIN_SQUARES = 1.5
"""The full-accuracy search runs on the board's neighbourhood: its inner corners' bounding box grown by this many
of its widest corner spacings (the outer squares and a quiet zone), as a fast search (:data:`LIVE_FLAGS`) finds
them. Measured on the demo's 1280x720 renders: 2.2 times faster on boards waved close (48 views), 3.2 times on a
board 2-3 m away in the yard (10 views); the refined corners (:func:`refine_corners`, window 0.3) agree with the
whole image's within 0.02 px (median 0.0003), and the detector's own corners lie 0.090 px (RMS) from the truth
against 0.098 px. OpenCV searches the whole image at every scale, which is most of its time."""
CROP_MAX_SHARE = 0.5
"""A neighbourhood larger than this share of the image is not worth cropping: the whole image is searched (the
board fills OpenCV's 640x480 stereo views, and their corners stay exactly as before)."""

FALLBACKS: dict[tuple[str, bool], tuple[str, ...]] = {
    ("checkerboard", False): ("sb-normalised", "normalised+clahe"),
    ("checkerboard", True): ("normalised+clahe",),
    ("charuco", False): ("normalised", "normalised+inverted", "normalised+clahe", "normalised+clahe+inverted"),
    ("charuco", True): ("normalised", "normalised+inverted"),
    ("aprilgrid", False): ("normalised", "normalised+clahe"),
    ("aprilgrid", True): ("normalised",),
}
"""Treatments tried, in order, per (board kind, live) when the plain image gives no board.

A name is its steps joined by ``+``, applied left to right; every treatment but
``sb-normalised`` starts with ``normalised``, which also turns images of any depth
into 8 bits. ``sb-normalised`` is the plain image with the detector's own
``CALIB_CB_NORMALIZE_IMAGE`` added (it found a 13th board on OpenCV's left stereo
set that the plain flags missed). The checkerboard detector finds either polarity
with the same corner numbering up to its usual half turn; on simulated thermal
boards (of every parity) a global stretch or an inversion found no board that
``normalised+clahe`` missed, so checkerboards try only these: each failed attempt
costs a whole detector run (about 0.8 s on a 1280x720 frame without a board, 0.2 s
live).
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
    refined: dict[str, np.ndarray] = field(default_factory=dict)
    """The same corners after :func:`refine_corners`, (N, 2) px per window fraction named as in
    :func:`refinement_name` (full-accuracy checkerboards only; empty otherwise)."""
    marker_corners_px: np.ndarray | None = None
    """A test field's: (N, 4, 2) the corners of the marker behind each point (px), from which its centre is
    computed again once the lens is known (:func:`~backend.core.markers.marker_centres`); None for a board."""

    def object_points(self, board: BoardSpec) -> np.ndarray:
        """(N, 3) float32 board-frame positions (m) of the detected corners."""
        return board.object_points[self.ids]

    def to_dict(self) -> dict:
        data = {"corners_px": self.corners_px.tolist(), "ids": self.ids.tolist(), "image_size": list(self.image_size),
                "preprocessing": self.preprocessing}
        if self.refined:
            data["refined"] = {name: corners.tolist() for name, corners in self.refined.items()}
        if self.marker_corners_px is not None:
            data["marker_corners_px"] = self.marker_corners_px.tolist()
        return data

    @classmethod
    def from_dict(cls, data: dict) -> Detection:
        """Inverse of :meth:`to_dict`. Dicts stored before ``preprocessing`` existed read as ``none``; before
        several refinements, the one ``refined_px`` was the first fraction's."""
        refined = data.get("refined")
        if refined is None:
            legacy = data.get("refined_px")
            refined = {} if legacy is None else {refinement_name(SUBPIX_WINDOW_FRACTIONS[0]): legacy}
        markers = data.get("marker_corners_px")
        return cls(np.asarray(data["corners_px"], float).reshape(-1, 2), np.asarray(data["ids"], int),
                   tuple(data["image_size"]), data.get("preprocessing", "none"),
                   {name: np.asarray(corners, float).reshape(-1, 2) for name, corners in refined.items()},
                   None if markers is None else np.asarray(markers, float).reshape(-1, 4, 2))


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
    attempts = (("none",) if gray.dtype == np.uint8 else ()) + tuple(
        name for name in FALLBACKS[(board.kind, live)] if gray.dtype == np.uint8 or name != "sb-normalised")
    treated: dict[str, np.ndarray] = {"none": gray}
    for name in attempts:
        sb_normalise = name == "sb-normalised"
        image = treated["none"] if sb_normalise else _treat(treated, name)
        found = _find_corners(image, board, live, sb_normalise)
        if found is not None:
            if live or board.kind != "checkerboard":
                return Detection(*found, size, name)
            return _refined(gray, board, *found, name)
    return None


def detect_checkerboard_classic(gray: np.ndarray, board: BoardSpec) -> Detection | None:
    """A checkerboard found by OpenCV's classic detector (``findChessboardCorners``, adaptive threshold) in the
    uint8 ``gray``, refined as :func:`detect_board`'s; ``None`` if it is not seen. For images the sector-based
    detector handles badly: a swept scanner's intensity image, blocky along its rows and curved by the sweep, where
    it found each board of the servo-scanner rig at some row stretches and not at others, and this one found all but
    one at every stretch (:mod:`backend.calib.lidar_camera.sweep_corners`)."""
    found, corners = cv2.findChessboardCorners(gray, board.corner_grid, flags=CLASSIC_FLAGS)
    if not found:
        return None
    return _refined(gray, board, corners.reshape(-1, 2).astype(np.float64), np.arange(board.n_corners), "classic")


def _refined(gray: np.ndarray, board: BoardSpec, corners: np.ndarray, ids: np.ndarray, name: str) -> Detection:
    """The full-accuracy detection of a whole checkerboard's ``corners`` (px, id order) found in ``gray`` after the
    treatment ``name``: refined at each of :data:`SUBPIX_WINDOW_FRACTIONS`, the corners its neighbours disagree with
    dropped."""
    # Refined in the untreated image: after CLAHE a rendered wide-lens view's refined corners lay 0.088 px
    # (RMS) from the truth, in the plain image 0.032 px; cornerSubPix weighs gradients, so linear
    # contrast (a 16-bit image as float) makes no difference to it.
    untreated = gray if gray.dtype == np.uint8 else gray.astype(np.float32)
    refined = {refinement_name(fraction): refine_corners(untreated, board, corners, fraction)
               for fraction in SUBPIX_WINDOW_FRACTIONS}
    keep = _agrees_with_neighbours(board, refined[refinement_name(SUBPIX_WINDOW_FRACTIONS[0])])
    return Detection(corners[keep], ids[keep], (gray.shape[1], gray.shape[0]), name,
                     {window: refined_px[keep] for window, refined_px in refined.items()})


def _nearest_spacing(board: BoardSpec, corners_px: np.ndarray) -> np.ndarray:
    """(N,) distance (px) from each corner of a full checkerboard grid (id order) to its nearest grid neighbour."""
    cols, rows = board.corner_grid
    grid = corners_px.reshape(rows, cols, 2)
    along_rows = np.linalg.norm(np.diff(grid, axis=1), axis=2)
    along_cols = np.linalg.norm(np.diff(grid, axis=0), axis=2)
    nearest = np.full((rows, cols), np.inf)
    for spacing, before, after in ((along_rows, np.s_[:, :-1], np.s_[:, 1:]), (along_cols, np.s_[:-1], np.s_[1:])):
        nearest[before] = np.minimum(nearest[before], spacing)
        nearest[after] = np.minimum(nearest[after], spacing)
    return nearest.ravel()


def _agrees_with_neighbours(board: BoardSpec, corners_px: np.ndarray) -> np.ndarray:
    """(N,) bool: each corner lies where a RANSAC homography of its grid neighbours puts it.

    OpenCV has no such check on a found grid; a corner the detector misplaced (by a fraction of a square,
    which the calibration would take as lens distortion) is caught here, and its own misplacement is kept out
    of the neighbours' fits by RANSAC.
    """
    cols, rows = board.corner_grid
    col, row = np.arange(cols * rows) % cols, np.arange(cols * rows) // cols
    limit = np.maximum(MAX_NEIGHBOUR_DEVIATION * _nearest_spacing(board, corners_px), MIN_DEVIATION_PX)
    keep = np.ones(len(corners_px), bool)
    grid_xy = np.column_stack([col, row]).astype(np.float64)
    for i in range(len(corners_px)):
        near = (np.abs(col - col[i]) <= NEIGHBOUR_RADIUS) & (np.abs(row - row[i]) <= NEIGHBOUR_RADIUS)
        near[i] = False
        H, _ = cv2.findHomography(grid_xy[near], corners_px[near], cv2.RANSAC, MIN_DEVIATION_PX)
        if H is not None:
            predicted = cv2.perspectiveTransform(grid_xy[i].reshape(1, 1, 2), H).ravel()
            keep[i] = np.linalg.norm(predicted - corners_px[i]) <= limit[i]
    return keep


def refinement_name(fraction: float) -> str:
    """The name of the refinement with half-windows of ``fraction`` of the corner spacing: ``refined-0.3``."""
    return f"refined-{fraction:g}"


def refine_corners(gray: np.ndarray, board: BoardSpec, corners_px: np.ndarray, fraction: float) -> np.ndarray:
    """(N, 2) checkerboard corners (all of ``board``'s, in id order) refined by ``cornerSubPix`` in ``gray``.

    Each corner's half-window is ``fraction`` of the distance (px) to its nearest grid neighbour, so a wide
    lens's compressed edge corners get smaller windows than its centre's. OpenCV takes one window per call, so
    corners are refined in groups of equal window.
    """
    window = np.clip(np.floor(fraction * _nearest_spacing(board, corners_px)),
                     *SUBPIX_WINDOW_PX).astype(int)
    refined = corners_px.astype(np.float32)
    for half in np.unique(window):
        group = window == half
        refined[group] = cv2.cornerSubPix(gray, refined[group].reshape(-1, 1, 2).copy(), (int(half), int(half)),
                                          (-1, -1), SUBPIX_CRITERIA).reshape(-1, 2)
    return refined.astype(np.float64)


def _find_corners(gray: np.ndarray, board: BoardSpec, live: bool,
                  sb_normalise: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """Corners (N, 2) float64 px and ids (N,) int of ``board`` in the uint8 ``gray``, or None.

    ``sb_normalise`` adds ``CALIB_CB_NORMALIZE_IMAGE`` to the full-accuracy checkerboard flags.
    """
    if board.kind == "checkerboard":
        if live:
            return _checkerboard_corners(gray, board, LIVE_FLAGS)
        flags = SB_FLAGS | (cv2.CALIB_CB_NORMALIZE_IMAGE if sb_normalise else 0)
        window = _board_window(gray, board)
        if window is not None:
            found = _checkerboard_corners(gray[window], board, flags)
            if found is not None:
                return found[0] + [window[1].start, window[0].start], found[1]
        return _checkerboard_corners(gray, board, flags)
    if board.kind == "aprilgrid":
        return _aprilgrid_corners(gray, board)
    detector = cv2.aruco.CharucoDetector(board.charuco_board())
    corners, ids, _, _ = detector.detectBoard(gray)
    if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
        return None
    return corners.reshape(-1, 2).astype(np.float64), ids.ravel().astype(int)


def _aprilgrid_corners(gray: np.ndarray, board: BoardSpec) -> tuple[np.ndarray, np.ndarray] | None:
    """An AprilGrid's tag corners (N, 2) float64 px and ids (N,) in ``gray``, or None below
    :data:`MIN_CHARUCO_CORNERS`.

    OpenCV's marker detector is not made for Kalibr's grid: the black squares in the gaps touch each tag's corners,
    so a tag's outline is not a clean quadrilateral and, on three rendered 752x480 views, it found 17, 36 and 14 of
    the 36 tags. The image with its dark parts thinned (a 2x2 dilation of the bright: touching corners come apart)
    is searched too (first), and each tag found in either is kept once: 29, 35 and 29. The same touching squares make
    each tag corner a checkerboard-like X, which ``cornerSubPix`` then refines in the untouched image, with a
    half-window of a third of the gap: 0.07-0.10 px from the truth (median, at most 0.23 px), against 0.66-0.71 px
    for the detector's own AprilTag refinement. A corner the refinement carried further than its window (to another
    junction) is left out.
    """
    thinned = cv2.dilate(gray, np.ones((2, 2), np.uint8))
    plain, thin = (detect_markers(image, board.dictionary, refine=False, min_distance_rate=0.0)
                   for image in (gray, thinned))
    found = MarkerDetections(np.concatenate([thin.ids, plain.ids]),
                             np.concatenate([thin.corners_px, plain.corners_px]))
    _, first = np.unique(found.ids, return_index=True)
    keep = first[found.ids[first] < board.cols * board.rows]
    if 4 * len(keep) < MIN_CHARUCO_CORNERS:
        return None
    quads = found.corners_px[keep]
    side_px = np.linalg.norm(quads - np.roll(quads, 1, axis=1), axis=2).mean(axis=1)
    half = np.clip(np.rint(board.spacing * side_px / 3), *SUBPIX_WINDOW_PX).astype(int)
    corners = quads.copy()
    for window in np.unique(half):
        group = half == window
        corners[group] = cv2.cornerSubPix(gray, quads[group].reshape(-1, 1, 2).astype(np.float32),
                                          (int(window), int(window)), (-1, -1), SUBPIX_CRITERIA).reshape(-1, 4, 2)
    moved = np.linalg.norm(corners - quads, axis=2) > np.maximum(half, 2)[:, None]  # drawn to another junction
    corner_ids = board.aprilgrid_corner_ids(found.ids[keep])[~moved]
    corners_px = corners[~moved].astype(np.float64)
    agree = _agrees_with_nearby_corners(board, corner_ids, corners_px, max(1.0, 0.1 * float(np.median(side_px))))
    corner_ids, corners_px = corner_ids[agree], corners_px[agree]
    if len(corner_ids) < MIN_CHARUCO_CORNERS:
        return None
    order = np.argsort(corner_ids)
    return corners_px[order], corner_ids[order]


def _agrees_with_nearby_corners(board: BoardSpec, ids: np.ndarray, corners_px: np.ndarray, limit_px: float
                                ) -> np.ndarray:
    """(N,) bool: each corner lies within ``limit_px`` of where a RANSAC homography of the corners found within two
    tags of it puts it (kept when fewer than six are near). A tag corner the detector placed on a neighbouring
    junction, or on a tag cut by the image's edge, is caught here (4.4 px off on a rendered view)."""
    plane = board.object_points[ids, :2].astype(np.float64)
    reach = 2.5 * (board.square_m + board.gap_m)
    keep = np.ones(len(ids), bool)
    for i in range(len(ids)):
        near = np.linalg.norm(plane - plane[i], axis=1) <= reach
        near[i] = False
        if near.sum() < 6:
            continue
        H, _ = cv2.findHomography(plane[near], corners_px[near], cv2.RANSAC, limit_px)
        if H is not None:
            predicted = cv2.perspectiveTransform(plane[i].reshape(1, 1, 2), H).ravel()
            keep[i] = np.linalg.norm(predicted - corners_px[i]) <= limit_px
    return keep


def _checkerboard_corners(gray: np.ndarray, board: BoardSpec, flags: int) -> tuple[np.ndarray, np.ndarray] | None:
    """``findChessboardCornersSB`` with ``flags``: corners (N, 2) float64 px and ids (N,), or None."""
    found, corners = cv2.findChessboardCornersSB(gray, board.corner_grid, flags=flags)
    if not found:
        return None
    return corners.reshape(-1, 2).astype(np.float64), np.arange(board.n_corners)


def _board_window(gray: np.ndarray, board: BoardSpec) -> tuple[slice, slice] | None:
    """(rows, columns) of ``gray`` about the checkerboard a fast search finds (:data:`CROP_MARGIN_SQUARES`), or None
    when it finds none or the window would be more than :data:`CROP_MAX_SHARE` of the image."""
    found = _checkerboard_corners(gray, board, LIVE_FLAGS)
    if found is None:
        return None
    corners_px = found[0]
    reach_px = CROP_MARGIN_SQUARES * _nearest_spacing(board, corners_px).max()
    x0, y0 = np.maximum(np.floor(corners_px.min(axis=0) - reach_px), 0).astype(int)
    x1, y1 = np.ceil(corners_px.max(axis=0) + reach_px).astype(int)
    height, width = gray.shape[:2]
    x1, y1 = min(x1, width), min(y1, height)
    if (x1 - x0) * (y1 - y0) > CROP_MAX_SHARE * width * height:
        return None
    return slice(y0, y1), slice(x0, x1)


def _treat(treated: dict[str, np.ndarray], name: str) -> np.ndarray:
    """The image after treatment ``name`` (steps joined by ``+``), memoised in ``treated`` (which holds ``none``)."""
    if name not in treated:
        head, _, step = name.rpartition("+")
        treated[name] = _STEPS[step](_treat(treated, head or "none"))
    return treated[name]


def normalised(gray: np.ndarray) -> np.ndarray:
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


_STEPS = {"normalised": normalised, "inverted": _inverted, "clahe": _clahe}
"""The single steps a treatment name is made of."""
