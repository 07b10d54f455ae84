"""The depth-cell scene the depth tests share: the paper's cell, its six nodes at their true poses, and what a
user types (the truth off by :data:`POSE_OFFSET`).

:func:`render_captures` renders a node's two captures (tables behind, then beside), :func:`build_cell_session`
makes a session of some nodes at their typed poses with those captures, :func:`pose_error` measures a solved pose.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from backend.calib.depth import service
from backend.core.depth import KINECT_V2, pose_from_row
from backend.core.depth_cell import PAPER_NODE_POSES, default_cell_layout
from backend.core.transforms import transform_error
from backend.devices.base import Sample
from backend.sim.depth_cell import CellScene, DepthFrame, table_placements
from backend.store.session import Session

POSE_OFFSET = np.array([0.04, -0.03, 0.05, 1.5, -1.0, 2.0])
"""How far each typed pose is from the truth: X, Y, Z (m), RotZ, RotY, RotX (deg)."""
ARRANGEMENTS = ("behind", "beside")


def frame_sample(frame: DepthFrame) -> Sample:
    """A rendered frame as the sim driver's sample: depth, points and their amplitude at their pixel index."""
    points, index = KINECT_V2.unproject(frame.depth_m)
    return Sample(frame.timestamp_s, depth=frame.depth_m, points=points, intensity=frame.amplitude.ravel()[index],
                  meta={"pixel_index": index})


def render_captures(node: str, seed: int) -> list[tuple[str, list[str], DepthFrame]]:
    """The node's two captures (tables behind, then beside each other) at its true pose: (arrangement, tables,
    frame)."""
    layout, rng = default_cell_layout(), np.random.default_rng(seed)
    out = []
    for arrangement in ARRANGEMENTS:
        placements = table_placements(node, arrangement, layout)
        frame = CellScene(layout, placements).render(pose_from_row(PAPER_NODE_POSES[node]), rng)
        out.append((arrangement, [p.table for p in placements], frame))
    return out


def typed_pose(node: str) -> list[float]:
    """The tape-measured pose the user types: the truth off by :data:`POSE_OFFSET`."""
    return list(np.array(PAPER_NODE_POSES[node]) + POSE_OFFSET)


def build_cell_session(folder: Path, nodes: Sequence[str], seed: int = 0) -> Session:
    """A session of ``nodes`` at their typed poses, each with its two captures."""
    session = Session.create(folder, folder.name)
    for i, node in enumerate(nodes):
        service.add_node(session, node, typed_pose(node))
        for arrangement, tables, frame in render_captures(node, seed + i):
            service.capture_node(session, node, frame_sample(frame), arrangement, tables)
    return session


def pose_error(T: np.ndarray, node: str) -> tuple[float, float]:
    """Translation (m) and rotation (deg) error of ``T`` against the node's true pose."""
    trans_m, rot_deg = transform_error(np.asarray(T), pose_from_row(PAPER_NODE_POSES[node]))
    return float(np.linalg.norm(trans_m)), float(np.linalg.norm(rot_deg))
