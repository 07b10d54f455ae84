"""V-shaped 3D targets: two plates joined along a ridge at a known angle, with markers on each face.

A spec is one string, ``vtarget:WxH:ANGLE:COLSxROWS:MARKER:DICT``: each plate's width (from the ridge to its outer
edge) and height (along the ridge) in metres, the angle between the plates in degrees as seen from the front (below
180: the V opens towards the sensors, the ridge at the back; above 180: the ridge points at them), each face's grid
of markers, the markers' printed side in metres and their OpenCV dictionary, e.g.
``vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50`` (100 x 60 cm plates at 120 deg, six 15 cm markers a face).

The target's frame is a board's seen from the front: origin on the ridge's midpoint, x to the right, y down along
the ridge, z away from the viewer (a camera square-on to the target has ``R_camera_target`` near the identity).
Face 0 is the left plate, face 1 the right one. Each face's print is ``W x H``: its markers sit at the centres of
a ``COLS x ROWS`` grid of equal cells, read left to right and top to bottom as seen from the front, ids
``0 .. COLS*ROWS - 1`` on face 0 and the next ``COLS*ROWS`` on face 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from backend.core.errors import InputError, shorten
from backend.core.markers import dictionary_named, dictionary_size

SPEC_FORMAT = "vtarget:WxH:ANGLE:COLSxROWS:MARKER:DICT (e.g. vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50)"
MIN_FLATNESS_DEG = 20.0
"""The plates must be at least this far from flat (180 deg): nearly flat plates pin the extrinsic as one plane does."""
MARKER_FILL = 0.8
"""A marker may fill at most this fraction of its cell, leaving a white quiet zone around it."""


@dataclass(frozen=True)
class VTarget:
    """A V-shaped target's geometry and markers (see the module's docstring for its frame)."""

    width_m: float
    """Each plate's width, from the ridge to its outer edge (m)."""
    height_m: float
    """Each plate's height, along the ridge (m)."""
    angle_deg: float
    """Angle between the two plates' fronts (deg)."""
    cols: int
    rows: int
    marker_m: float
    dictionary: str

    @classmethod
    def parse(cls, spec: str) -> VTarget:
        """Parse a V-target spec, raising :class:`InputError` naming the bad field."""
        parts = spec.strip().split(":")
        shown = shorten(spec)
        if parts[0] != "vtarget" or len(parts) != 6:
            raise InputError(f"V-target spec {shown} is not {SPEC_FORMAT}", "target")
        try:
            width_m, height_m = (float(v) for v in parts[1].lower().split("x"))
            angle_deg = float(parts[2])
            cols, rows = (int(v) for v in parts[3].lower().split("x"))
            marker_m = float(parts[4])
        except ValueError:
            raise InputError(f"V-target spec {shown} has a field that is not a number; expected {SPEC_FORMAT}",
                             "target") from None
        dictionary_named(parts[5], spec, "target")
        if not (0.1 <= width_m <= 5 and 0.1 <= height_m <= 5):
            raise InputError(f"plate size {shorten(parts[1])} in {shown} must be two lengths in metres, 0.1 to 5",
                             "target")
        if not MIN_FLATNESS_DEG <= abs(angle_deg - 180) <= 180 - MIN_FLATNESS_DEG:
            raise InputError(f"plate angle {angle_deg:g} deg in {shown} must be between {MIN_FLATNESS_DEG:g} and "
                             f"{180 - MIN_FLATNESS_DEG:g} deg from flat (180 deg)", "target")
        if cols < 1 or rows < 1:
            raise InputError(f"marker grid {shorten(parts[3])} in {shown} must be at least 1x1", "target")
        target = cls(width_m, height_m, angle_deg, cols, rows, marker_m, parts[5])
        cell_m = min(width_m / cols, height_m / rows)
        if not 0 < marker_m <= MARKER_FILL * cell_m:
            raise InputError(f"marker size {marker_m:g} m in {shown} must be positive and at most "
                             f"{MARKER_FILL * cell_m:.3g} m ({MARKER_FILL:g} of a grid cell, for the white border)",
                             "target")
        if 2 * cols * rows > dictionary_size(target.dictionary):
            raise InputError(f"{target.dictionary} has {dictionary_size(target.dictionary)} markers; {shown} needs "
                             f"{2 * cols * rows}", "target")
        return target

    def __str__(self) -> str:
        return (f"vtarget:{self.width_m:g}x{self.height_m:g}:{self.angle_deg:g}:{self.cols}x{self.rows}:"
                f"{self.marker_m:g}:{self.dictionary}")

    @property
    def markers_per_face(self) -> int:
        return self.cols * self.rows

    @cached_property
    def T_target_face(self) -> np.ndarray:
        """(2, 4, 4) each face's print frame in the target frame: origin at the print's top-left corner as seen from
        the front, x to the right, y down, z into the plate (a board's frame; m)."""
        half = math.radians(self.angle_deg) / 2
        s, c = math.sin(half), math.cos(half)
        frames = np.tile(np.eye(4), (2, 1, 1))
        down = np.array([0.0, 1.0, 0.0])
        x_left = np.array([s, 0.0, c])  # along the left plate, from its outer edge towards the ridge
        x_right = np.array([s, 0.0, -c])  # along the right plate, from the ridge outwards
        top = np.array([0.0, -self.height_m / 2, 0.0])
        for face, (x_axis, origin) in enumerate(((x_left, top - self.width_m * x_left), (x_right, top))):
            frames[face, :3, :3] = np.column_stack([x_axis, down, np.cross(x_axis, down)])
            frames[face, :3, 3] = origin
        return frames

    @property
    def face_planes(self) -> np.ndarray:
        """(2, 4) each face's plane ``[n, d]`` in the target frame, ``n . p + d = 0``, ``n`` towards the viewer."""
        normals = -self.T_target_face[:, :3, 2]
        offsets = -np.einsum("fi,fi->f", normals, self.T_target_face[:, :3, 3])
        return np.column_stack([normals, offsets])

    def plate_corners(self) -> np.ndarray:
        """(2, 4, 3) each plate's corners in the target frame (m): top-left, top-right, bottom-right, bottom-left."""
        print_xy = np.array([[0, 0], [self.width_m, 0], [self.width_m, self.height_m], [0, self.height_m]])
        return np.stack([self.on_face(face, print_xy) for face in range(2)])

    def on_face(self, face: int, print_xy: np.ndarray) -> np.ndarray:
        """(N, 3) target-frame points (m) of (N, 2) print coordinates (m, from the print's top-left) on ``face``."""
        T = self.T_target_face[face]
        return print_xy @ T[:3, :2].T + T[:3, 3]

    @cached_property
    def marker_ids(self) -> np.ndarray:
        """(2 * COLS * ROWS,) every marker's id: face 0's, then face 1's."""
        return np.arange(2 * self.markers_per_face)

    @cached_property
    def marker_centres_print(self) -> np.ndarray:
        """(COLS * ROWS, 2) marker centres on a face's print (m, from its top-left), in id order."""
        col, row = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        return np.column_stack([(col.ravel() + 0.5) * self.width_m / self.cols,
                                (row.ravel() + 0.5) * self.height_m / self.rows])

    @cached_property
    def marker_corners(self) -> np.ndarray:
        """(2 * COLS * ROWS, 4, 3) every marker's corners in the target frame (m), in id order and OpenCV's corner
        order (top-left, top-right, bottom-right, bottom-left of the printed marker)."""
        half = self.marker_m / 2
        offsets = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
        corners = [self.on_face(face, (self.marker_centres_print[:, None, :] + offsets).reshape(-1, 2))
                   for face in range(2)]
        return np.concatenate(corners).reshape(-1, 4, 3)

    def face_of(self, marker_ids: np.ndarray) -> np.ndarray:
        """The face (0 or 1) of each id in ``marker_ids``; -1 for an id the target does not carry."""
        ids = np.asarray(marker_ids, int)
        return np.where((ids >= 0) & (ids < 2 * self.markers_per_face), ids // self.markers_per_face, -1)
