"""The LiDAR-to-camera results in a session: a hand-set transform stored as a transform result between the rig's
frames, accepted into the rig through the one accept service (the rig re-fitted so that it holds), reverting to
an older result, and what cannot be stored or accepted."""

from __future__ import annotations

import numpy as np
import pytest

from backend.calib.lidar_camera import service
from backend.calib.rig import service as rig_service
from backend.core.errors import InputError
from backend.core.result import TransformResult
from backend.core.rig import edge_slot
from backend.core.transforms import from_xyz_ypr, transform_error
from backend.sim.demo_rig import demo_rig
from backend.store.session import Session, SessionStore

SLOT = "lidar_front/T_cam_front_lidar_front"


@pytest.fixture
def session(tmp_path) -> Session:
    return SessionStore(tmp_path).create("l2c", rig=demo_rig())


def _off_by(session: Session, T: np.ndarray) -> tuple[float, float]:
    """How far the rig's ``T_cam_front_lidar_front`` is from ``T`` (m, deg)."""
    err_t, err_r = transform_error(session.rig.T_a_b("cam_front", "lidar_front"), T)
    return float(np.linalg.norm(err_t)), float(np.linalg.norm(err_r))


def test_a_hand_set_transform_is_a_transform_result_between_the_rig_frames(session):
    T = session.rig.T_a_b("cam_front", "lidar_front") @ from_xyz_ypr(np.array([0.02, 0, 0]), np.radians([1, 0, 0]))
    result_id = service.store_manual(session, "cam_front", "lidar_front", T,
                                     inputs=["cam_front:00001", "lidar_front:00001"])
    record = session.result(result_id)
    assert record["sensor"] == "lidar_front" and record["inputs"] == ["cam_front:00001", "lidar_front:00001"]
    assert record["verdict"] == {"level": "check", "reasons": ["set by hand: no uncertainty, no cross-check"]}
    result = TransformResult.from_record(record)
    assert (result.kind, result.method, result.parent, result.child) == ("lidar_camera", "manual", "cam_front",
                                                                         "lidar_front")
    np.testing.assert_allclose(result.T_parent_child, T, atol=1e-12)
    assert np.isnan(result.covariance).all() and result.std == {"trans_m": [None] * 3, "rot_deg": [None] * 3}
    assert rig_service.slot_of(record) == SLOT == edge_slot("cam_front", "lidar_front")
    np.testing.assert_allclose(service.result_transform(session, "lidar_front", result_id), T, atol=1e-12)
    # A record kept before the results were transform results (its transform under its own name) still reads.
    legacy = session.add_result("lidar_front", {"kind": "lidar_camera", "method": "target", "camera": "cam_front",
                                                "T_camera_lidar": T.tolist(), "converged": True}, inputs=[])
    np.testing.assert_allclose(service.result_transform(session, "lidar_front", legacy), T, atol=1e-12)


def test_a_hand_set_transform_is_accepted_and_reverted(session):
    first = session.rig.T_a_b("cam_front", "lidar_front") @ from_xyz_ypr(np.array([0.02, 0, 0]), np.radians([1, 0, 0]))
    second = first @ from_xyz_ypr(np.array([0, 0.01, 0]), np.radians([0, 0.5, 0]))
    first_id = service.store_manual(session, "cam_front", "lidar_front", first, inputs=[])
    with pytest.raises(InputError, match="set by hand: no uncertainty, no cross-check") as info:
        rig_service.accept(session, first_id)  # a manual result is a 'check': it needs confirming
    assert info.value.input == "confirm" and session.accepted(SLOT) is None
    far_m, far_deg = _off_by(session, first)
    rig_service.accept(session, first_id, confirm=True)
    # The edge's assumed sigma (rig_service.MANUAL_SIGMA) against the mounting guesses' (5 cm, 5 deg): the tree takes
    # the edge.
    near_m, near_deg = _off_by(session, first)
    assert far_m > 0.019 and far_deg > 0.99 and near_m < 0.001 and near_deg < 0.01, (near_m, near_deg)

    second_id = service.store_manual(session, "cam_front", "lidar_front", second, inputs=[])
    rig_service.accept(session, second_id, confirm=True)
    assert _off_by(Session.load(session.path), second)[0] < 0.001
    rig_service.accept(session, first_id, confirm=True)  # back to the first
    assert _off_by(session, first)[0] < 0.001 and session.accepted(SLOT) == first_id
    assert [r["id"] for r in session.results("lidar_front", "lidar_camera")] == [first_id, second_id]


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
    with pytest.raises(InputError, match="belongs to lidar_front, not lidar_top") as info:
        service.lidar_camera_record(session, "lidar_top", result_id)
    assert info.value.input == "result"
    note = session.add_result("lidar_front", {"kind": "note"}, inputs=[])
    with pytest.raises(InputError, match=f"result {note} is a note result, not lidar_camera"):
        service.result_transform(session, "lidar_front", note)
    assert session.accepted(SLOT) is None
