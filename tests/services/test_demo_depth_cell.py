"""``calib-studio demo --rig depth-cell``: the session of six tape-measured depth nodes, the simulator's truth beside
it, six node-agent processes connected to the studio, an agent that dies named, and none left when the studio stops.

One studio process for the module (its agents take a few seconds to start on two cores)."""

from __future__ import annotations

import json
import os
import queue
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import pytest

from backend.core.depth import pose_row
from backend.core.depth_cell import PAPER_NODE_POSES
from backend.core.transforms import transform_error
from backend.services.demo_depth_cell import DEPTH_CELL_NAME, MOUNT_SIGMA, TAPE_ERROR_DEG, TAPE_ERROR_M, TRUTH_FILE
from backend.services.node_processes import NodeProcesses, free_tcp_port
from tests.conftest import ROOT, START_WAIT_S, Studio, poll, start_demo, stop_process, wait_health

pytestmark = pytest.mark.slow

NODES = sorted(PAPER_NODE_POSES)


@dataclass
class CellStudio(Studio):
    """The studio of ``demo --rig depth-cell``, with its viewer's port and its sessions folder."""

    viewer_port: int
    sessions: Path

    def log_text(self) -> str:
        return self.log.read_text(errors="replace")


def agent_processes(parent: int) -> dict[str, int]:
    """``{node name: pid}`` of the ``backend.cli node`` processes whose parent is ``parent`` (read from /proc)."""
    agents = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            argv = (entry / "cmdline").read_bytes().decode(errors="replace").split("\0")
        except (OSError, IndexError, ValueError):
            continue  # gone meanwhile
        if ppid == parent and "backend.cli" in argv and "node" in argv and "--name" in argv:
            agents[argv[argv.index("--name") + 1]] = int(entry.name)
    return agents


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory, free_port: Callable[[], int]) -> Iterator[CellStudio]:
    tmp = tmp_path_factory.mktemp("depth_cell")
    log = tmp / "studio.log"
    process, api_port, viewer_port = start_demo(tmp / "sessions", free_port, log, ("demo", "--rig", "depth-cell"))
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in process.stdout], daemon=True).start()
    studio = CellStudio("", f"http://127.0.0.1:{api_port}", process, log, viewer_port, tmp / "sessions")
    try:
        try:
            studio.url = lines.get(timeout=START_WAIT_S).strip()
        except queue.Empty:
            pytest.fail(f"the studio printed no URL (exit code {process.poll()}):\n{studio.log_tail()}")
        wait_health(studio.api, process, studio.log_tail)
        yield studio
    finally:
        stop_process(process)


def test_first_line_is_the_url_and_the_api_answers(cell: CellStudio) -> None:
    assert cell.url == f"http://127.0.0.1:{cell.viewer_port}/"
    assert cell.get("/api/health") == {"status": "ok"}


@pytest.fixture(scope="module")
def built(cell: CellStudio) -> CellStudio:
    """The studio once its depth-cell session is built (listed by the API)."""
    poll(lambda: DEPTH_CELL_NAME in [s["name"] for s in cell.get("/api/sessions")],
         lambda: f"the depth-cell session was never built:\n{cell.log_tail()}", START_WAIT_S)
    return cell


def test_the_session_holds_six_tape_measured_depth_nodes(built: CellStudio) -> None:
    cell = built
    rig = cell.get(f"/api/sessions/{DEPTH_CELL_NAME}/rig")
    assert rig["root"] == "world"
    frames = {frame["name"]: frame for frame in rig["frames"] if frame["name"] != "world"}
    assert sorted(frames) == NODES
    for name, frame in frames.items():
        assert frame["kind"] == "depth" and frame["parent"] == "world", frame
        assert frame["device"] == {"driver": "node", "node": name}
        assert tuple(frame["mount_sigma"]) == MOUNT_SIGMA
        # The tape-measured guess: off the truth by what a tape and a protractor leave (and not the truth itself).
        dt, dr_deg = transform_error(np.array(frame["T_parent_child"]), np.array(
            json.loads((cell.sessions / DEPTH_CELL_NAME / TRUTH_FILE).read_text())["nodes"][name]["T_world_node"]))
        assert TAPE_ERROR_M[0] - 1e-9 <= np.linalg.norm(dt) <= TAPE_ERROR_M[1] + 1e-9, (name, dt)
        assert TAPE_ERROR_DEG[0] - 1e-6 <= np.linalg.norm(dr_deg) <= TAPE_ERROR_DEG[1] + 1e-6, (name, dr_deg)


def test_truth_json_holds_the_paper_poses(built: CellStudio) -> None:
    truth = json.loads((built.sessions / DEPTH_CELL_NAME / TRUTH_FILE).read_text())
    assert sorted(truth["nodes"]) == NODES
    for name, row in PAPER_NODE_POSES.items():
        np.testing.assert_allclose(truth["nodes"][name]["pose_row"], row, atol=1e-9)
        np.testing.assert_allclose(pose_row(np.array(truth["nodes"][name]["T_world_node"])), row, atol=1e-9)
    assert set(truth["crosses"]) >= {"gantry_a1", "gantry_a2", "robot_b1", "robot_b2"}


def test_every_node_captures_over_the_network_through_the_api(built: CellStudio) -> None:
    """A full frame from each of the six agents, through the studio's node network (``capture-live``)."""
    base = f"{built.api}/api/sessions/{DEPTH_CELL_NAME}/depth-network/nodes"

    def capture(node: str) -> httpx.Response:
        return httpx.post(f"{base}/{node}/capture-live", json={"arrangement": "free", "timeout_s": 20}, timeout=30)

    def capture_when_seen(node: str) -> httpx.Response:
        def captured() -> httpx.Response | None:
            response = capture(node)  # the agent not yet seen: a 4xx naming it
            assert response.status_code < 500, response.text
            return response if response.status_code == 201 else None

        return poll(captured, lambda: f"{node}: {capture(node).text}", START_WAIT_S, 0.5)

    with ThreadPoolExecutor(len(NODES)) as pool:  # as the studio's Capture all: the nodes answer at once
        responses = dict(zip(NODES, pool.map(capture_when_seen, NODES), strict=True))
    for node, response in responses.items():
        assert response.status_code == 201, f"{node}: {response.text}\n{built.log_tail()}"
        record = response.json()
        assert record["image_size"] == [512, 424] and record["n_points"] > 100_000, record
    assert all(len(built.get(f"/api/sessions/{DEPTH_CELL_NAME}/depth-network/nodes/{n}/captures")) == 3 for n in NODES)
    presence = {p["name"]: p for p in built.get(f"/api/sessions/{DEPTH_CELL_NAME}/depth-network/presence")}
    assert sorted(presence) == sorted(NODES) and all(p["alive"] for p in presence.values()), presence
    assert all(abs(p["clock_offset_s"]) < 0.05 for p in presence.values()), presence  # one host: one clock
    network = built.get(f"/api/sessions/{DEPTH_CELL_NAME}/depth-network/network")  # secured, as a user runs it
    assert network["secure"] and network["admitted"] == sorted(NODES) and network["listen"][0].startswith("tls/")
    assert all(p["zid"] and p["refused"] == [] and p["held"] is None for p in presence.values()), presence


def test_six_agent_processes_run_and_a_dead_one_is_named(cell: CellStudio) -> None:
    poll(lambda: sorted(agent_processes(cell.process.pid)) == NODES,
         lambda: f"agents: {agent_processes(cell.process.pid)}\n{cell.log_tail()}", START_WAIT_S)
    os.kill(agent_processes(cell.process.pid)["sn6"], signal.SIGKILL)
    poll(lambda: "node agent sn6 was killed (SIGKILL)" in cell.log_text(), cell.log_tail, START_WAIT_S)
    assert sorted(agent_processes(cell.process.pid)) == NODES[:5]


def test_stopping_the_studio_stops_its_agents(cell: CellStudio) -> None:
    agents = agent_processes(cell.process.pid)
    assert agents, "no agents to stop"
    stop_process(cell.process)
    assert cell.process.returncode == 0, cell.log_tail()

    def gone(pid: int) -> bool:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return True
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"  # a zombie has stopped

    poll(lambda: all(gone(pid) for pid in agents.values()), lambda: f"agents left running: {agents}", START_WAIT_S)


def test_an_agent_that_cannot_start_is_named_with_its_reason(tmp_path: Path) -> None:
    with NodeProcesses(f"tcp/127.0.0.1:{free_tcp_port()}", tmp_path) as agents:
        agents.start({"sn9": "no-such-device"})
        poll(agents.dead, lambda: f"still running: {agents.status()}", START_WAIT_S)
        why = agents.dead()["sn9"]
    assert why.startswith("exited with code 2") and "unknown device spec" in why, why
    assert agents.alive() == []


@pytest.mark.parametrize("death_signal", [True, False], ids=["death-signal", "parent-watch-alone"])
def test_a_studio_killed_outright_leaves_no_agent(tmp_path: Path, death_signal: bool) -> None:
    """SIGKILL runs no cleanup: the kernel stops the agent (its parent-death signal), and without that signal the
    agent stops itself once its parent is gone."""
    parent = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\n"
         "from backend.services import node_processes\n"
         + ("" if death_signal else "node_processes._death_signal_prefix = lambda: []\n") +
         "agents = node_processes.NodeProcesses(sys.argv[1], sys.argv[2])\n"
         "agents.start({'sn1': 'sim-cell:sn1'})\n"
         "print(agents.agents['sn1'].process.pid, flush=True)\n"
         "time.sleep(120)\n", f"tcp/127.0.0.1:{free_tcp_port()}", str(tmp_path)],
        cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        agent = int(parent.stdout.readline())
        # Once the agent runs Python (setpriv has set its death signal and executed it), kill its parent.
        poll(lambda: b"backend.cli" in Path(f"/proc/{agent}/cmdline").read_bytes(),
             lambda: (tmp_path / "sn1.log").read_text(), START_WAIT_S)
    finally:
        parent.kill()
        parent.wait(timeout=10)

    def gone() -> bool:
        try:
            return Path(f"/proc/{agent}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
        except FileNotFoundError:
            return True

    # The signal may land while the agent still starts (its handler then lets it finish opening the device and
    # Zenoh first): allow it the start-up time of a loaded machine.
    poll(gone, f"agent {agent} outlived its killed parent", START_WAIT_S)
