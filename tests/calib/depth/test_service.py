"""The depth-network service on the simulated cell: the automatic solve of all six nodes against the truth, the
verification of the laser-measured cross distances, the merged map, the pick, the pose table and its export, the
report's section, and bad input (empty depth, unknown tables, a broken depth_network.json).

The session is built once for the module: six nodes at the paper's poses, each seen with its tables behind each
other and beside each other (H1's simulator, rendered directly), typed poses off by 4-5 cm and 1-2 deg.
"""

from __future__ import annotations

import csv
import io
import shutil
from pathlib import Path

import numpy as np
import pytest

from backend.calib.depth import guided_service as depth_guided
from backend.calib.depth import service
from backend.core.depth import pose_from_row
from backend.core.depth_cell import PAPER_NODE_POSES, default_cell_layout
from backend.core.errors import InputError
from backend.core.rig import Frame
from backend.devices.base import Sample
from backend.services.exports import export_text
from backend.services.report import render_report
from backend.store.session import Session
from tests.calib.depth.conftest import (
    build_cell_session,
    frame_sample,
    pose_error,
    render_captures,
    typed_pose,
)


@pytest.fixture(scope="module")
def solved(tmp_path_factory: pytest.TempPathFactory) -> tuple[Session, dict]:
    session = build_cell_session(tmp_path_factory.mktemp("depth") / "cell", list(PAPER_NODE_POSES))
    return session, service.solve_network(session)


@pytest.mark.slow
def test_the_automatic_solve_recovers_every_node(solved) -> None:
    session, outcome = solved
    assert outcome["problems"] == [] and sorted(outcome["results"]) == sorted(PAPER_NODE_POSES)
    assert len(outcome["accepted"]) == 6
    summary = service.network_summary(session)
    for node, entry in summary["nodes"].items():
        trans_m, rot_deg = pose_error(entry["T_world_node"], node)
        assert trans_m < 0.005 and rot_deg < 0.05, (node, trans_m, rot_deg)  # the 5 mm and 0.05 deg
        record = session.result(entry["result_id"])
        assert (record["kind"], record["parent"], record["child"]) == ("depth_node", "world", node)
        assert entry["verdict"] == record["verdict"] and entry["verdict"]["level"] != "reject"
        assert all(0 < s < 0.005 for s in entry["std"]["trans_m"]), entry["std"]
    assert summary["problems"] == []


@pytest.mark.slow
def test_the_verification_distances_are_within_10_mm(solved) -> None:
    session, _ = solved
    rows = service.verify_layout_distances(session)
    layout = default_cell_layout()
    assert [(r["a"], r["b"]) for r in rows] == [(d.a, d.b) for d in layout.distances]
    for row in rows:
        assert abs(row["error_m"]) < 0.010, row
        assert row["estimated_m"] == pytest.approx(row["measured_m"] + row["error_m"])
    assert [r["a"] for r in service.network_summary(session)["verification"]] == [r["a"] for r in rows]
    assert service.verify_layout_distances(session) == []  # each distance once
    for target in service.detected_crosses(session):  # every cross, averaged over the nodes that see it whole
        assert np.linalg.norm(np.subtract(target["point_m"], layout.cross(target["name"]).position_m)) < 0.008


@pytest.mark.slow
def test_the_merged_map_and_a_pick(solved) -> None:
    session, _ = solved
    voxel_map = service.merged_voxel_map(session, voxel_m=0.04)
    clouds = service.world_clouds(session)
    assert voxel_map.counts.sum() == sum(len(points) for points, _ in clouds.values())
    assert set(np.unique(voxel_map.node_index)) == set(range(6))
    assert np.allclose(np.mod(voxel_map.centres_m, 0.04), 0.02, atol=1e-6)
    floor = np.abs(np.abs(voxel_map.centres_m[:, 2]) - 0.02) < 1e-6  # the voxels either side of z = 0
    assert voxel_map.counts[floor].sum() > 0.5 * voxel_map.counts.sum()  # most of what the nodes see is floor
    cross = default_cell_layout().cross("robot_a1")
    picked = service.pick(session, [cross.position_m[0] + 0.05, cross.position_m[1], 3.0], [0, 0, -1])
    assert picked["kind"] == "cross" and picked["name"] == "robot_a1"
    assert np.linalg.norm(np.subtract(picked["point_m"], cross.position_m)) < 0.008
    on_arm = np.add(cross.position_m, [0.25, 0.0, 0.0])  # beyond the snap to its centre, on the floor
    point = service.pick_point(session, on_arm + [0.0, 0.0, 3.0], [0.0, 0.0, -1.0])
    assert np.allclose(point, on_arm, atol=0.05)
    with pytest.raises(InputError, match="misses every node"):
        service.pick(session, on_arm + [0.0, 0.0, 3.0], [0.0, 0.0, 1.0])


@pytest.mark.slow
def test_a_depth_capture_reads_as_a_cloud_like_any_range_sensor(solved) -> None:
    session, _ = solved
    [record, *_] = service.captures(session, "sn2")
    points, amplitude = session.capture_cloud("sn2", record.id)  # as the LiDAR steps read a capture
    depth, stored_amplitude = session.depth_capture("sn2", record.id)
    assert points.shape == (record.n_points, 3) and amplitude.shape == (record.n_points,)
    assert np.allclose(np.sort(points[:, 2]), np.sort(depth[depth > 0]), atol=1e-6)  # Z is the stored depth
    assert np.isclose(np.sort(amplitude), np.sort(stored_amplitude[depth > 0])).all()


@pytest.mark.slow
def test_the_pose_table_export_and_report(solved) -> None:
    session, _ = solved
    summary = service.network_summary(session)
    text = service.pose_table_text(summary)
    lines = text.splitlines()
    assert lines[0].split()[:7] == ["node", "X", "[m]", "Y", "[m]", "Z", "[m]"]
    assert [line.split()[0] for line in lines[1:7]] == [f"sn{i}" for i in range(1, 7)]
    name, csv_text = export_text(session, "pose-table")
    assert name.endswith("_pose_table.csv")
    rows = list(csv.DictReader(io.StringIO(csv_text)))
    for row, table_row in zip(rows, summary["pose_table"], strict=True):
        assert row["node"] == table_row["node"]
        assert float(row["RotX_deg"]) == pytest.approx(table_row["RotX"], abs=1e-3)
        assert float(row["X_m"]) == pytest.approx(table_row["X"], abs=1e-4)
    for fmt in ("rig", "urdf", "launch"):  # the rig exports on a rig rooted at world
        _, exported = export_text(session, fmt)
        assert "world" in exported and all(node in exported for node in PAPER_NODE_POSES), fmt
    html = render_report(session)
    assert "Depth network" in html and "gantry_a1" in html and "sn6" in html


@pytest.mark.slow
def test_bad_input_is_refused_and_nothing_is_lost(solved, tmp_path: Path) -> None:
    session, _ = solved
    before = len(session.captures("sn1"))
    empty = Sample(0.0, depth=np.zeros((424, 512), np.float32))
    with pytest.raises(InputError, match="no return within"):
        service.capture_node(session, "sn1", empty)
    with pytest.raises(InputError, match="no table named 'table9'"):
        service.capture_node(session, "sn1", frame_sample(render_captures("sn1", 0)[0][2]), "behind", ["table9"])
    with pytest.raises(InputError, match="expected 512x424"):
        service.capture_node(session, "sn1", Sample(0.0, depth=np.ones((10, 10), np.float32)))
    assert len(session.captures("sn1")) == before
    with pytest.raises(InputError, match="not a depth node"):
        service.capture_node(session, "world", empty)
    robot = Session.create(tmp_path / "robot", "robot")
    robot.add_sensor(Frame("lidar", "base_link", kind="lidar3d"))
    with pytest.raises(InputError, match="a depth node hangs under the cell's 'world' frame"):
        service.add_node(robot, "sn1", typed_pose("sn1"))

    shutil.copytree(session.path, tmp_path / "copy")
    copy = Session.load(tmp_path / "copy")
    (copy.path / "depth_network.json").write_text("{broken")
    summary = service.network_summary(copy)
    assert len(summary["nodes"]) == 6 and summary["verification"] == []  # the poses stand; the table is gone
    assert any("depth_network.json" in p and "quarantine" in p for p in summary["problems"]), summary["problems"]
    assert (copy.path / "quarantine" / "depth_network.json").read_text() == "{broken"
    assert [q["file"] for q in copy.quarantined()] == ["depth_network.json"]
    assert service.network_summary(copy)["problems"] == []  # afresh after the quarantine
    service.capture_node(copy, "sn1", frame_sample(render_captures("sn1", 0)[0][2]), clock_offset_s=3.0)
    assert "sn1: its clock is +3.00 s off the studio's (capture 00003)" in service.network_summary(copy)["problems"][0]


def test_a_guided_pose_the_captures_cannot_solve_keeps_the_hand_set_sigma(tmp_path: Path) -> None:
    session = Session.create(tmp_path / "bare", "bare")
    service.add_node(session, "sn1", typed_pose("sn1"))
    covariance, basis = depth_guided._least_squares_check(session, "sn1", pose_from_row(typed_pose("sn1")))
    assert basis == {"problem": "no least-squares solve of the same captures (node sn1: no captures to solve from; "
                                "capture the node first); sigma assumed 5 mm, 0.3 deg"}
    assert np.allclose(np.sqrt(np.diag(covariance)), [0.005] * 3 + [np.radians(0.3)] * 3)
