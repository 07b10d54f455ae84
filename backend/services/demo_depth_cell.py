"""The depth-cell demo: six simulated Kinect v2 nodes over the paper's 10 x 15 x 5 m cell, each its own agent process.

``calib-studio demo --rig depth-cell`` opens the session :data:`DEPTH_CELL_NAME`:

- its rig is rooted at ``world`` (the cell's floor corner, Z up) and holds the depth nodes ``sn1`` .. ``sn6``
  (kind ``depth``, optical frames), each mounted where a tape measure would put it: the paper's calibrated pose
  (:data:`~backend.core.depth_cell.PAPER_NODE_POSES`, the simulator's truth) off by :data:`TAPE_ERROR_M` and
  :data:`TAPE_ERROR_DEG` (seeded), with the mounting sigma :data:`MOUNT_SIGMA`;
- each node's device is ``{"driver": "node", "node": NAME}``: it is captured through the studio's
  :class:`~backend.devices.node_network.NodeNetwork`, from the agent process that renders it
  (:func:`start_depth_cell_nodes`, device spec ``sim-cell:NAME``);
- the cell's layout (tables, floor lines, crosses and their laser-measured distances) is in the session's
  ``depth_network.json``, and two captures per node (its tables behind each other, then beside each other) are
  stored so the network screen and the automatic solve have something at once;
- the simulator's truth (node poses, table placements, cross positions) is ``truth.json`` in the session
  folder, for tests and checks; the studio's rig step shows each node's distance from it, nothing else reads it.

The session is built in :data:`STAGING_DIR` and moved into place whole, as the robot-rig demo is
(:mod:`backend.services.demo`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from backend.calib.depth import service as depth_network
from backend.core.depth import pose_from_row
from backend.core.depth_cell import PAPER_NODE_POSES, CellLayout, TablePlacement, default_cell_layout
from backend.core.result import ProgressCallback, no_progress
from backend.core.rig import Frame, Rig
from backend.devices.base import create_device
from backend.devices.node_network import NodeNetwork
from backend.services.demo import ensure_staged_session
from backend.services.jobs import Job, JobRunner
from backend.services.network_keys import ensure_network_keys
from backend.services.node_processes import NodeProcesses, free_tcp_port
from backend.sim.depth_cell import table_placements, truth_dict
from backend.sim.tape_measure import tape_guess
from backend.store.atomic import write_json_atomic
from backend.store.session import Session, SessionStore

DEPTH_CELL_NAME = "depth-cell"
DEPTH_NODES = tuple(PAPER_NODE_POSES)
"""The cell's nodes, ``sn1`` .. ``sn6``."""
TAPE_ERROR_M = (0.03, 0.05)
"""How far (m, range of the norm) each node's tape-measured position is from the truth."""
TAPE_ERROR_DEG = (1.0, 2.0)
"""How far (deg, range of the angle) each node's typed rotation is from the truth."""
MOUNT_SIGMA = (0.1, 5.0)
"""1-sigma of the tape-measured mounting: translation (m, per axis), rotation (deg, per axis)."""
DEMO_SEED = 14
SEEDED_ARRANGEMENTS: tuple[Literal["behind", "beside"], ...] = ("behind", "beside")
"""The captures stored per node: the tables behind each other, then beside each other (the guided steps 2, 3)."""
AGENT_RATE_HZ = 1.0
"""Publishing rate (Hz) of the demo's agents: six renderers on a laptop's cores at the Kinect's 30 Hz would
starve the studio; the cell stands still, so a frame a second previews it, and captures are full frames on
request."""
TRUTH_FILE = "truth.json"
STAGING_DIR = ".depth-cell-building"
"""Folder under the sessions root where the session is built before it is moved into place (not a session)."""
NODE_LOG_DIR = ".node-logs"
"""Folder under the sessions root holding each demo agent's log, ``<name>.log`` (not a session)."""
NODE_KEYS_DIR = ".depth-cell-keys"
"""Folder under the sessions root holding the demo network's keys (made once, then reused; not a session)."""
BUILD_TITLE = "preparing the depth-cell session"


def depth_cell_rig(seed: int = DEMO_SEED) -> Rig:
    """The cell's rig: ``world`` and the six nodes at their tape-measured poses (seeded), captured over the
    network (device ``{"driver": "node", "node": NAME}``)."""
    rng = np.random.default_rng(seed)
    rig = Rig(root="world")
    for name, row in PAPER_NODE_POSES.items():
        rig.add(Frame(name, "world", tape_guess(pose_from_row(row), rng, TAPE_ERROR_M, TAPE_ERROR_DEG), kind="depth",
                      device={"driver": "node", "node": name}, mount_sigma=MOUNT_SIGMA))
    return rig


def demo_placements(layout: CellLayout) -> dict[str, list[TablePlacement]]:
    """Where the tables stand in each seeded capture: ``{"sn1/behind": [...], "sn1/beside": [...], ...}``."""
    return {f"{node}/{arrangement}": table_placements(node, arrangement, layout)
            for node in DEPTH_NODES for arrangement in SEEDED_ARRANGEMENTS}


def ensure_depth_cell_session(store: SessionStore, *, fresh: bool = False,
                              progress: ProgressCallback = no_progress) -> Session:
    """Open the depth-cell session, building it from the simulator in :data:`STAGING_DIR` if missing (or ``fresh``:
    the old one is moved aside, never deleted). ``progress`` hears the build's fraction (0..1) and what it does."""
    return ensure_staged_session(store, DEPTH_CELL_NAME, STAGING_DIR, lambda staging: _build(staging, progress),
                                 fresh=fresh)


def start_depth_cell_build(store: SessionStore, jobs: JobRunner, *, fresh: bool = False) -> Job:
    """:func:`ensure_depth_cell_session` as a job titled :data:`BUILD_TITLE` (its result: the :class:`Session`)."""
    return jobs.submit(BUILD_TITLE, lambda progress: ensure_depth_cell_session(store, fresh=fresh, progress=progress))


def _build(store: SessionStore, progress: ProgressCallback) -> Session:
    """Create the session in ``store``: the rig, the layout, the truth beside it and the seeded captures."""
    layout = default_cell_layout()
    session = store.create(DEPTH_CELL_NAME, rig=depth_cell_rig(),
                           title="Simulated depth cell: six Kinect v2 nodes (known ground truth)")
    depth_network.set_layout(session, layout.to_dict())
    placements = demo_placements(layout)
    truth = truth_dict(layout, {name: pose_from_row(row) for name, row in PAPER_NODE_POSES.items()}, placements)
    write_json_atomic(session.path / TRUTH_FILE, truth)
    for i, node in enumerate(DEPTH_NODES):
        progress(i / len(DEPTH_NODES), f"capturing the tables in view of simulated node {node}")
        with create_device({"driver": "sim_depth", "node": node, "seed": DEMO_SEED, "rate_hz": 0.0}) as camera:
            for arrangement in SEEDED_ARRANGEMENTS:
                tables = placements[f"{node}/{arrangement}"]
                camera.set_placements(tables)
                depth_network.capture_node(session, node, camera.read(), arrangement, [t.table for t in tables],
                                           device=camera.describe())
    return session


def agent_devices() -> dict[str, str]:
    """Each node agent's device spec: ``{"sn1": "sim-cell:sn1", ...}``."""
    return {node: f"sim-cell:{node}" for node in DEPTH_NODES}


@dataclass
class DepthCellNodes:
    """The studio's end of the cell's network and the six agent processes connected to it."""

    network: NodeNetwork
    agents: NodeProcesses
    endpoint: str
    """Where the studio listens (``tcp/127.0.0.1:PORT``): another agent joins with ``--connect`` to it."""

    def close(self) -> None:
        """Stop the agents, then the studio's Zenoh session."""
        self.agents.stop()
        self.network.close()


def start_depth_cell_nodes(log_dir: Path, keys_dir: Path, on_exit: Callable[[str, str], None],
                           rate_hz: float = AGENT_RATE_HZ) -> DepthCellNodes:
    """Listen with the network's keys on a free port of 127.0.0.1 and start one agent per node connecting to it,
    each with its own key bundle, as six computers would (logs in ``log_dir``).

    The keys are made in ``keys_dir`` the first time, then reused. ``on_exit(name, why)`` hears of
    any agent that exits before :meth:`DepthCellNodes.close`. Call from the thread that lives as long as the
    studio (see :mod:`backend.services.node_processes`).
    """
    keys = ensure_network_keys(keys_dir, list(DEPTH_NODES))
    endpoint = f"tls/127.0.0.1:{free_tcp_port()}"
    network = NodeNetwork(listen=[endpoint], keys=keys)
    network.open()
    agents = NodeProcesses(endpoint, log_dir, rate_hz=rate_hz, keys=keys)
    try:
        agents.start(agent_devices())
    except BaseException:
        agents.stop()
        network.close()
        raise
    agents.watch(on_exit)
    return DepthCellNodes(network, agents, endpoint)

