"""The simulated robot driven to other places of the yard, so that LiDAR-to-LiDAR scenes from several places check
each other and the demo's step 4 can reach a ``trusted`` result as its guidance asks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import open3d as o3d
import pytest

from backend.calib._session import store_cloud
from backend.calib.lidar_lidar import service as lidar_service
from backend.core.errors import InputError
from backend.core.rig import Rig
from backend.core.transforms import params_between, transform_points
from backend.devices.base import DeviceError, create_device
from backend.services.demo import move_simulated_robot, simulated_place
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.sim.lidar_scene import ROBOT_PLACES, LidarScene, robot_place
from backend.store.session import Session, SessionStore

SIMULATED = ["cam_front", "cam_wide", "cam_right", "lidar_top", "lidar_front", "scanner_2d", "sweep_3d"]


@pytest.fixture
def session(tmp_path: Path) -> Session:
    return SessionStore(tmp_path).create("yard", rig=demo_rig(), board=DEMO_BOARD)


def test_every_simulated_sensor_moves_in_one_change_and_a_bad_place_changes_nothing(session: Session) -> None:
    assert simulated_place(session) == 0
    revision = session.revision
    assert sorted(move_simulated_robot(session, 2)) == sorted(SIMULATED)
    assert session.revision == revision + 1 and simulated_place(session) == 2
    assert session.rig.get("lidar_top").device["place"] == 2
    assert session.rig.get("sweep_3d").device["scanner"] == {"driver": "sim", "place": 2}
    reopened = SessionStore(session.path.parent).get("yard")  # saved
    assert simulated_place(reopened) == 2

    for place in (len(ROBOT_PLACES), -1, "1"):
        with pytest.raises(InputError, match=r"expected one of 0-2") as info:
            move_simulated_robot(session, place)
        assert info.value.input == "place"
    assert simulated_place(session) == 2 and session.revision == revision + 1

    real = SessionStore(session.path.parent).create("real", rig=Rig("base_link"), board=DEMO_BOARD)
    assert simulated_place(real) is None
    with pytest.raises(InputError, match="no simulated sensors"):
        move_simulated_robot(real, 1)


def test_a_place_outside_the_yard_is_refused_when_the_device_opens() -> None:
    for device in ({"driver": "simulated_lidar", "sensor": "lidar_top", "place": 7},
                   {"driver": "simulated", "camera": "cam_front", "place": 7}):
        with pytest.raises(DeviceError, match="place must be one of 0-2"):
            create_device(device).open()


def test_the_yard_seen_from_another_place_is_the_same_yard() -> None:
    """lidar_top's scan from place 1, mapped into the yard with the robot's pose there, lies on the yard's surfaces
    (the walls and boxes stay; only the robot moved, and the board with it)."""
    T_base_lidar = demo_rig().T_root_frame("lidar_top")
    with create_device({"driver": "simulated_lidar", "sensor": "lidar_top", "place": 1}) as device:
        sample = device.read()
    assert sample.meta["place"] == 1
    T_yard_lidar = robot_place(1) @ T_base_lidar
    yard = LidarScene(robot_place(1) @ np.array(sample.meta["T_base_board"]))
    surfaces = o3d.t.geometry.RaycastingScene()
    surfaces.add_triangles(o3d.core.Tensor(yard.vertices, o3d.core.float32),
                           o3d.core.Tensor(yard.triangles, o3d.core.uint32))
    distance_m = surfaces.compute_distance(o3d.core.Tensor(transform_points(T_yard_lidar, sample.points),
                                                           o3d.core.float32)).numpy()
    assert np.percentile(distance_m, 95) < 0.03  # the 1 cm range noise
    at_origin = surfaces.compute_distance(o3d.core.Tensor(transform_points(T_base_lidar, sample.points),
                                                          o3d.core.float32)).numpy()
    assert np.median(at_origin) > 0.1  # as if the robot had not moved: off the walls


@pytest.mark.slow
def test_clouds_from_three_places_give_a_trusted_lidar_to_lidar_result(session: Session) -> None:
    pairs = []  # each place's two clouds, as step 4 captures them (one after the other here: the scans' stamps
    # may lie further apart than the next place's on a loaded machine, so the pairs are named, not found by stamp)
    for place in range(len(ROBOT_PLACES)):
        move_simulated_robot(session, place)
        ids = []
        for sensor in ("lidar_front", "lidar_top"):
            with create_device(session.rig.get(sensor).device) as device:
                ids.append(store_cloud(session, sensor, device.read(), device=device.describe()).id)
        pairs.append(tuple(ids))
    result_id, result = lidar_service.solve_session(session, "lidar_front", "lidar_top", pairs=pairs)
    record = session.result(result_id)
    assert record["verdict"]["level"] == "trusted", record["verdict"]
    assert len(result.diagnostics["scenes"]) == len(ROBOT_PLACES), result.diagnostics["scenes"]
    error = params_between(demo_rig().T_a_b("lidar_top", "lidar_front"), result.T_parent_child)
    sigma = np.r_[result.std["trans_m"], np.radians(result.std["rot_deg"])]
    assert np.all(np.abs(error) < 3 * sigma + 1e-4), (error, sigma)
