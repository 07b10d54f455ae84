"""Importing recordings as captures: a ROS 2 bag's PointCloud2 and LaserScan topics (sqlite3 and MCAP),
time windows, every n-th scan, limits, a folder of cloud files with a corrupt one, bad input that leaves
the session unchanged, and the API (topics listing, import job, errors)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from rosbags.rosbag2 import StoragePlugin

from backend.api.app import create_app
from backend.core.errors import InputError
from backend.services import recordings
from backend.sim.demo_rig import demo_rig
from backend.store.session import Session, SessionStore
from tests.conftest import wait_job
from tests.devices.test_rosbag_source import CLOUD_XYZ, write_bag


@pytest.fixture(scope="module", params=[StoragePlugin.SQLITE3, StoragePlugin.MCAP], ids=["sqlite3", "mcap"])
def bag(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_bag(tmp_path_factory.mktemp("bags") / "rig", request.param)


@pytest.fixture
def session(tmp_path: Path) -> Session:
    return SessionStore(tmp_path / "sessions").create("rec", rig=demo_rig())


def rosbag(bag: Path, topic: str, **window: float) -> dict:
    return {"driver": "rosbag", "path": str(bag), "topic": topic, **window}


def test_a_bag_topic_becomes_captures_point_for_point(bag, session):
    summary = recordings.import_recording(session, "lidar_top", rosbag(bag, "/lidar/points"))
    assert len(summary.added) == 3 and summary.complete and summary.skipped == []
    assert "end of bag after 3 messages on /lidar/points" in summary.ended
    for k, capture in enumerate(session.captures("lidar_top")):
        points, _ = session.capture_cloud("lidar_top", capture.id)
        expected = CLOUD_XYZ[k][np.isfinite(CLOUD_XYZ[k]).all(axis=1)]
        np.testing.assert_allclose(points, expected, atol=1e-6)
        assert capture.source == f"/lidar/points #{k}" and capture.meta["topic"] == "/lidar/points"


@pytest.mark.slow
def test_window_every_and_limit(bag, session):
    assert len(recordings.import_recording(session, "lidar_top", rosbag(bag, "/lidar/points", start_s=0.05,
                                                                         end_s=0.2)).added) == 2
    every = recordings.import_recording(session, "lidar_top", rosbag(bag, "/lidar/points"), every=2)
    assert [session.captures("lidar_top")[-i].source for i in (2, 1)] == ["/lidar/points #0", "/lidar/points #2"]
    assert len(every.added) == 2
    limited = recordings.import_recording(session, "lidar_top", rosbag(bag, "/lidar/points"), limit=1)
    assert len(limited.added) == 1 and "limit of 1" in limited.ended
    scans = recordings.import_recording(session, "scanner_2d", rosbag(bag, "/scan"))
    assert len(scans.added) == 2 and session.captures("scanner_2d")[0].n_points > 0


def test_bad_recordings_leave_the_session_unchanged(bag, session, tmp_path):
    cases = [
        (rosbag(bag, "/cam/mono"), "lidar_top", "holds no point cloud", "topic"),
        (rosbag(bag, "/no/such/topic"), "lidar_top", "has no topic '/no/such/topic'", str(bag)),
        (rosbag(tmp_path / "missing.mcap", "/points"), "lidar_top", "does not exist", str(tmp_path / "missing.mcap")),
        ({"driver": "simulated_lidar", "sensor": "lidar_top"}, "lidar_top", "not a recording", "driver"),
        (rosbag(bag, "/lidar/points"), "cam_front", "not a LiDAR", "sensor"),
    ]
    for settings, sensor, message, field in cases:
        with pytest.raises(InputError, match=message) as info:
            recordings.import_recording(session, sensor, settings)
        assert info.value.input == field
    assert all(session.captures(s) == [] for s in ("lidar_top", "cam_front"))
    with pytest.raises(InputError, match="at least 1"):
        recordings.import_recording(session, "lidar_top", rosbag(bag, "/lidar/points"), every=0)


def test_a_corrupt_file_in_a_cloud_folder_is_skipped_and_named(session, tmp_path):
    folder = tmp_path / "clouds"
    folder.mkdir()
    for k in range(3):
        np.save(folder / f"scan{k}.npy", np.random.default_rng(k).uniform(-5, 5, (500, 3)))
    (folder / "scan1.npy").write_bytes(b"\x93NUMPY broken")
    summary = recordings.import_recording(session, "lidar_top", {"driver": "cloud_files", "path": str(folder)})
    assert len(summary.added) == 2 and [Path(s["input"]).name for s in summary.skipped] == ["scan1.npy"]
    assert [c.source for c in session.captures("lidar_top")] == ["scan0.npy", "scan2.npy"]


def test_api_lists_topics_and_imports(bag, tmp_path):
    store = SessionStore(tmp_path / "api")
    store.create("rec", rig=demo_rig())
    with TestClient(create_app(store)) as client:
        topics = client.get("/api/recordings/topics", params={"path": str(bag)})
        assert topics.status_code == 200
        assert {t["name"]: t["count"] for t in topics.json()}["/lidar/points"] == 3
        missing = client.get("/api/recordings/topics", params={"path": str(tmp_path / "nope")})
        assert missing.status_code == 422 and "does not exist" in missing.json()["error"]["message"]

        job = client.post("/api/sessions/rec/sensors/lidar_top/import",
                          json={"device": rosbag(bag, "/lidar/points"), "every": 1})
        assert job.status_code == 202
        status = wait_job(client, job.json()["id"])
        assert status["state"] == "done" and len(status["summary"]["added"]) == 3, status
        captures = client.get("/api/sessions/rec/sensors/lidar_top/captures").json()
        assert [c["id"] for c in captures] == status["summary"]["added"]

        refused = client.post("/api/sessions/rec/sensors/lidar_top/import", json={})  # its device is live-only
        assert refused.status_code == 422 and refused.json()["error"]["input"] == "driver"
        bad_topic = client.post("/api/sessions/rec/sensors/lidar_top/import",
                                json={"device": rosbag(bag, "/cam/mono")})
        status = wait_job(client, bad_topic.json()["id"])
        assert status["state"] == "failed" and "holds no point cloud" in status["error"]["message"]


def test_topics_for_each_sensor_kind(bag):
    topics = recordings.bag_topics(str(bag))
    assert recordings.topics_for_kind(topics, "lidar3d") == ["/lidar/padded", "/lidar/points", "/scan"]
    assert recordings.topics_for_kind(topics, "camera") == ["/cam/bgr", "/cam/compressed", "/cam/mono"]
