"""Accumulating the frames of a static LiDAR into one dense cloud, and how much of its field of view it covers.

A non-repetitive scanner (Livox Horizon, Avia) hits a different part of its field of view in every frame, so a
static sensor's frames added up over an integration time ``T`` (s, the user's choice) make a cloud that gets denser
and more complete as ``T`` grows. :class:`CloudAccumulator` keeps the returns whose times fall in ``[t0, t0 + T)``,
``t0`` being the first return's time, and counts them per angular cell as it goes.

**Coverage.** The field of view (:class:`FieldOfView`, full angles in rad, centred on the x axis of the sensor frame:
x forward, y left, z up) is cut into square cells of ``cell_rad`` (0.5 deg by default) in azimuth (from x towards y)
and elevation (up from the x-y plane). A return lands in the cell of its direction; the coverage share is the share
of the cells inside the field of view hit at least once (a rectangular field of view counts every cell, an
elliptical one the cells the ellipse reaches into). :class:`Coverage` holds the per-cell counts as an
image: row 0 at the top (highest elevation), column 0 at the left (largest azimuth, the sensor's left seen from
behind it), so a UI draws it as is.

Everything is vectorised over points; sizes are bounded by :data:`MAX_INTEGRATION_S` and
:data:`~backend.core.limits.MAX_CLOUD_POINTS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from backend.core.errors import InputError
from backend.core.limits import MAX_CLOUD_POINTS

DEFAULT_CELL_RAD = math.radians(0.5)
"""Side of a coverage cell (rad)."""
MIN_CELL_RAD = math.radians(0.05)
"""Finest coverage cell allowed (rad): bounds the counts image."""
MAX_INTEGRATION_S = 60.0
"""Longest integration time accepted (s)."""


@dataclass(frozen=True)
class FieldOfView:
    """A sensor's field of view, centred on its x axis."""

    horizontal_rad: float
    """Full horizontal angle (rad), in azimuth."""
    vertical_rad: float
    """Full vertical angle (rad), in elevation."""
    elliptical: bool = False
    """True when the pattern fills an ellipse in azimuth/elevation (the Avia's rosette), False for a rectangle."""

    def cells(self, cell_rad: float) -> tuple[int, int, np.ndarray]:
        """``(rows, columns, inside)``: the cell grid over the field of view and the (rows, columns) bool mask of
        the cells inside it."""
        rows = max(1, math.ceil(self.vertical_rad / cell_rad - 1e-9))
        cols = max(1, math.ceil(self.horizontal_rad / cell_rad - 1e-9))
        if not self.elliptical:
            return rows, cols, np.ones((rows, cols), bool)
        # the point of each cell nearest the centre of the field of view: a cell the edge cuts is inside
        top = self.vertical_rad / 2 - np.arange(rows) * cell_rad
        left = self.horizontal_rad / 2 - np.arange(cols) * cell_rad
        elevation = np.clip(0.0, top - cell_rad, top)
        azimuth = np.clip(0.0, left - cell_rad, left)
        inside = ((elevation[:, None] / (self.vertical_rad / 2)) ** 2
                  + (azimuth[None, :] / (self.horizontal_rad / 2)) ** 2) <= 1.0
        return rows, cols, inside


@dataclass
class Coverage:
    """How much of a field of view a cloud hits (see the module docstring)."""

    counts: np.ndarray
    """(rows, columns) int64 returns per cell, row 0 at the top, column 0 at the left."""
    inside: np.ndarray
    """(rows, columns) bool: cells inside the field of view."""
    cell_rad: float
    fov: FieldOfView
    beyond_grid: int = 0
    """Returns whose directions lie beyond the grid of cells altogether (not in :attr:`counts`)."""

    @property
    def share(self) -> float:
        """Share (0..1) of the cells inside the field of view hit at least once."""
        return float(np.count_nonzero(self.counts[self.inside]) / max(np.count_nonzero(self.inside), 1))

    @property
    def outside(self) -> int:
        """Returns outside the field of view, in cells outside it or beyond the grid (none from a sensor within its
        field of view, but for the quantisation of its coordinates along the edge)."""
        return int(self.counts[~self.inside].sum()) + self.beyond_grid


def check_integration_s(integration_s: float) -> float:
    """``integration_s`` as a float; :class:`InputError` naming ``integration_s`` unless it is a number of seconds in
    (0, :data:`MAX_INTEGRATION_S`]."""
    if isinstance(integration_s, bool) or not (isinstance(integration_s, (int, float))
                                               and 0 < integration_s <= MAX_INTEGRATION_S):
        raise InputError(f"the integration time must be a number of seconds in (0, {MAX_INTEGRATION_S:g}], "
                         f"not {integration_s!r}", "integration_s")
    return float(integration_s)


def _check_cell(cell_rad: float) -> float:
    number = isinstance(cell_rad, (int, float)) and not isinstance(cell_rad, bool)
    if not (number and MIN_CELL_RAD <= cell_rad <= math.pi / 4):
        raise InputError(f"the coverage cell must be {math.degrees(MIN_CELL_RAD):g} to 45 deg, not {cell_rad!r} rad",
                         "cell_rad")
    return float(cell_rad)


def cell_indices(points: np.ndarray, fov: FieldOfView, cell_rad: float) -> np.ndarray:
    """(N,) int64 flat index (``row * columns + column``) of each point's cell, -1 for points outside the grid."""
    points = np.asarray(points, float).reshape(-1, 3)
    rows, cols, _ = fov.cells(cell_rad)
    azimuth = np.arctan2(points[:, 1], points[:, 0])
    elevation = np.arctan2(points[:, 2], np.hypot(points[:, 0], points[:, 1]))
    row = np.floor((fov.vertical_rad / 2 - elevation) / cell_rad).astype(np.int64)
    col = np.floor((fov.horizontal_rad / 2 - azimuth) / cell_rad).astype(np.int64)
    on_grid = (row >= 0) & (row < rows) & (col >= 0) & (col < cols)
    return np.where(on_grid, row * cols + col, -1)


def coverage_of(points: np.ndarray, fov: FieldOfView, cell_rad: float = DEFAULT_CELL_RAD) -> Coverage:
    """The :class:`Coverage` of ``points`` (N, 3) (m, sensor frame) over ``fov``."""
    cell_rad = _check_cell(cell_rad)
    rows, cols, inside = fov.cells(cell_rad)
    cells = cell_indices(points, fov, cell_rad)
    counts = np.bincount(cells[cells >= 0], minlength=rows * cols).reshape(rows, cols)
    return Coverage(counts.astype(np.int64), inside, cell_rad, fov, int(np.count_nonzero(cells < 0)))


@dataclass
class AccumulatedCloud:
    """The returns of a static sensor over one integration time."""

    points: np.ndarray
    """(N, 3) float64 (m), the sensor frame."""
    intensity: np.ndarray
    """(N,) float32."""
    time_s: np.ndarray
    """(N,) float64 each return's time after the first (s)."""
    integration_s: float
    """The integration time asked for (s)."""
    frames: int
    """Frames that contributed."""
    coverage: Coverage


class CloudAccumulator:
    """Adds up frames of a static sensor until ``integration_s`` of its time is covered (see the module docstring)."""

    def __init__(self, integration_s: float, fov: FieldOfView, cell_rad: float = DEFAULT_CELL_RAD):
        """:class:`InputError` for a bad ``integration_s`` (:func:`check_integration_s`) or a cell out of range."""
        self.integration_s = check_integration_s(integration_s)
        self.fov = fov
        self.cell_rad = _check_cell(cell_rad)
        rows, cols, self._inside = fov.cells(self.cell_rad)
        self._counts = np.zeros(rows * cols, np.int64)
        self._beyond_grid = 0
        self._points: list[np.ndarray] = []
        self._intensity: list[np.ndarray] = []
        self._times: list[np.ndarray] = []
        self._t0: float | None = None
        self._size = 0
        self.frames = 0
        self.complete = False
        """True once a return at or past the end of the window has been seen: the window is fully covered."""

    def add(self, points: np.ndarray, time_s: np.ndarray, intensity: np.ndarray | None = None) -> bool:
        """Add a frame: (N, 3) points (m), (N,) their times (s, any origin, the same for every frame) and
        intensities; returns :attr:`complete`. Returns before the window are dropped (time running backwards
        does not extend it). :class:`InputError` when the window would hold more than
        :data:`~backend.core.limits.MAX_CLOUD_POINTS`."""
        points = np.asarray(points, float).reshape(-1, 3)
        time_s = np.asarray(time_s, float).reshape(-1)
        intensity = np.zeros(len(points), np.float32) if intensity is None else np.asarray(intensity, np.float32)
        if len(time_s) == 0:
            return self.complete
        if self._t0 is None:
            self._t0 = float(time_s.min())
        rel = time_s - self._t0
        keep = (rel >= 0) & (rel < self.integration_s)
        self.complete = self.complete or bool((rel >= self.integration_s).any())
        if not keep.any():
            return self.complete
        self._size += int(keep.sum())
        if self._size > MAX_CLOUD_POINTS.value():
            raise InputError(f"{self.integration_s:g} s of this sensor hold more than {MAX_CLOUD_POINTS.describe()}; "
                             "choose a shorter integration time", "integration_s")
        kept = points[keep]
        self._points.append(kept)
        self._intensity.append(intensity[keep])
        self._times.append(rel[keep])
        cells = cell_indices(kept, self.fov, self.cell_rad)
        self._counts += np.bincount(cells[cells >= 0], minlength=len(self._counts))
        self._beyond_grid += int(np.count_nonzero(cells < 0))
        self.frames += 1
        return self.complete

    def coverage(self) -> Coverage:
        """The coverage of what has been added so far."""
        return Coverage(self._counts.reshape(self._inside.shape).copy(), self._inside, self.cell_rad, self.fov,
                        self._beyond_grid)

    def cloud(self) -> AccumulatedCloud:
        """The accumulated cloud so far, with its coverage."""
        if not self._points:
            empty = np.zeros((0, 3))
            return AccumulatedCloud(empty, np.zeros(0, np.float32), np.zeros(0), self.integration_s, 0,
                                    self.coverage())
        return AccumulatedCloud(np.concatenate(self._points), np.concatenate(self._intensity),
                                np.concatenate(self._times), self.integration_s, self.frames, self.coverage())
