"""Square fiducial markers (ArUco and AprilTag families, by OpenCV dictionary name): the dictionary, a marker's
printable image and their detection.

Every marker target (the wall test field, the V-target) names its dictionary as OpenCV does (``DICT_4X4_50``,
``DICT_APRILTAG_36h11``, ...). Corners come in OpenCV's order (top-left, top-right, bottom-right, bottom-left of
the printed marker, in pixels with the top-left pixel's centre at (0, 0)), refined to sub-pixel: AprilTag's own
edge fit for the AprilTag families, OpenCV's corner refinement for ArUco.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError, shorten


def dictionary_named(name: str, spec: str, input_name: str) -> cv2.aruco.Dictionary:
    """OpenCV's predefined marker dictionary ``name``; :class:`InputError` naming ``spec`` if there is none."""
    if not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
        raise InputError(f"unknown marker dictionary {shorten(name)} in {shorten(spec)}; expected an OpenCV name "
                         "such as DICT_4X4_50, DICT_5X5_100 or DICT_APRILTAG_36h11", input_name)
    return cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))


def dictionary_size(name: str) -> int:
    """How many markers the dictionary ``name`` holds."""
    return int(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0])


def marker_image(dictionary: str, marker_id: int, cells_px: int) -> np.ndarray:
    """The marker ``marker_id`` as a uint8 image, its black border included, ``cells_px`` pixels per cell."""
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    cells = d.markerSize + 2
    return d.generateImageMarker(int(marker_id), cells * cells_px)


def marker_cells(dictionary: str, marker_id: int, side: float, top_left: np.ndarray) -> np.ndarray:
    """(N, 4) rectangles ``[x0, y0, x1, y1]`` of the black cells of marker ``marker_id``, its border included,
    upright as OpenCV draws it (:func:`marker_image`), ``side`` a side and its top-left corner at ``top_left`` (any
    one length unit, x to the right and y down)."""
    image = marker_image(dictionary, marker_id, 1)
    cell = side / len(image)
    rows, cols = np.nonzero(image == 0)
    x0, y0 = top_left[0] + cols * cell, top_left[1] + rows * cell
    return np.column_stack([x0, y0, x0 + cell, y0 + cell])


@dataclass(frozen=True)
class MarkerDetections:
    """The markers found in one image."""

    ids: np.ndarray
    """(N,) int marker ids (a marker found twice is listed twice)."""
    corners_px: np.ndarray
    """(N, 4, 2) float64 corners per marker in OpenCV's order (px)."""

    @property
    def centres_px(self) -> np.ndarray:
        """(N, 2) each marker's centre (px): where its diagonals cross, the image of the printed centre under any
        perspective (the mean of the corners is not), though not through a distorting lens (see
        :func:`marker_centres`)."""
        return diagonal_crossings(self.corners_px)


def marker_centres(corners_px: np.ndarray, camera: CameraIntrinsics | None = None) -> np.ndarray:
    """(N, 2) the image of each marker's printed centre (px) from its (N, 4, 2) corners: where the diagonals
    cross, through ``camera``'s lens if given (crossed in undistorted coordinates, mapped back to pixels). A lens
    bends the marker's edges, so the crossing in pixels is off the centre's image: on the simulated Blackfly's
    barrel lens by 0.1 px towards the image centre, enough to put a resected camera a millimetre too far away."""
    if camera is None:
        return diagonal_crossings(corners_px)
    undistorted = camera.undistort_points(corners_px.reshape(-1, 2)).reshape(-1, 4, 2)
    return camera.project_normalised(diagonal_crossings(undistorted))


def diagonal_crossings(corners: np.ndarray) -> np.ndarray:
    """(N, 2) where the diagonals 0-2 and 1-3 of each (4, 2) quadrilateral in ``corners`` (N, 4, 2) cross."""
    p0, p1, p2, p3 = (corners[:, k] for k in range(4))
    d02, d13, d01 = p2 - p0, p3 - p1, p1 - p0
    cross = d02[:, 0] * d13[:, 1] - d02[:, 1] * d13[:, 0]
    s = (d01[:, 0] * d13[:, 1] - d01[:, 1] * d13[:, 0]) / np.where(np.abs(cross) > 1e-12, cross, 1e-12)
    return p0 + s[:, None] * d02


def detect_markers(image: np.ndarray, dictionary: str, *, refine: bool = True,
                   min_distance_rate: float | None = None) -> MarkerDetections:
    """Every marker of ``dictionary`` in ``image`` (grayscale or BGR), corners refined to sub-pixel unless not
    ``refine`` (the caller refines them); ``min_distance_rate`` overrides OpenCV's least distance between markers
    (as a fraction of their perimeter: 0 keeps markers whose corners touch, and may list one twice)."""
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    parameters = cv2.aruco.DetectorParameters()
    parameters.cornerRefinementMethod = (cv2.aruco.CORNER_REFINE_NONE if not refine else
                                         cv2.aruco.CORNER_REFINE_APRILTAG if "APRILTAG" in dictionary
                                         else cv2.aruco.CORNER_REFINE_SUBPIX)
    if min_distance_rate is not None:
        parameters.minMarkerDistanceRate = min_distance_rate
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary)),
                                       parameters)
    corners, ids, _ = detector.detectMarkers(gray)
    if ids is None:
        return MarkerDetections(np.zeros(0, int), np.zeros((0, 4, 2)))
    return MarkerDetections(ids.ravel().astype(int), np.asarray(corners, float).reshape(-1, 4, 2))
