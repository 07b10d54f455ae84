"""The depth nodes' pose table, as the paper prints it: X, Y, Z (m) and RotZ, RotY, RotX (deg) per node.

Rotations are the ROS static-transform order (``R = Rz Ry Rx``, :func:`backend.core.depth.pose_row`).
The same rows give the ``pose-table`` export (CSV), the CLI's text table and the report's table.
"""

from __future__ import annotations

import csv
import io
import re
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from backend.core.depth import POSE_COLUMNS, pose_row
from backend.core.errors import InputError
from backend.core.rig import Rig

UNITS = ("m", "m", "m", "deg", "deg", "deg")
"""Units of :data:`~backend.core.depth.POSE_COLUMNS`, in order."""


def node_order(names: Iterable[str]) -> list[str]:
    """Node names in natural order (``sn2`` before ``sn10``), the paper's table order."""
    return sorted(names, key=lambda name: [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", name)])


def pose_table_rows(poses: Mapping[str, np.ndarray], std: Mapping[str, Mapping[str, Any]] | None = None
                    ) -> list[dict[str, Any]]:
    """One row per node (natural order): ``node``, the six pose columns (m, deg) of ``T_world_node`` and, from
    ``std`` (``{"trans_m": [3], "rot_deg": [3]}`` per node, entries None where unknown), ``sigma_mm`` and
    ``sigma_deg``: the largest translation (mm) and rotation (deg) 1-sigma, None when unknown."""
    rows = []
    for node in node_order(poses):
        row: dict[str, Any] = {"node": node, **dict(zip(POSE_COLUMNS, pose_row(poses[node]), strict=True))}
        sigma = (std or {}).get(node) or {}
        trans, rot = sigma.get("trans_m"), sigma.get("rot_deg")
        row["sigma_mm"] = None if not trans or None in trans else 1e3 * max(trans)
        row["sigma_deg"] = None if not rot or None in rot else max(rot)
        rows.append(row)
    return rows


def rig_pose_rows(rig: Rig) -> list[dict[str, Any]]:
    """:func:`pose_table_rows` of every depth node of ``rig`` (``T_root_node``, sigma from its frame's covariance,
    which is about its parent's axes); :class:`InputError` (409) when the rig has none."""
    nodes = rig.sensors("depth")
    if not nodes:
        raise InputError("the rig has no depth nodes; add the cell's nodes first", "rig", 409)
    std = {}
    for frame in nodes:
        sigmas = frame.sigmas
        std[frame.name] = {} if sigmas is None else {"trans_m": sigmas[0].tolist(), "rot_deg": sigmas[1].tolist()}
    return pose_table_rows({frame.name: rig.T_root_frame(frame.name) for frame in nodes}, std)


def dump_pose_table_csv(rows: list[dict[str, Any]]) -> str:
    """The rows as CSV: ``node,X_m,Y_m,Z_m,RotZ_deg,RotY_deg,RotX_deg,sigma_mm,sigma_deg`` (empty when unknown)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["node", *(f"{c}_{u}" for c, u in zip(POSE_COLUMNS, UNITS, strict=True)), "sigma_mm",
                     "sigma_deg"])
    for row in rows:
        writer.writerow([row["node"], *(f"{row[c]:.4f}" if u == "m" else f"{row[c]:.3f}"
                                        for c, u in zip(POSE_COLUMNS, UNITS, strict=True)),
                         "" if row["sigma_mm"] is None else f"{row['sigma_mm']:.2f}",
                         "" if row["sigma_deg"] is None else f"{row['sigma_deg']:.4f}"])
    return out.getvalue()


def format_pose_table(rows: list[dict[str, Any]], extra: Mapping[str, str] | None = None) -> str:
    """The rows as a fixed-width text table for a terminal; ``extra`` (node -> text) adds a last column."""
    header = f"{'node':<8}" + "".join(f"{f'{c} [{u}]':>12}" for c, u in zip(POSE_COLUMNS, UNITS, strict=True))
    header += f"{'sigma mm':>10}{'sigma deg':>10}" + ("  verdict" if extra else "")
    lines = [header]
    for row in rows:
        cells = "".join(f"{row[c]:>12.4f}" if u == "m" else f"{row[c]:>12.3f}"
                        for c, u in zip(POSE_COLUMNS, UNITS, strict=True))
        sigma_mm = "—" if row["sigma_mm"] is None else f"{row['sigma_mm']:.2f}"
        sigma_deg = "—" if row["sigma_deg"] is None else f"{row['sigma_deg']:.3f}"
        lines.append(f"{row['node']:<8}{cells}{sigma_mm:>10}{sigma_deg:>10}"
                     + (f"  {extra.get(row['node'], '')}" if extra else ""))
    return "\n".join(lines)


def dump_pose_table(rig: Rig) -> str:
    """The ``pose-table`` export: :func:`dump_pose_table_csv` of the rig's depth nodes."""
    return dump_pose_table_csv(rig_pose_rows(rig))
