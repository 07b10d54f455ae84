"""Capture across computers: six node-agent processes of the simulated cell on 127.0.0.1, one studio NodeNetwork.

One module-scoped network, secured as a user sets it up (``calib-studio node-keys``: mutual TLS and access
control), and six agent processes (``python -m studio.cli node ... --device sim-cell:snK --keys snK.keys.pem``);
two more agents run in this process (``run_agent`` in threads) serving a test cloud of 1 MB and of 10 MB (random,
so it does not compress) with a clock 12.4 s ahead. The security tests start more agent processes: one with
another network's keys, one claiming a name already held, one whose device changes.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from backend.core.depth import KINECT_V2, pose_from_row
from backend.core.depth_cell import PAPER_NODE_POSES, TablePlacement
from backend.core.errors import InputError
from backend.core.transforms import transform_points
from backend.devices import base
from backend.devices.base import CaptureDevice, DeviceError, Sample, create_device
from backend.devices.device_spec import parse_device_spec
from backend.devices.node_agent import node_key, open_session, run_agent
from backend.devices.node_keys import NetworkKeys, load_network_keys, read_bundle
from backend.devices.node_network import NodeNetwork
from studio.cli import main as cli_main
from tests.conftest import ROOT, poll

ROOT = ROOT
NODES = [f"sn{i}" for i in range(1, 7)]
CLOCK_AHEAD_S = 12.4
BIG_POINTS = {"big1": 70_000, "big10": 700_000}
"""Points of each in-process test cloud: about 1 MB and 10 MB of frame (14.5 bytes a point, incompressible)."""
SPARE = "spare"
"""A node the network's keys admit that no agent runs as until a test starts one."""


class NoiseCloud(CaptureDevice):
    """A test LiDAR: ``points`` random points in a 100 m cube (fixed per seed), 10 reads a second at most.

    Registered only while the module's ``cell`` fixture runs, so other modules see the built-in drivers alone.
    """

    driver = "test_noise_cloud"

    def __init__(self, points: int, seed: int = 0):
        self.points, self.seed = points, seed

    def open(self) -> None:
        rng = np.random.default_rng(self.seed)
        self.cloud = rng.uniform(-50, 50, (self.points, 3))
        self.intensity = rng.uniform(0, 255, self.points).astype(np.float32)

    def read(self) -> Sample:
        time.sleep(0.1)
        return Sample(time.time(), points=self.cloud, intensity=self.intensity, meta={"seed": self.seed})

    def close(self) -> None:
        pass


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def ready(network: NodeNetwork, names: list[str]) -> bool:
    """Every node present, its info and clock offset in."""
    status = {s.name: s for s in network.nodes()}
    return all(n in status and status[n].alive and status[n].kind and status[n].clock_offset_s is not None
               for n in names)


def make_keys(folder, nodes: list[str]) -> NetworkKeys:
    """A network's keys made as the README says (``calib-studio node-keys DIR --nodes ...``)."""
    assert cli_main(["node-keys", str(folder), "--nodes", ",".join(nodes)]) == 0
    return load_network_keys(folder)


def start_agent(name: str, device: str, endpoint: str, keys_file=None) -> subprocess.Popen:
    """A node-agent process as a node's computer runs it."""
    command = [sys.executable, "-m", "studio.cli", "node", "--name", name, "--device", device, "--connect", endpoint,
               "--rate", "0.5"]
    return subprocess.Popen(command + ([] if keys_file is None else ["--keys", str(keys_file)]), cwd=ROOT,
                            stderr=subprocess.PIPE, text=True)


@pytest.fixture(scope="module")
def cell(tmp_path_factory) -> Iterator[tuple[NodeNetwork, dict[str, subprocess.Popen]]]:
    with pytest.MonkeyPatch.context() as patch:
        patch.setitem(base._DRIVERS, NoiseCloud.driver, NoiseCloud)
        yield from _cell(tmp_path_factory.mktemp("keys") / "network")


def _cell(keys_dir) -> Iterator[tuple[NodeNetwork, dict[str, subprocess.Popen]]]:
    keys = make_keys(keys_dir, [*NODES, *BIG_POINTS, SPARE])
    endpoint = f"tls/127.0.0.1:{free_port()}"
    network = NodeNetwork(listen=[endpoint], keys=keys)
    network.open()
    agents = {name: start_agent(name, f"sim-cell:{name}", endpoint, keys.bundle_path(name)) for name in NODES}
    stop = threading.Event()
    threads = [threading.Thread(target=run_agent, daemon=True, kwargs=dict(
        name=name, device=f'{{"driver": "test_noise_cloud", "points": {points}}}', connect=[endpoint], rate_hz=0.2,
        voxel_m=None, stop=stop, clock=lambda: time.time() + CLOCK_AHEAD_S, keys=read_bundle(keys.bundle_path(name))))
        for name, points in BIG_POINTS.items()]
    for thread in threads:
        thread.start()
    try:
        poll(lambda: ready(network, NODES + list(BIG_POINTS)), "eight nodes never all came", 90)
        yield network, agents
    finally:
        stop.set()
        for agent in agents.values():
            if agent.poll() is None:
                agent.send_signal(signal.SIGTERM)
        codes = {name: agent.wait(20) for name, agent in agents.items()}
        for thread in threads:
            thread.join(10)
        network.close()
    # every agent not killed by a test ended cleanly on SIGTERM
    assert all(code in (0, -signal.SIGKILL) for code in codes.values()), codes


@pytest.mark.slow
def test_presence_lists_every_node_with_its_info(cell) -> None:
    network, _ = cell
    status = {s.name: s for s in network.nodes()}
    assert {name for name, s in status.items() if s.alive} >= set(NODES)
    for name in NODES:
        assert status[name].kind == "depth" and status[name].device == f"sim-cell:{name}"
        assert status[name].info["intrinsics"] == KINECT_V2.to_dict()
        assert abs(status[name].clock_offset_s) <= status[name].clock_rtt_s / 2 + 1e-4  # one host: truth 0
    assert status["big1"].kind == "lidar"


@pytest.mark.slow
def test_capture_from_all_six(cell) -> None:
    network, _ = cell
    assert network.set_sim_placements([TablePlacement("table1", (9.0, 1.5))]) == NODES
    with pytest.raises(InputError, match="node sn1: table placements refused: .*table9") as refused:
        network.set_sim_placements([TablePlacement("table9", (9.0, 1.5))])
    assert refused.value.input == "placements"
    frames, failures = network.capture_all(NODES)
    assert failures == {} and sorted(frames) == NODES
    for name, frame in frames.items():
        assert frame.depth.shape == (KINECT_V2.height, KINECT_V2.width)
        index = frame.meta["pixel_index"]  # the node's valid pixels; their points at their depth (mm steps)
        np.testing.assert_allclose(frame.points[:, 2], frame.depth.ravel()[index], atol=1e-6)
        np.testing.assert_array_equal(frame.intensity, frame.meta["amplitude"].ravel()[index])
        # ground truth: in the world frame of the node's true pose, the floor is at z = 0
        z_world = transform_points(pose_from_row(PAPER_NODE_POSES[name]), frame.points)[:, 2]
        assert np.mean(np.abs(z_world) < 0.03) > 0.3, name
        assert frame.meta["node"] == name and abs(frame.meta["studio_time_s"] - time.time()) < 30
        assert [p["table"] for p in frame.meta["placements"]] == ["table1"]


@pytest.mark.slow
def test_streams_show_bandwidth_and_a_preview(cell) -> None:
    network, _ = cell
    poll(lambda: all(s.frames >= 2 for s in network.nodes() if s.name in NODES), "not two streamed frames each")
    status = {s.name: s for s in network.nodes()}
    for name in NODES:
        assert 20_000 < status[name].bandwidth_bps < 5_000_000  # ~0.35 MB frames at 0.5 Hz
        preview = network.latest_preview(name)
        assert preview.meta["voxel_m"] == 0.02 and 1000 < len(preview.points) < 217_088


@pytest.mark.slow
def test_one_and_ten_megabyte_payloads_arrive_intact(cell) -> None:
    network, _ = cell
    for name, points in BIG_POINTS.items():
        rng = np.random.default_rng(0)
        truth = rng.uniform(-50, 50, (points, 3))
        frame = network.capture(name, timeout_s=30)  # query/reply
        assert np.abs(frame.points - truth).max() <= 0.00005 + 1e-9
        poll(lambda n=name: network.latest_preview(n) is not None, f"no streamed frame of {name}")
        streamed = network.latest_preview(name)  # publish/subscribe, full frames (voxel_m None)
        assert len(streamed.points) == points and np.abs(streamed.points - truth).max() <= 0.00005 + 1e-9
        assert next(s for s in network.nodes() if s.name == name).dropped == 0


@pytest.mark.slow
def test_a_skewed_clock_is_estimated_within_half_its_round_trip(cell) -> None:
    network, _ = cell
    estimate = network.estimate_clock("big1")
    # the bound the estimate states (its round trip is the machine's load: benchmarks/ measures it)
    assert abs(estimate.offset_s - CLOCK_AHEAD_S) <= estimate.rtt_s / 2 + 1e-6, estimate
    assert estimate.warning == "node big1's clock is 12.4 s ahead"
    frame = network.capture("big1", timeout_s=30)
    assert abs(frame.meta["studio_time_s"] - time.time()) < 5  # the node's stamp brought onto the studio's clock


@pytest.mark.slow
def test_a_node_killed_mid_capture_is_named_and_the_rest_kept(cell, monkeypatch) -> None:
    network, agents = cell
    victim = agents["sn6"]
    victim.send_signal(signal.SIGSTOP)  # it can no longer answer: the capture waits on it
    asked = threading.Event()  # the capture has found sn6 on the network: its request goes out next
    require_node = network._require_node

    def require_and_tell(node: str):
        session = require_node(node)
        if node == "sn6":
            asked.set()
        return session

    monkeypatch.setattr(network, "_require_node", require_and_tell)
    result: dict = {}
    capture = threading.Thread(target=lambda: result.update(
        zip(("frames", "failures"), network.capture_all(NODES, timeout_s=20), strict=True)))
    capture.start()
    poll(asked.is_set, "the capture never asked sn6")
    victim.kill()
    capture.join(30)
    assert sorted(result["frames"]) == NODES[:5]
    assert result["failures"] == {"sn6": "node sn6 disappeared during the capture"}
    poll(lambda: not next(s for s in network.nodes() if s.name == "sn6").alive, "sn6 still listed alive")
    with pytest.raises(InputError, match=r"node sn6 left the network .* ago") as gone:
        network.capture("sn6")
    assert gone.value.input == "sn6"
    present = "big1, big10, sn1, sn2, sn3, sn4, sn5"
    with pytest.raises(InputError, match=f"node sn9 is not on the network; nodes present: {present}$"):
        network.capture("sn9")


def test_bad_device_spec_or_endpoint_is_one_line_and_exit_2(capsys: pytest.CaptureFixture[str]) -> None:
    for args, message in ((["--device", "kinect3"], "unknown device spec 'kinect3'; expected one of sim-cell:NODE"),
                          (["--device", "sim-cell:sn1", "--connect", "udp:nowhere"],
                           "connect: endpoint 'udp:nowhere': expected PROTOCOL/ADDRESS")):
        assert cli_main(["node", "--name", "sn1", *args]) == 2
        stderr = capsys.readouterr().err
        assert len(stderr.strip().splitlines()) == 1 and message in stderr, stderr


def test_device_specs() -> None:
    assert parse_device_spec("sim-cell:sn1") == {"driver": "sim_depth", "node": "sn1"}
    assert parse_device_spec("kinect2") == {"driver": "kinect2"}
    assert parse_device_spec("realsense:0123") == {"driver": "realsense", "serial": "0123"}
    assert parse_device_spec("depth-files:/data/sn1") == {"driver": "depth_files", "path": "/data/sn1"}
    assert parse_device_spec('{"driver": "velodyne", "port": 2368}') == {"driver": "velodyne", "port": 2368}
    for bad, message in (("kinect3", "unknown device spec 'kinect3'"), ("sim-cell:", "lacks its node"),
                         ("{nope", "not valid JSON"), ('{"port": 1}', 'naming its "driver"')):
        with pytest.raises(InputError, match=message) as error:
            parse_device_spec(bad)
        assert error.value.input == "device"


@pytest.mark.slow
def test_a_node_is_a_rig_sensor_through_the_node_driver(cell) -> None:
    with create_device({"driver": "node", "node": "sn2"}) as device:  # the studio's open network
        sample = device.read()
    assert sample.depth.shape == (KINECT_V2.height, KINECT_V2.width) and sample.meta["node"] == "sn2"
    assert sample.timestamp_s == sample.meta["studio_time_s"]
    with pytest.raises(DeviceError, match="node sn7 did not appear within 0.2 s; nodes present: big1"):
        create_device({"driver": "node", "node": "sn7", "timeout_s": 0.2}).open()


def floor_fraction(node: str, frame: Sample) -> float:
    """The share of the frame's points on the floor (|z| < 3 cm) when placed at ``node``'s true pose: high only for
    that node's own view."""
    z_world = transform_points(pose_from_row(PAPER_NODE_POSES[node]), frame.points)[:, 2]
    return float(np.mean(np.abs(z_world) < 0.03))


def finished(agent: subprocess.Popen, timeout_s: float = 60) -> tuple[int, str]:
    """The agent's exit code and stderr, once it has exited by itself."""
    poll(lambda: agent.poll() is not None, "the agent did not exit", timeout_s)
    return agent.returncode, agent.stderr.read()


def log_line(agent: subprocess.Popen, text: str, timeout_s: float = 60) -> str:
    """The agent's first stderr line holding ``text`` (read as it comes)."""
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(agent.stderr.readline, "")), daemon=True)
    reader.start()
    return poll(lambda: next((line for line in lines if text in line), None), lambda: f"no '{text}' in {lines}",
                timeout_s)


def stopped(agent: subprocess.Popen) -> None:
    agent.terminate()
    assert agent.wait(20) == 0


@pytest.mark.slow
def test_a_node_without_the_networks_keys_never_joins(cell, tmp_path) -> None:
    network, _ = cell
    endpoint = network.listen[0]
    other = make_keys(tmp_path / "other", ["intruder"])  # keys of another network: TLS refuses them
    intruder = start_agent("intruder", "sim-cell:sn3", endpoint, other.bundle_path("intruder"))
    plain = start_agent("plain", "sim-cell:sn3", endpoint.replace("tls/", "tcp/"))  # no keys at all
    try:
        for agent in (intruder, plain):
            assert "no link after 5 s" in log_line(agent, "no link after")
        spare = start_agent(SPARE, "sim-cell:sn3", endpoint, network.keys.bundle_path(SPARE))  # the control
        try:
            poll(lambda: ready(network, [SPARE]), "the node with the network's keys did not join")
        finally:
            stopped(spare)
        assert {s.name for s in network.nodes()}.isdisjoint({"intruder", "plain"})
    finally:
        stopped(intruder)
        stopped(plain)


@pytest.mark.slow
def test_a_node_cannot_speak_under_another_nodes_name(cell, capsys) -> None:
    network, _ = cell
    endpoint = network.listen[0]
    spare_keys = network.keys.bundle_path(SPARE)
    assert cli_main(["node", "--name", "sn1", "--device", "sim-cell:sn3", "--connect", endpoint,
                     "--keys", str(spare_keys)]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: keys: spare.keys.pem holds node spare's keys; this node is named sn1 (each node joins with the keys "
        "issued for its name)")
    # a peer that skips that check: admitted with spare's keys, it claims sn1 too; the studio's access control
    # lets through only what it says as spare
    session = open_session([], [endpoint], "connect", read_bundle(spare_keys))
    zid = str(session.zid())
    tokens = []
    try:
        tokens += [session.liveliness().declare_token(node_key(name, zid, "alive")) for name in (SPARE, "sn1")]
        session.put(node_key("sn1", zid, "frames"), b"spoofed")
        poll(lambda: any(s.name == SPARE and s.alive for s in network.nodes()), "spare's own token never came")
        sn1 = next(s for s in network.nodes() if s.name == "sn1")
        assert sn1.alive and sn1.zid != zid and sn1.refused == [] and sn1.warnings == []
        frame = network.capture("sn1")
        assert floor_fraction("sn1", frame) > 0.3  # still sn1's own view
    finally:
        for token in tokens:
            token.undeclare()
        session.close()


@pytest.mark.slow
def test_a_second_agent_under_a_held_name_is_refused(cell) -> None:
    network, _ = cell
    held_by = next(s.zid for s in network.nodes() if s.name == "sn2")
    second = start_agent("sn2", "sim-cell:sn4", network.listen[0], network.keys.bundle_path("sn2"))
    code, stderr = finished(second)
    assert code == 2 and stderr.strip().splitlines()[-1].startswith(
        "error: name: the studio refused node sn2: another agent (Zenoh id "), stderr
    assert "claims node name sn2, held since" in stderr and f"by {held_by}: refused" in stderr
    sn2 = next(s for s in network.nodes() if s.name == "sn2")
    assert sn2.zid == held_by and sn2.alive
    assert any("claims node name sn2" in warning for warning in sn2.warnings)  # named in presence
    assert floor_fraction("sn2", network.capture("sn2")) > 0.3


@pytest.mark.slow
def test_a_node_back_with_another_device_is_held_until_confirmed(cell) -> None:
    network, _ = cell
    endpoint, keys_file = network.listen[0], network.keys.bundle_path(SPARE)
    first = start_agent(SPARE, "sim-cell:sn3", endpoint, keys_file)  # as it first came in this module
    try:
        poll(lambda: ready(network, [SPARE]), "spare did not come")
    finally:
        stopped(first)
    poll(lambda: not network.is_alive(SPARE), "spare still listed alive")
    second = start_agent(SPARE, "sim-cell:sn2", endpoint, keys_file)
    try:
        status = poll(lambda: next((s for s in network.nodes() if s.name == SPARE and s.alive and s.held), None),
                      "the changed device was not held")
        assert status.held == ("node spare's device changed from sim-cell:sn3 (sim_depth sn3) to sim-cell:sn2 "
                               "(sim_depth sn2): its captures wait until you confirm the change")
        with pytest.raises(InputError, match="its captures wait until you confirm") as held:
            network.capture(SPARE)
        assert held.value.status_code == 409
        assert network.confirm_device(SPARE).held is None
        assert floor_fraction("sn2", network.capture(SPARE)) > 0.3
    finally:
        stopped(second)


@pytest.mark.slow
def test_a_frame_over_the_limit_is_refused_and_named(cell, monkeypatch) -> None:
    network, _ = cell
    monkeypatch.setenv("CALIB_MAX_NODE_FRAME_MB", "5")
    with pytest.raises(InputError, match=r"^node big10 sent a [\d,]+-byte frame: over the 5 MB limit on a node's "
                                         r"frame \(CALIB_MAX_NODE_FRAME_MB\); nothing of it is kept$") as refused:
        network.capture("big10", timeout_s=30)
    assert refused.value.status_code == 413
