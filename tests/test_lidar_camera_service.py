"""The LiDAR-to-camera results in a session: a hand-set transform stored and accepted into the rig (the LiDAR
re-mounted, the camera left alone), reverting to an older result, and what cannot be accepted."""

from __future__ import annotations

import numpy as np
import pytest

from backend.core.errors import InputError
from backend.core.transforms import from_xyz_ypr
from backend.services import lidar_camera as service
from backend.sim.demo_rig import demo_rig
from backend.store.session import Session, SessionStore


@pytest.fixture
def session(tmp_path) -> Session:
    return SessionStore(tmp_path).create("l2c", rig=demo_rig())


def test_a_hand_set_transform_is_accepted_and_reverted(session):
    camera_before = session.rig.get("cam_front").T_parent_child.copy()
    first = session.rig.T_a_b("cam_front", "lidar_front") @ from_xyz_ypr(np.array([0.02, 0, 0]), np.radians([1, 0, 0]))
    second = first @ from_xyz_ypr(np.array([0, 0.01, 0]), np.radians([0, 0.5, 0]))
    first_id = service.store_manual(session, "cam_front", "lidar_front", first,
                                    inputs=["cam_front:00001", "lidar_front:00001"])
    with pytest.raises(InputError, match="set by hand: no uncertainty, no cross-check"):
        service.accept(session, "lidar_front", first_id)  # a manual result is a 'check': it needs confirming
    service.accept(session, "lidar_front", first_id, confirm=True)
    np.testing.assert_allclose(session.rig.T_a_b("cam_front", "lidar_front"), first, atol=1e-12)
    np.testing.assert_array_equal(session.rig.get("cam_front").T_parent_child, camera_before)
    assert session.rig.get("lidar_front").covariance is None  # nothing measured it

    second_id = service.store_manual(session, "cam_front", "lidar_front", second, inputs=[])
    service.accept(session, "lidar_front", second_id, confirm=True)
    np.testing.assert_allclose(Session.load(session.path).rig.T_a_b("cam_front", "lidar_front"), second, atol=1e-12)
    service.accept(session, "lidar_front", first_id, confirm=True)  # back to the first
    np.testing.assert_allclose(session.rig.T_a_b("cam_front", "lidar_front"), first, atol=1e-12)
    assert session.accepted("lidar_front/T_cam_front_lidar_front") == first_id
    assert [r["id"] for r in session.results("lidar_front", "lidar_camera")] == [first_id, second_id]
    record = session.result(first_id)
    assert record["method"] == "manual" and record["inputs"] == ["cam_front:00001", "lidar_front:00001"]
    assert record["verdict"] == {"level": "check", "reasons": ["set by hand: no uncertainty, no cross-check"]}


def test_what_cannot_be_stored_or_accepted_is_named(session):
    T = session.rig.T_a_b("cam_front", "lidar_front")
    with pytest.raises(InputError, match="not a camera") as info:
        service.store_manual(session, "lidar_top", "lidar_front", T, inputs=[])
    assert info.value.input == "camera"
    with pytest.raises(InputError, match="not a LiDAR"):
        service.store_manual(session, "cam_front", "cam_wide", T, inputs=[])
    with pytest.raises(InputError, match="4x4") as info:
        service.store_manual(session, "cam_front", "lidar_front", np.eye(3), inputs=[])
    assert info.value.input == "T_camera_lidar"
    result_id = service.store_manual(session, "cam_front", "lidar_front", T, inputs=[])
    with pytest.raises(InputError, match="belongs to lidar_front"):
        service.accept(session, "lidar_top", result_id)
    assert session.accepted("lidar_front/T_cam_front_lidar_front") is None
