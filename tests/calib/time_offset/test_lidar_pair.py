"""Two 3D LiDARs on their own clocks (42 ms apart), the rig turned in the simulated yard: their clocks lined up by
each LiDAR's own odometry through the session service, and the rotation between them checked against the rig."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.calib.time_offset import service
from backend.core.errors import InputError
from backend.core.rig import Frame, Rig
from backend.sim.demo_rig import demo_rig
from backend.sim.lidar_imu import turning, turning_scans
from backend.sim.lidar_scene import LidarScene
from backend.store.session import SessionStore

OFFSET_S = 0.042


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    truth = demo_rig()
    rig = Rig()
    for name in ("lidar_top", "lidar_front"):
        rig.add(Frame(name, "base_link", truth.T_root_frame(name), kind="lidar3d"))
    session = SessionStore(tmp_path_factory.mktemp("lidar_pair") / "sessions").create("rig", rig=rig)
    motion, scene = turning(seed=3, amplitude_rad=0.3), LidarScene(include_board=False)
    for name, first_s, clock_s in (("lidar_top", 0.0, 0.0), ("lidar_front", 0.037, OFFSET_S)):
        times = np.arange(first_s, 8.0, 0.1)  # the two spin out of phase
        for t_s, points in zip(times, turning_scans(name, times, motion, scene), strict=True):
            session.add_cloud_capture(name, points, None, {"timestamp_s": 100.0 + t_s + clock_s, "device": "sim"})
    return session


def test_two_lidars_lined_up_by_their_odometry(session) -> None:
    result_id = service.solve_session(session, "lidar_top", "lidar_front")
    record = session.result(result_id)
    error_s = record["time_offset_s"] - OFFSET_S
    print(f"LiDAR-LiDAR offset {1e3 * record['time_offset_s']:.2f} ms (truth 42), sigma "
          f"{1e3 * record['std']['time_s']:.2f} ms, verdict {record['verdict']['level']}")
    assert abs(error_s) < 2e-3 and abs(error_s) < 3 * record["std"]["time_s"], (error_s, record["std"])
    R_top_front = session.rig.T_a_b("lidar_top", "lidar_front")[:3, :3]
    off_deg = np.degrees(Rotation.from_matrix(np.array(record["R_a_b"]) @ R_top_front.T).magnitude())
    assert off_deg < 1.0, off_deg


def test_a_lidar_with_too_few_scans_is_refused(session) -> None:
    session.add_sensor(Frame("lidar_new", "base_link", kind="lidar3d"))
    with pytest.raises(InputError, match="lidar_new holds 0 scans"):
        service.signals(session, "lidar_top", "lidar_new")
    with pytest.raises(InputError, match="name the camera first"):
        service.check_pair(session, "lidar_top", "lidar_top")
