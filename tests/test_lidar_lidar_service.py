"""LiDAR-to-LiDAR through the session: capture simulated clouds, solve, accept into the rig, export."""

from __future__ import annotations

import numpy as np
import pytest

from backend.core.errors import InputError
from backend.core.transforms import from_xyz_ypr, invert, rotation_angle_deg
from backend.devices.base import create_device
from backend.exports.rig_transforms import load_rig_transforms
from backend.services import exports as export_service
from backend.services import lidar_lidar as service
from backend.sim.demo_rig import demo_rig
from backend.store.session import SessionStore

SOURCE, TARGET = "lidar_front", "lidar_top"


@pytest.fixture
def session(tmp_path):
    """The demo rig with lidar_front's mounting off by 10 cm and 4 degrees, and 2 clouds per LiDAR."""
    rig = demo_rig()
    truth = rig.T_a_b(TARGET, SOURCE)
    rig.get(SOURCE).T_parent_child = rig.get(SOURCE).T_parent_child @ from_xyz_ypr(
        np.array([0.06, -0.05, 0.06]), np.radians([3.0, -2.0, 1.5]))
    session = SessionStore(tmp_path).create("lidars", rig=rig)
    for sensor in (SOURCE, TARGET):
        with create_device(demo_rig().get(sensor).device) as device:
            for _ in range(2):
                service.store_cloud(session, sensor, device.read(), device=device.describe())
    session.truth = truth
    return session


@pytest.mark.slow
def test_solve_accept_and_export(session):
    result_id, result = service.solve_session(session, SOURCE, TARGET)
    assert result.converged
    error = invert(session.truth) @ result.T_target_source
    assert np.linalg.norm(error[:3, 3]) < 0.005
    assert rotation_angle_deg(error[:3, :3]) < 0.1
    assert np.all(np.abs(error[:3, 3]) < 3 * result.std[:3] + 1e-4)

    record = session.result(result_id)
    # both frames were taken with the rig standing still: one scene, so no cross-check and a 'check'
    assert record["verdict"]["level"] == "check" and len(record["scenes"]) == 1
    assert len(record["inputs"]) == 2  # the two frame pairs, as "source id:target id"
    with pytest.raises(InputError, match="confirm"):
        service.accept(session, SOURCE, result_id)
    service.accept(session, SOURCE, result_id, confirm=True)
    assert session.acceptance_log[-1].confirmed and session.acceptance_log[-1].verdict == "check"
    accepted = session.rig.T_a_b(TARGET, SOURCE)
    np.testing.assert_allclose(accepted, result.T_target_source, atol=1e-9)
    assert session.accepted(service.slot(SOURCE, TARGET)) == result_id
    sigma_trans_m, sigma_rot_deg = session.rig.get(SOURCE).sigmas
    assert np.all(sigma_trans_m > 0) and np.all(sigma_rot_deg > 0)
    # lidar_front hangs off base_link, not lidar_top: its covariance was carried into base_link's axes
    assert session.rig.get(SOURCE).parent == "base_link"

    _, text = export_service.export_text(session, "rig")
    exported = {f["child"]: f for f in load_rig_transforms(text)}
    np.testing.assert_allclose(exported[SOURCE]["T_parent_child"], session.rig.get(SOURCE).T_parent_child, atol=1e-9)
    np.testing.assert_allclose(exported[SOURCE]["sigma"]["trans_m"], sigma_trans_m, rtol=1e-9)


def test_non_converged_result_cannot_be_accepted(session):
    """A poor fit is stored for inspection but refused on accept; the rig keeps its transform."""
    record = {"kind": "lidar_lidar", "target": TARGET, "converged": False, "warnings": ["fitness 0.000: no overlap"],
              "T_target_source": np.eye(4).tolist(), "covariance": np.eye(6).tolist()}
    result_id = session.add_result(SOURCE, record, inputs=[])
    before = session.rig.get(SOURCE).T_parent_child.copy()
    with pytest.raises(InputError, match="did not converge"):  # a hand-made record has no verdict: 'check'
        service.accept(session, SOURCE, result_id, confirm=True)
    np.testing.assert_array_equal(session.rig.get(SOURCE).T_parent_child, before)
    assert session.accepted(service.slot(SOURCE, TARGET)) is None


def test_wrong_sensors_and_missing_clouds_are_named(session):
    with pytest.raises(InputError, match="cam_front.*not a LiDAR"):
        service.capture_pairs(session, "cam_front", TARGET)
    with pytest.raises(InputError, match="no clouds captured for scanner_2d"):
        service.capture_pairs(session, SOURCE, "scanner_2d")
    with pytest.raises(InputError, match="notes.txt: not a point-cloud file"):
        service.import_clouds(session, SOURCE, [("notes.txt", b"hello")])
