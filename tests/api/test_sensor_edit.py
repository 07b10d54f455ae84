"""Editing the rig through the API: a sensor's mounting guess, parent, mount sigma and device changed (previewed
first), a sensor removed with what it captured and solved kept aside, and restored; the rig re-fitted and the
exports following each change; and the 4xx JSON of what cannot be done."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.transforms import from_xyz_ypr, to_xyz_ypr
from backend.sim.demo_rig import demo_rig
from backend.store.session import SessionStore
from tests.conftest import fresh_demo

S = "/api/sessions/demo"


def manual_pose() -> dict:
    """T_cam_front_lidar_top as a hand-set result would give it: the demo's mounting, 30 mm off in the camera's x."""
    T = demo_rig().T_a_b("cam_front", "lidar_top")
    xyz, ypr = to_xyz_ypr(T)
    return {"xyz_m": (xyz + [0.03, 0.0, 0.0]).tolist(), "ypr_deg": np.degrees(ypr).tolist()}


@pytest.fixture
def sessions(tmp_path: Path, demo_template: Path) -> Path:
    return fresh_demo(demo_template, tmp_path / "sessions")


@pytest.fixture
def client(sessions: Path) -> Iterator[TestClient]:
    app = create_app(sessions)
    with TestClient(app) as c:
        yield c
    app.state.studio.jobs.shutdown()


def frames(client: TestClient) -> dict[str, dict]:
    return {f["name"]: f for f in client.get(f"{S}/rig").json()["frames"]}


def error(response, status: int) -> dict:
    assert response.status_code == status, response.text
    return response.json()["error"]


def accept_manual_lidar_edge(client: TestClient) -> str:
    """A hand-set T_cam_front_lidar_top, accepted: the slot ``lidar_top/T_cam_front_lidar_top``."""
    response = client.post(f"{S}/lidar-camera/manual", json={"camera": "cam_front", "lidar": "lidar_top",
                                                              "pose": manual_pose()})
    assert response.status_code == 201, response.text
    result_id = response.json()["result_id"]
    assert client.post(f"{S}/accept", json={"result_id": result_id, "confirm": True}).status_code == 200
    return result_id


def test_a_new_mounting_guess_is_previewed_then_moves_the_sensor(client, sessions):
    assert client.post(f"{S}/sensors", json={"name": "imu0", "kind": "imu"}).status_code == 201
    session_file = (sessions / "demo" / "session.json").read_bytes()
    pose = {"xyz_m": [0.1, 0.02, 0.3], "ypr_deg": [90.0, 0.0, 0.0]}

    preview = client.patch(f"{S}/sensors/imu0", params={"preview": True}, json={"pose": pose})
    assert preview.status_code == 200, preview.text
    body = preview.json()
    assert body["applied"] is False and body["action"] == "edit"
    [move] = body["moves"]
    assert move["frame"] == "imu0" and move["trans_m"] == pytest.approx(np.linalg.norm([0.1, 0.02, 0.3]), abs=1e-9)
    assert move["rot_deg"] == pytest.approx(90.0, abs=1e-6)
    assert (sessions / "demo" / "session.json").read_bytes() == session_file, "a preview wrote the session"

    applied = client.patch(f"{S}/sensors/imu0", json={"pose": pose, "mount_sigma": [0.01, 1.0]})
    assert applied.status_code == 200 and applied.json()["applied"] is True
    imu = frames(client)["imu0"]
    np.testing.assert_allclose(imu["T_parent_child"], from_xyz_ypr(np.array([0.1, 0.02, 0.3]), np.radians([90, 0, 0])),
                               atol=1e-9)
    assert imu["mount_sigma"] == [0.01, 1.0]
    # the edit is on disk: a new store reads it
    reopened = SessionStore(sessions).get("demo").rig.get("imu0")
    assert reopened.mount_sigma == (0.01, 1.0)
    np.testing.assert_allclose(reopened.T_mount, imu["T_parent_child"], atol=1e-12)

    assert client.patch(f"{S}/sensors/imu0", json={"mount_sigma": None}).status_code == 200
    assert frames(client)["imu0"]["mount_sigma"] is None


def test_a_new_parent_keeps_the_sensor_where_it_is(client):
    pose = {"xyz_m": [0.2, 0.1, 0.5], "ypr_deg": [30.0, 5.0, 0.0]}
    for name, kind in (("mast", "frame"), ("imu0", "imu")):
        assert client.post(f"{S}/sensors", json={"name": name, "kind": kind, "pose": pose}).status_code == 201
    before = client.get(f"{S}/rig/tree").json()
    response = client.patch(f"{S}/sensors/imu0", json={"parent": "mast"})
    assert response.status_code == 200, response.text
    rig = SessionStore(client.app.state.studio.store.root).get("demo").rig
    assert rig.get("imu0").parent == "mast"
    np.testing.assert_allclose(rig.T_root_frame("imu0"), from_xyz_ypr(np.array([0.2, 0.1, 0.5]),
                                                                      np.radians([30.0, 5.0, 0.0])), atol=1e-9)
    assert before["frames"]["imu0"]["parent"] == "base_link"
    # the moved frame now comes after its new parent, so the session file still reads parents first
    assert list(rig.frames).index("imu0") > list(rig.frames).index("mast")


def test_edits_that_cannot_be_made_are_refused_and_change_nothing(client, sessions):
    assert client.post(f"{S}/sensors", json={"name": "mast", "kind": "frame"}).status_code == 201
    assert client.post(f"{S}/sensors", json={"name": "imu0", "parent": "mast", "kind": "imu"}).status_code == 201
    session_file = (sessions / "demo" / "session.json").read_bytes()

    cycle = error(client.patch(f"{S}/sensors/mast", json={"parent": "imu0"}), 422)
    assert cycle["input"] == "parent" and "'imu0' hangs below 'mast'" in cycle["message"]
    assert "cycle" in cycle["message"]
    itself = error(client.patch(f"{S}/sensors/mast", json={"parent": "mast"}), 422)
    assert "is the frame itself" in itself["message"]
    unknown = error(client.patch(f"{S}/sensors/mast", json={"parent": "nowhere"}), 422)
    assert unknown["input"] == "parent" and "'nowhere' is not in the rig" in unknown["message"]
    assert error(client.patch(f"{S}/sensors/ghost", json={"parent": "mast"}), 404)["input"] == "sensor"
    assert error(client.patch(f"{S}/sensors/mast", json={}), 422)["input"] == "body"
    assert error(client.patch(f"{S}/sensors/base_link", json={"mount_sigma": None}), 409)["input"] == "sensor"
    sigma = error(client.patch(f"{S}/sensors/mast", json={"mount_sigma": [0.0, 1.0]}), 422)
    assert "mount_sigma" in sigma["input"]
    nan = error(client.patch(f"{S}/sensors/mast", content='{"pose": {"xyz_m": [NaN, 0, 0]}}',
                             headers={"content-type": "application/json"}), 422)
    assert "xyz_m" in nan["input"]
    device = error(client.patch(f"{S}/sensors/mast", json={"device": {"driver": "nope"}}), 422)
    assert device["input"] == "device" and "unknown driver 'nope'" in device["message"]
    options = error(client.patch(f"{S}/sensors/mast", json={"device": {"driver": "uvc", "colour": 1}}), 422)
    assert options["input"] == "device" and "colour" in options["message"]
    added = error(client.post(f"{S}/sensors", json={"name": "cam9", "device": {"driver": "nope"}}), 422)
    assert added["input"] == "device"
    assert (sessions / "demo" / "session.json").read_bytes() == session_file


def test_removing_a_sensor_keeps_its_captures_and_results_aside_and_restores_them(client, sessions):
    result_id = accept_manual_lidar_edge(client)
    slot = "lidar_top/T_cam_front_lidar_top"
    captures = sorted(p.name for p in (sessions / "demo" / "captures" / "lidar_top").iterdir())
    assert captures, "the demo has lidar_top captures to keep"
    assert 'name="lidar_top"' in client.get(f"{S}/export/urdf").text
    tree_before = client.get(f"{S}/rig/tree").json()["frames"]

    preview = client.delete(f"{S}/sensors/lidar_top", params={"preview": True})
    assert preview.status_code == 200, preview.text
    assert preview.json()["emptied"] == [slot] and preview.json()["applied"] is False
    assert "lidar_top" in frames(client)

    removed = client.delete(f"{S}/sensors/lidar_top")
    assert removed.status_code == 200, removed.text
    body = removed.json()
    assert body["emptied"] == [slot] and body["removal"]["id"] == "lidar_top-1"
    assert "lidar_top" not in body["rig"]["frames"] and "lidar_top" not in frames(client)
    info = client.get(S).json()
    assert slot not in info["accepted"] and "lidar_top" not in info["sensors"]
    assert info["acceptance_log"][-1] | {"at": 0} == {"slot": slot, "result_id": None, "at": 0, "verdict": None,
                                                      "confirmed": False, "note": "lidar_top removed (lidar_top-1)"}
    [listed] = client.get(f"{S}/removed").json()
    assert listed["sensor"] == "lidar_top" and listed["captures"] == len(captures) // 2
    assert result_id in listed["results"] and listed["slots"] == {slot: result_id}
    # kept aside, not deleted; the results stay readable by id, but no listing shows them
    assert sorted(p.name for p in (sessions / "demo" / "removed" / "lidar_top-1" / "captures").iterdir()) == captures
    assert not (sessions / "demo" / "captures" / "lidar_top").exists()
    assert client.get(f"{S}/results/{result_id}").status_code == 200
    assert result_id not in [r["id"] for r in client.get(f"{S}/results").json()]
    assert 'name="lidar_top"' not in client.get(f"{S}/export/urdf").text
    assert "<td>emptied</td>" in (report := client.get(f"{S}/report").text)
    assert "lidar_top removed (lidar_top-1)" in report

    restored = client.post(f"{S}/removed/lidar_top-1/restore")
    assert restored.status_code == 200, restored.text
    assert restored.json()["restored"] == [slot] and restored.json()["not_restored"] == {}
    assert client.get(S).json()["accepted"][slot] == result_id
    assert sorted(p.name for p in (sessions / "demo" / "captures" / "lidar_top").iterdir()) == captures
    assert client.get(f"{S}/removed").json() == []
    assert 'name="lidar_top"' in client.get(f"{S}/export/urdf").text
    tree_after = client.get(f"{S}/rig/tree").json()["frames"]
    assert tree_after.keys() == tree_before.keys()
    for name, frame in tree_before.items():
        np.testing.assert_allclose(tree_after[name]["T_parent_child"], frame["T_parent_child"], atol=1e-9)
    again = error(client.post(f"{S}/removed/lidar_top-1/restore"), 409)
    assert "restored already" in again["message"]


def test_a_sensor_others_hang_from_is_not_removed(client, sessions):
    assert client.post(f"{S}/sensors", json={"name": "imu0", "parent": "cam_front", "kind": "imu"}).status_code == 201
    refused = error(client.delete(f"{S}/sensors/cam_front"), 409)
    assert "'imu0' hangs from it" in refused["message"] and refused["input"] == "sensor"
    assert "cam_front" in frames(client) and (sessions / "demo" / "captures" / "cam_front").is_dir()
    assert error(client.delete(f"{S}/sensors/base_link"), 409)["input"] == "sensor"
    assert error(client.delete(f"{S}/sensors/ghost"), 404)["input"] == "sensor"
    assert error(client.post(f"{S}/removed/ghost-1/restore"), 404)["input"] == "removal"


def test_a_restore_never_takes_a_name_or_a_slot_that_is_taken(client):
    accept_manual_lidar_edge(client)
    assert client.delete(f"{S}/sensors/lidar_top").status_code == 200
    assert client.post(f"{S}/sensors", json={"name": "lidar_top", "kind": "lidar3d"}).status_code == 201
    taken = error(client.post(f"{S}/removed/lidar_top-1/restore"), 409)
    assert "a frame of that name is in the rig now" in taken["message"]
    # the new lidar_top starts with no captures and none of the removed one's results
    assert client.get(f"{S}/results", params={"sensor": "lidar_top"}).json() == []
    assert client.delete(f"{S}/sensors/lidar_top").status_code == 200
    assert [r["id"] for r in client.get(f"{S}/removed").json()] == ["lidar_top-1", "lidar_top-2"]

    # cam_front's removal empties its intrinsics: restoring lidar_top then cannot bring back its edge to cam_front
    assert client.delete(f"{S}/sensors/cam_front").status_code == 200
    restored = client.post(f"{S}/removed/lidar_top-1/restore").json()
    assert restored["restored"] == []
    assert restored["not_restored"] == {"lidar_top/T_cam_front_lidar_top": "the rig no longer holds cam_front"}


def test_removing_a_sensor_previews_the_frames_its_edges_held(client):
    """The hand-set edge cam_front -> lidar_top (sigma 5 mm, 0.3 deg) pulls cam_front off its tape-measured mounting
    guess (sigma 50 mm, 5 deg) towards lidar_top, whose mounting is the drawing's; removing lidar_top drops the edge,
    and cam_front goes back to its guess: the preview says so first."""
    accept_manual_lidar_edge(client)
    rig = client.app.state.studio.store.get("demo").rig
    held = rig.get("cam_front").T_parent_child.copy()
    guess = rig.get("cam_front").T_mount.copy()
    expected_m = float(np.linalg.norm(held[:3, 3] - guess[:3, 3]))
    assert expected_m > 0.01, "the hand-set edge moved cam_front"

    preview = client.delete(f"{S}/sensors/lidar_top", params={"preview": True}).json()
    assert preview["emptied"] == ["lidar_top/T_cam_front_lidar_top"]
    moves = {m["frame"]: m for m in preview["moves"]}
    assert moves["cam_front"]["trans_m"] == pytest.approx(expected_m, rel=1e-6)
    assert client.delete(f"{S}/sensors/lidar_top").json()["moves"] == preview["moves"]
    np.testing.assert_allclose(frames(client)["cam_front"]["T_parent_child"], guess, atol=1e-9)
