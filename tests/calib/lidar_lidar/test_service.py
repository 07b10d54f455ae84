"""LiDAR-to-LiDAR through the session: capture simulated clouds, solve, accept into the rig's tree, export."""

from __future__ import annotations

import numpy as np
import pytest

from backend.calib._session import store_cloud
from backend.calib.lidar_lidar import service
from backend.calib.rig import service as rig_service
from backend.core.errors import InputError
from backend.core.transforms import from_xyz_ypr, invert, params_between, rotation_angle_deg
from backend.devices.base import Sample, create_device
from backend.exports.rig_transforms import load_rig_transforms
from backend.services import exports as export_service
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
    with create_device(demo_rig().get(SOURCE).device) as source, create_device(demo_rig().get(TARGET).device) as target:
        for _ in range(2):  # both read together, as a capture with both live does: the pairs go by time stamp
            for device in (source, target):
                store_cloud(session, device.sensor, device.read(), device=device.describe())
    session.truth = truth
    return session


@pytest.mark.slow
def test_solve_accept_and_export(session):
    result_id, result = service.solve_session(session, SOURCE, TARGET)
    assert result.converged and (result.parent, result.child) == (TARGET, SOURCE)
    error = invert(session.truth) @ result.T_parent_child
    assert np.linalg.norm(error[:3, 3]) < 0.005
    assert rotation_angle_deg(error[:3, :3]) < 0.1
    assert np.all(np.abs(error[:3, 3]) < 3 * result.std_vector[:3] + 1e-4)

    record = session.result(result_id)
    assert (record["kind"], record["parent"], record["child"], record["sensor"]) == ("lidar_lidar", TARGET, SOURCE,
                                                                                     SOURCE)
    np.testing.assert_allclose(record["T_parent_child"], result.T_parent_child)
    assert service.pair_results(session, SOURCE, TARGET) == [record] and not service.pair_results(session, TARGET,
                                                                                                  SOURCE)
    # both frames were taken with the rig standing still: one scene, so no cross-check and a 'check'
    assert record["verdict"]["level"] == "check" and len(record["diagnostics"]["scenes"]) == 1
    assert len(record["inputs"]) == 2  # the two frame pairs, as "source id:target id"
    with pytest.raises(InputError, match="confirm"):
        rig_service.accept(session, result_id)
    update = rig_service.accept(session, result_id, confirm=True)
    assert session.acceptance_log[-1].confirmed and session.acceptance_log[-1].verdict == "check"
    assert session.accepted(f"{SOURCE}/T_{TARGET}_{SOURCE}") == result_id
    # the rig now holds the fused tree: the measured edge, against weak mounting guesses, decides it
    fused = session.rig.T_a_b(TARGET, SOURCE)
    assert np.all(np.abs(params_between(result.T_parent_child, fused)) < 0.1 * result.std_vector)
    assert any(move.frame == SOURCE for move in update.moves)
    sigma_trans_m, sigma_rot_deg = session.rig.get(SOURCE).sigmas
    assert np.all(sigma_trans_m > 0) and np.all(sigma_rot_deg > 0)
    assert session.rig.get(SOURCE).parent == "base_link"

    _, text = export_service.export_text(session, "rig")
    exported = {f["child"]: f for f in load_rig_transforms(text)}
    np.testing.assert_allclose(exported[SOURCE]["T_parent_child"], session.rig.get(SOURCE).T_parent_child, atol=1e-9)
    np.testing.assert_allclose(exported[SOURCE]["sigma"]["trans_m"], sigma_trans_m, rtol=1e-9)


def test_non_converged_result_cannot_be_accepted(session):
    """A poor fit is stored for inspection but refused on accept; the rig keeps its transform."""
    record = {"kind": "lidar_lidar", "method": "gicp", "parent": TARGET, "child": SOURCE, "converged": False,
              "warnings": ["fitness 0.000: no overlap"], "T_parent_child": np.eye(4).tolist(),
              "covariance": np.eye(6).tolist()}
    result_id = session.add_result(SOURCE, record, inputs=[])
    before = session.rig.get(SOURCE).T_parent_child.copy()
    with pytest.raises(InputError, match="did not converge"):
        rig_service.accept(session, result_id, confirm=True)
    np.testing.assert_array_equal(session.rig.get(SOURCE).T_parent_child, before)
    assert session.accepted(f"{SOURCE}/T_{TARGET}_{SOURCE}") is None


def test_a_result_is_checked_against_its_sensor_and_kind(session):
    record = {"kind": "lidar_lidar", "parent": TARGET, "child": SOURCE, "T_parent_child": np.eye(4).tolist()}
    result_id = session.add_result(SOURCE, record, inputs=[])
    assert service.check_result(session, SOURCE, result_id)["id"] == result_id
    with pytest.raises(InputError, match=f"result {result_id} belongs to {SOURCE}, not {TARGET}"):
        service.check_result(session, TARGET, result_id)
    other = session.add_result(SOURCE, {"kind": "sweep"}, inputs=[])
    with pytest.raises(InputError, match=f"result {other} is a sweep result, not lidar_lidar"):
        service.check_result(session, SOURCE, other)


def test_global_guess_and_the_fit_at_a_nudged_pose(session):
    """The step's nudging: a rough starting pose from RANSAC, and the fit of the clouds at any pose."""
    from scipy.spatial import cKDTree

    start = service.global_guess(session, SOURCE, TARGET)
    assert start.kept == "global" and 0 < start.global_fitness <= 1 and start.T_target_source.shape == (4, 4)
    assert start.message().startswith("Global guess on the sliders (fitness at 0.2 m: global ")
    source_points, target_points = service.capture_pairs(session, SOURCE, TARGET)[-1]
    tree = cKDTree(target_points)
    # a correct current pose is never replaced by a worse guess; a poor one is
    kept = service.global_guess(session, SOURCE, TARGET, T_current=session.truth)
    assert kept.kept == "current" and np.array_equal(kept.T_target_source, session.truth)
    assert kept.current_fitness == service.fit_at(source_points, tree, session.truth, 0.2)["fitness"]
    assert kept.current_fitness >= kept.global_fitness and kept.message().startswith("Kept the current pose")
    far = session.truth @ from_xyz_ypr(np.array([3.0, -2.0, 1.0]), np.array([40.0, 0, 0]))
    replaced = service.global_guess(session, SOURCE, TARGET, T_current=far)
    assert replaced.kept == "global" and replaced.current_fitness < replaced.global_fitness
    assert "fits better than the current pose" in replaced.message()
    at_truth = service.fit_at(source_points, tree, session.truth, 0.2)
    nudged = service.fit_at(source_points, tree, session.truth @ from_xyz_ypr(np.array([0.3, 0, 0]), np.zeros(3)), 0.2)
    assert at_truth["distances_m"].shape == (len(source_points),)
    assert at_truth["fitness"] > nudged["fitness"] and at_truth["c2c_mean_m"] < nudged["c2c_mean_m"]
    assert np.all(at_truth["inliers_m"] <= 0.2) and np.all(~np.isfinite(at_truth["distances_m"])
                                                          | (at_truth["distances_m"] <= 0.4))
    assert at_truth["fitness"] == pytest.approx(len(at_truth["inliers_m"]) / len(source_points))


def test_captures_pair_by_time_stamp_and_the_unpaired_are_named(tmp_path):
    """Never by capture number: lidar_top's second capture, taken alone, and lidar_front's third, taken long after,
    find no partner; uploads (no stamp) pair with each other in upload order."""
    session = SessionStore(tmp_path).create("stamps", rig=demo_rig())
    cloud = np.random.default_rng(0).uniform(-5, 5, (100, 3))
    stamps = {SOURCE: [1000.0, 1600.0, 2500.0, 0.0, 0.0], TARGET: [1000.3, 1300.0, 1600.2, 0.0, 0.0]}
    ids = {sensor: [store_cloud(session, sensor, Sample(t, points=cloud), device="test").id for t in times]
           for sensor, times in stamps.items()}
    found = service.pairing(session, SOURCE, TARGET)
    (s1, s2, s3, u1, u2), (t1, t2, t3, v1, v2) = ids[SOURCE], ids[TARGET]
    assert found.pairs == [(u1, v1), (u2, v2), (s1, t1), (s2, t3)]
    assert [why.split(" (")[0] for why in found.unpaired] == [f"{SOURCE} {s3}", f"{TARGET} {t2}"]
    assert found.unpaired[0].endswith(f"): no {TARGET} capture within 1 s")
    assert service.pairing(session, SOURCE, TARGET, window_s=0.25).pairs == [(u1, v1), (u2, v2), (s2, t3)]


def test_wrong_sensors_and_missing_clouds_are_named(session):
    with pytest.raises(InputError, match="cam_front.*not a LiDAR"):
        service.capture_pairs(session, "cam_front", TARGET)
    with pytest.raises(InputError, match="no clouds captured for scanner_2d"):
        service.capture_pairs(session, SOURCE, "scanner_2d")
    with pytest.raises(InputError, match="notes.txt: not a point-cloud file"):
        service.import_clouds(session, SOURCE, [("notes.txt", b"hello")])
