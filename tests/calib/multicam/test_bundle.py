"""The joint multi-camera solve: order independence, sigmas against the simulator's truth, the observation graph,
outliers, refined intrinsics, clear refusals, and agreement with ``cv2.stereoCalibrate`` on OpenCV's real stereo
chessboard pairs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.calib.board.detection import Detection
from backend.calib.multicam.bundle import MulticamResult, MulticamSettings, calibrate_multicam
from backend.calib.multicam.graph import Observation, observation_graph, spanning_tree
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import TransformResult
from backend.core.transforms import invert

STEREO_BOARD = BoardSpec.parse("checkerboard:9x6:0.025")


def _rotation_deg(R: np.ndarray) -> float:
    return float(np.degrees(Rotation.from_matrix(R).magnitude()))


def _relative(result: MulticamResult, a: str, b: str) -> np.ndarray:
    return invert(result.T_ref_cam[a]) @ result.T_ref_cam[b]


def test_the_ring_only_connects_through_its_neighbours(ring, ring_observations):
    graph = observation_graph(list(ring.cameras), [(o.camera, o.frame) for o in ring_observations])
    assert ("cam0", "cam5") not in graph.shared_frames and ("cam0", "cam3") not in graph.shared_frames
    assert {("cam0", "cam1"), ("cam1", "cam2"), ("cam2", "cam3"), ("cam3", "cam4"), ("cam4", "cam5")} <= set(
        graph.shared_frames)
    tree = spanning_tree(graph)
    assert len(tree) == 5 and tree[0][0] == "cam0"
    assert {child for _, child in tree} == {"cam1", "cam2", "cam3", "cam4", "cam5"}


@pytest.mark.slow
def test_every_camera_order_gives_the_same_rig(ring, ring_observations, ring_result):
    names = list(ring.cameras)
    for order in (names[::-1], ["cam3", "cam0", "cam5", "cam1", "cam4", "cam2"]):
        result = calibrate_multicam({n: ring.cameras[n] for n in order}, ring.board, ring_observations)
        assert result.reference == order[0] and result.converged
        for name in names:
            ours, theirs = _relative(ring_result, "cam0", name), _relative(result, "cam0", name)
            assert np.abs(ours[:3, 3] - theirs[:3, 3]).max() < 1e-6  # m
            assert _rotation_deg(ours[:3, :3].T @ theirs[:3, :3]) < 1e-6  # deg
            assert result.rms_px[name] == pytest.approx(ring_result.rms_px[name], abs=1e-9)


def test_errors_stay_within_three_sigma_of_the_truth(ring, ring_result):
    truth = ring.T_ref_cam("cam0")
    z_scores = []
    for name in list(ring.cameras)[1:]:
        error = invert(truth[name]) @ ring_result.T_ref_cam[name]
        translation_error_m = ring_result.T_ref_cam[name][:3, 3] - truth[name][:3, 3]  # reference axes
        rotation_error_deg = np.degrees(Rotation.from_matrix(error[:3, :3]).as_rotvec())  # about the camera's axes
        std = ring_result.transforms[name].std
        z = np.concatenate([translation_error_m / std["trans_m"], rotation_error_deg / std["rot_deg"]])
        assert np.all(np.abs(z) < 3), (name, z)
        z_scores.append(z)
    # The sigmas are neither far too small nor far too large: the squared z-scores average about 1.
    assert 0.2 < np.mean(np.square(z_scores)) < 3.0
    # RMS of the corners' residual lengths, as OpenCV reports it: sqrt(2) * 0.3 px of noise per axis.
    assert all(0.38 < v < 0.46 for v in ring_result.rms_px.values()), ring_result.rms_px
    assert not any(f.flagged for f in ring_result.frames)
    correlation = np.array(ring_result.correlation["matrix"], dtype=float)
    assert correlation.shape == (30, 30) and np.allclose(np.diag(correlation), 1.0)


def test_each_camera_is_one_transform_result(ring, ring_result):
    """Every camera but the reference is one TransformResult from the reference, its record read back alike; the
    CLI's summary still holds every camera (the reference's identity and zero sigmas)."""
    names = list(ring.cameras)
    assert list(ring_result.transforms) == names[1:]
    record = ring_result.to_record()
    assert "T_ref_cam" not in record and list(record["verdict"]) == names
    for name in names[1:]:
        transform = ring_result.transforms[name]
        assert (transform.kind, transform.method, transform.parent, transform.child) == ("multicam", "bundle",
                                                                                         "cam0", name)
        assert transform.residuals["rms_px"] == ring_result.rms_px[name] and transform.converged
        assert transform.verdict is not None and transform.verdict == ring_result.verdicts[name]
        assert transform.diagnostics["pairs"] and all(name in (p["a"], p["b"]) for p in transform.diagnostics["pairs"])
        back = TransformResult.from_record(record["transforms"][name])
        np.testing.assert_array_equal(back.T_parent_child, transform.T_parent_child)
        np.testing.assert_allclose(back.covariance, transform.covariance, rtol=0, atol=0)
        assert back.std == transform.std and back.verdict == transform.verdict
    summary = ring_result.summary()
    assert set(summary) == {"cameras", "T_ref_cam", "std", "rms_px", "seconds", "verdict"}
    assert list(summary["T_ref_cam"]) == list(summary["std"]) == list(summary["verdict"]) == names
    assert summary["T_ref_cam"]["cam0"] == np.eye(4).tolist()
    assert summary["std"]["cam0"] == {"trans_m": [0.0] * 3, "rot_deg": [0.0] * 3}
    assert summary["std"]["cam3"] == ring_result.transforms["cam3"].std


def test_sigmas_grow_along_the_chain(ring_result):
    """cam5 is related to cam0 only through four other cameras, so it is less certain than cam1."""
    std = {name: np.linalg.norm(ring_result.transforms[name].std["trans_m"]) for name in ("cam1", "cam5")}
    assert std["cam5"] > 2 * std["cam1"]


@pytest.mark.slow
def test_outlier_views_and_corners_are_flagged_and_do_not_pull(ring, ring_observations, ring_result):
    observations = list(ring_observations)
    bad_view = next(i for i, o in enumerate(observations) if o.camera == "cam2")
    d = observations[bad_view].detection
    observations[bad_view] = replace(observations[bad_view],
                                     detection=replace(d, corners_px=d.corners_px + [25.0, -18.0]))
    bad_corner = next(i for i, o in enumerate(observations) if o.camera == "cam4")
    d = observations[bad_corner].detection
    shifted = d.corners_px.copy()
    shifted[7] += [8.0, 6.0]
    observations[bad_corner] = replace(observations[bad_corner], detection=replace(d, corners_px=shifted))

    result = calibrate_multicam(ring.cameras, ring.board, observations)
    flagged = [(f.camera, f.frame) for f in result.frames if f.flagged]
    assert flagged == [("cam2", observations[bad_view].frame)]
    corner_view = next(f for f in result.frames if (f.camera, f.frame) == ("cam4", observations[bad_corner].frame))
    assert corner_view.outlier_corners == 1 and not corner_view.flagged
    assert any("left out as outliers" in w for w in result.warnings)
    for name in ring.cameras:  # the rig is as without the damage, well within its sigmas
        difference = invert(ring_result.T_ref_cam[name]) @ result.T_ref_cam[name]
        std_m = np.linalg.norm(ring_result.transforms[name].std["trans_m"]) if name != "cam0" else 0.0
        assert np.linalg.norm(difference[:3, 3]) < 0.3 * std_m + 1e-9


@pytest.mark.slow
def test_intrinsics_are_refined_with_the_rig(ring, ring_observations):
    truth = ring.cameras["cam1"]
    K = truth.K.copy()
    K[0, 0] *= 1.02
    K[1, 1] *= 0.985
    K[0, 2] += 6.0
    K[1, 2] -= 4.0
    start = dict(ring.cameras) | {"cam1": CameraIntrinsics(truth.model, truth.width, truth.height, K,
                                                           truth.dist * 0.8)}
    result = calibrate_multicam(start, ring.board, ring_observations, MulticamSettings(estimate_intrinsics=["cam1"]))
    assert result.converged
    refined, std = result.cameras["cam1"], result.intrinsics_std["cam1"]
    assert set(std) == {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"}
    for name, (row, col) in {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}.items():
        assert abs(refined.K[row, col] - truth.K[row, col]) < max(3 * std[name], 0.05), name
    assert abs(refined.dist[0] - truth.dist[0]) < 3 * std["k1"]
    assert result.cameras["cam0"].K.tolist() == ring.cameras["cam0"].K.tolist()  # held


def test_a_camera_that_never_shares_a_frame_is_refused_by_name(ring, ring_observations):
    frames_of = {c: {o.frame for o in ring_observations if o.camera == c} for c in ring.cameras}
    cut = frames_of["cam2"] & frames_of["cam3"]  # remove every frame cam2 and cam3 saw together
    observations = [o for o in ring_observations if not (o.frame in cut and o.camera in ("cam2", "cam3"))]
    with pytest.raises(InputError, match="camera cam3 never sees the board in the same frame as cam0, cam1, cam2") \
            as info:
        calibrate_multicam(ring.cameras, ring.board, observations)
    assert info.value.input == "cam3"


def test_a_camera_that_never_saw_the_board_is_refused_by_name(ring, ring_observations):
    observations = [o for o in ring_observations if o.camera != "cam4"]
    with pytest.raises(InputError, match="camera cam4 did not see the board in any frame") as info:
        calibrate_multicam(ring.cameras, ring.board, observations)
    assert info.value.input == "cam4"
    with pytest.raises(InputError, match="at least two cameras"):
        calibrate_multicam({"cam0": ring.cameras["cam0"]}, ring.board, ring_observations)
    with pytest.raises(InputError, match="camera cam9, which is not among"):
        calibrate_multicam(ring.cameras, ring.board, ring_observations + [replace(ring_observations[0], camera="cam9")])


@pytest.mark.slow
def test_a_camera_whose_intrinsics_do_not_fit_is_named(ring, ring_observations):
    """Another focal length, held fixed: none of the camera's views agree with the others, and the solve says so."""
    wrong = dict(ring.cameras) | {"cam0": replace(ring.cameras["cam0"], K=ring.cameras["cam0"].K * [[0.8], [0.8], [1]])}
    with pytest.raises(InputError, match=r"camera cam0 fits worst \(median RMS \d\.\d\d px against 0\.4\d px") as info:
        calibrate_multicam(wrong, ring.board, ring_observations)
    assert info.value.input == "cam0"


# --------------------------------------------------------------------------------------------
# Real data: OpenCV's stereo chessboard pairs


@pytest.fixture(scope="module")
def stereo_views(stereo_detections: dict[str, dict[str, Detection]]) -> dict[str, dict[str, Detection]]:
    """Each side's detections, by frame number."""
    return {side: {Path(name).stem[len(side):]: detection for name, detection in detections.items()}
            for side, detections in stereo_detections.items()}


@pytest.mark.slow
def test_agrees_with_opencv_stereo_calibrate_on_real_pairs(stereo_views):
    frames = sorted(stereo_views["left"])
    assert len(frames) == 13
    object_points = [STEREO_BOARD.object_points.astype(np.float32)] * len(frames)
    image_points = {side: [stereo_views[side][f].corners_px.astype(np.float32) for f in frames]
                    for side in ("left", "right")}
    size = (640, 480)
    cameras = {}
    for side in ("left", "right"):
        _, K, dist, _, _ = cv2.calibrateCamera(object_points, image_points[side], size, None, None)
        cameras[side] = CameraIntrinsics("pinhole-radtan", *size, K, dist.ravel()[:5])
    rms_cv, *_, R, T, _, _ = cv2.stereoCalibrate(
        object_points, image_points["left"], image_points["right"], cameras["left"].K, cameras["left"].dist,
        cameras["right"].K, cameras["right"].dist, size, flags=cv2.CALIB_FIX_INTRINSIC,
        criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12))
    T_right_left = np.eye(4)
    T_right_left[:3, :3], T_right_left[:3, 3] = R, T.ravel()

    observations = [Observation(side, f, stereo_views[side][f]) for side in ("left", "right") for f in frames]
    # Like with like: stereoCalibrate's objective (squares, every corner kept), which the defaults (soft-L1,
    # corners beyond 1 px dropped) are not.
    result = calibrate_multicam(cameras, STEREO_BOARD, observations,
                                MulticamSettings(loss_scale_px=1e4, outlier_min_px=1e4))
    assert result.converged and not any(f.flagged for f in result.frames)
    T_left_right = result.T_ref_cam["right"]
    difference = T_right_left @ T_left_right
    baseline_m = np.linalg.norm(T_left_right[:3, 3])
    print(f"baseline ours {baseline_m * 1e3:.4f} mm, OpenCV {np.linalg.norm(T) * 1e3:.4f} mm; "
          f"rms ours {result.rms_px}, OpenCV {rms_cv:.4f} px; std {result.transforms['right'].std}")
    assert baseline_m == pytest.approx(np.linalg.norm(T), abs=1e-6)  # 1 um of 83 mm
    assert np.linalg.norm(difference[:3, 3]) < 1e-6
    assert _rotation_deg(difference[:3, :3]) < 1e-4
    combined_rms = np.sqrt(np.mean([result.rms_px["left"] ** 2, result.rms_px["right"] ** 2]))
    assert combined_rms == pytest.approx(rms_cv, rel=1e-4)
    # The robust defaults (soft-L1, far corners dropped) see slightly different data: within 2 sigma of OpenCV's.
    default = calibrate_multicam(cameras, STEREO_BOARD, observations)
    assert np.linalg.norm(default.T_ref_cam["right"][:3, 3]) == pytest.approx(
        baseline_m, abs=2 * default.transforms["right"].std["trans_m"][0])
    # OpenCV's stereo sample's rough expectation: about 3.3 squares, mostly along -x of the right camera.
    assert 0.08 < baseline_m < 0.087 and T_left_right[0, 3] > 0.08
    std = result.transforms["right"].std
    assert max(std["trans_m"]) < 1e-3 and max(std["rot_deg"]) < 0.2
