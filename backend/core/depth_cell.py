"""What is known of a depth-camera cell: its floor lines, its tables, its crosses and their measured distances.

The cell's ``world`` frame has its origin on the floor in one corner, X and Y along the
walls and Z up (m). The calibration of every depth node rests on this known geometry:

- **tables** of known top height (white, movable): a table top seen by a node is a horizontal
  plane at ``height_m``; where it stands is not known;
- **floor lines** (tape) at known ``X = value`` or ``Y = value``;
- **crosses** (retroreflective) whose distances a laser distance meter measured: the
  independent check of the network (never a constraint of the solve unless ``surveyed``).

:data:`PAPER_NODE_POSES` are the six Kinect v2 nodes' calibrated poses in the paper's table
(X, Y, Z in m; RotZ, RotY, RotX in deg; see :mod:`backend.core.depth`); the simulated cell
places its nodes there.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np

from backend.core.errors import InputError

PAPER_NODE_POSES: dict[str, tuple[float, float, float, float, float, float]] = {
    "sn1": (9.975, 0.260, 4.898, 44.977, -0.859, -138.598),
    "sn2": (0.247, 0.285, 4.960, -46.696, -1.146, -139.573),
    "sn3": (9.850, 7.555, 4.950, 88.064, -1.375, -139.630),
    "sn4": (0.138, 7.437, 4.930, -89.668, -0.573, -148.396),
    "sn5": (6.395, 13.550, 4.954, 154.870, -0.745, -138.255),
    "sn6": (0.087, 14.660, 4.990, -131.207, 0.000, -134.645),
}
"""The paper's calibrated node poses: X, Y, Z (m), RotZ, RotY, RotX (deg), ``R = Rz Ry Rx`` in the node frame."""


@dataclass(frozen=True)
class TableSpec:
    """A movable white table of known top height."""

    name: str
    height_m: float
    """Height of the top above the floor (m)."""
    size_m: tuple[float, float] = (1.6, 0.8)
    """Length and width of the top (m)."""


@dataclass(frozen=True)
class TablePlacement:
    """Where a table stands for one capture (the simulator's truth; a user knows only which tables are in view)."""

    table: str
    centre_xy_m: tuple[float, float]
    yaw_deg: float = 0.0


@dataclass(frozen=True)
class FloorLine:
    """A tape line on the floor: every point of it has ``axis`` coordinate ``value_m`` (``X = 2 m``)."""

    name: str
    axis: Literal["x", "y"]
    value_m: float
    span_m: tuple[float, float]
    """Extent along the other axis (m)."""
    width_m: float = 0.05

    @property
    def label(self) -> str:
        return f"{self.axis.upper()} = {self.value_m:g} m"


@dataclass(frozen=True)
class Cross:
    """A retroreflective cross: its centre (m, world) and arm length (m)."""

    name: str
    position_m: tuple[float, float, float]
    size_m: float = 0.3
    surveyed: bool = False
    """True when its position was surveyed and may be used as a known point of the solve."""


@dataclass(frozen=True)
class MeasuredDistance:
    """A laser-measured distance between two crosses (m)."""

    a: str
    b: str
    measured_m: float
    what: str = ""
    """What the distance spans, for the table (``gantry track``)."""


@dataclass
class CellLayout:
    """The known geometry of one cell (m, world frame)."""

    size_m: tuple[float, float, float] = (10.0, 15.0, 5.0)
    tables: list[TableSpec] = field(default_factory=list)
    lines: list[FloorLine] = field(default_factory=list)
    crosses: list[Cross] = field(default_factory=list)
    distances: list[MeasuredDistance] = field(default_factory=list)

    def table(self, name: str) -> TableSpec:
        for table in self.tables:
            if table.name == name:
                return table
        raise InputError(f"no table named {name!r}; the cell has {[t.name for t in self.tables]}", "table")

    def cross(self, name: str) -> Cross:
        for cross in self.crosses:
            if cross.name == name:
                return cross
        raise InputError(f"no cross named {name!r}; the cell has {[c.name for c in self.crosses]}", "cross")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CellLayout:
        """Read :meth:`to_dict` back; a missing or malformed field raises :class:`InputError` naming it."""
        try:
            layout = cls(size_m=tuple(float(v) for v in data.get("size_m", (10.0, 15.0, 5.0))),
                         tables=[TableSpec(t["name"], float(t["height_m"]), tuple(t.get("size_m", (1.6, 0.8))))
                                 for t in data.get("tables", [])],
                         lines=[FloorLine(ln["name"], ln["axis"], float(ln["value_m"]), tuple(ln["span_m"]),
                                          float(ln.get("width_m", 0.05))) for ln in data.get("lines", [])],
                         crosses=[Cross(c["name"], tuple(float(v) for v in c["position_m"]),
                                        float(c.get("size_m", 0.3)), bool(c.get("surveyed", False)))
                                  for c in data.get("crosses", [])],
                         distances=[MeasuredDistance(d["a"], d["b"], float(d["measured_m"]), d.get("what", ""))
                                    for d in data.get("distances", [])])
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"cell layout: {type(exc).__name__} {exc}; expected the fields of CellLayout.to_dict",
                             "layout") from None
        for line in layout.lines:
            if line.axis not in ("x", "y"):
                raise InputError(f"floor line {line.name!r}: axis must be 'x' or 'y', got {line.axis!r}", "axis")
        return layout


def default_cell_layout() -> CellLayout:
    """The industrial cell of the paper, as the simulator builds it: 10 x 15 x 5 m, three white tables of
    0.74 m, tape lines at X = 2, 7 m and Y = 2, 7.5, 13 m, and retroreflective crosses on two gantry tracks
    and two robot tracks whose laser-measured distances are the paper's (6732, 6684, 1476, 1555 mm)."""
    tables = [TableSpec(f"table{i}", 0.74) for i in (1, 2, 3)]
    lines = [FloorLine("x2", "x", 2.0, (0.5, 14.5)), FloorLine("x7", "x", 7.0, (0.5, 14.5)),
             FloorLine("y2", "y", 2.0, (0.5, 9.5)), FloorLine("y7_5", "y", 7.5, (0.5, 9.5)),
             FloorLine("y13", "y", 13.0, (0.5, 9.5))]
    crosses = [Cross("gantry_a1", (3.5, 3.0, 0.0)), Cross("gantry_a2", (3.5, 9.732, 0.0)),
               Cross("gantry_b1", (6.0, 3.5, 0.0)), Cross("gantry_b2", (6.0, 10.184, 0.0)),
               Cross("robot_a1", (4.0, 11.0, 0.0)), Cross("robot_a2", (5.476, 11.0, 0.0)),
               Cross("robot_b1", (4.5, 5.5, 0.0)), Cross("robot_b2", (6.055, 5.5, 0.0))]
    distances = [MeasuredDistance("gantry_a1", "gantry_a2", 6.732, "gantry track 1"),
                 MeasuredDistance("gantry_b1", "gantry_b2", 6.684, "gantry track 2"),
                 MeasuredDistance("robot_a1", "robot_a2", 1.476, "robot track 1"),
                 MeasuredDistance("robot_b1", "robot_b2", 1.555, "robot track 2")]
    return CellLayout(tables=tables, lines=lines, crosses=crosses, distances=distances)


def cross_distance(layout: CellLayout, a: str, b: str) -> float:
    """The true distance (m) between two crosses of the layout."""
    return float(np.linalg.norm(np.subtract(layout.cross(a).position_m, layout.cross(b).position_m)))
