"""A test field's markers in one image, matched to the survey: one image point per surveyed marker seen; and any
camera target (a board or a test field) found in an image by the one call (:func:`detect_target`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from backend.calib.board.detection import Detection, detect_board
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.markers import detect_markers, marker_centres
from backend.core.targets import CameraTarget
from backend.core.test_field import TestField

MIN_MARKERS = 6
"""Fewer surveyed markers than this in an image do not make a view: a pose alone takes three, with no redundancy."""


@dataclass
class FieldDetection:
    """The surveyed markers found in one image, and what was left out and why."""

    detection: Detection | None
    """Marker centres (px) with ``ids`` indexing the survey's rows (:attr:`TestField.object_points`); None when
    fewer than :data:`MIN_MARKERS` surveyed markers are seen."""
    notes: list[str] = field(default_factory=list)
    """One line per marker left out: ids the survey does not hold, ids seen twice."""
    reason: str = ""
    """Why there is no detection (too few surveyed markers); empty when there is one."""


def _ids_text(ids: np.ndarray) -> str:
    shown = ", ".join(str(i) for i in ids[:8])
    return shown + (f" and {len(ids) - 8} more" if len(ids) > 8 else "")


def detect_test_field(image: np.ndarray, test_field: TestField, name: str,
                      camera: CameraIntrinsics | None = None) -> FieldDetection:
    """The surveyed markers of ``test_field`` in ``image`` (grayscale or BGR) called ``name``, their centres
    through ``camera``'s lens when it is known (:func:`~backend.core.markers.marker_centres`).

    A marker whose id the survey does not hold is left out, and so is an id seen more than once (a test field
    holds each id once, so one of the two is not the surveyed marker); each is named in the notes.
    """
    found = detect_markers(image, test_field.dictionary)
    ids, counts = np.unique(found.ids, return_counts=True)
    notes = []
    twice = ids[counts > 1]
    if len(twice):
        notes.append(f"{name}: marker id(s) {_ids_text(twice)} seen more than once; left out (each id is on the "
                     "wall once, so all but one are other markers)")
    rows = test_field.rows_of(found.ids)
    unknown = np.unique(found.ids[rows < 0])
    if len(unknown):
        notes.append(f"{name}: marker id(s) {_ids_text(unknown)} are not in the survey file {test_field.survey}; "
                     "left out (survey them, or check that the file is this wall's)")
    keep = (rows >= 0) & ~np.isin(found.ids, twice)
    height, width = image.shape[:2]
    if keep.sum() < MIN_MARKERS:
        return FieldDetection(None, notes, f"{name}: {int(keep.sum())} surveyed marker(s) of {test_field.dictionary} "
                              f"found; a view needs at least {MIN_MARKERS} (is the dictionary right, and the wall "
                              "sharp and well lit?)")
    order = np.argsort(rows[keep])
    corners = found.corners_px[keep][order]
    detection = Detection(marker_centres(corners, camera), rows[keep][order], (width, height),
                          marker_corners_px=corners)
    return FieldDetection(detection, notes)


def no_board_message(name: str, board: BoardSpec) -> str:
    """Why a board was not found in the image ``name``."""
    cols, rows = board.corner_grid
    return (f"{name}: no {board.kind} with {cols}x{rows} inner corners found; check the board spec ({board}) "
            "and that the whole board is sharp and inside the image")


def detect_target(image: np.ndarray, target: CameraTarget, name: str) -> tuple[Detection | None, str, list[str]]:
    """The target in the image ``name`` (grayscale or BGR): its detection (None if not found, at full accuracy),
    why it was not found, and notes on what was left out of it (a test field's markers whose ids are not surveyed
    or are seen twice)."""
    if isinstance(target, TestField):
        found = detect_test_field(image, target, name)
        return found.detection, found.reason, found.notes
    return detect_board(image, target), no_board_message(name, target), []
