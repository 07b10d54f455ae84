"""The target solve on the real VLP-16 + fisheye set (``../shared/data/vlp16_camera_checkerboard``): its verdict
follows the cross-check rule and is never ``trusted`` while the result misses the reference runs; it agrees with the
runs' own method redone on the board's points, and the runs' distance from it is their selection of points; the
targetless intensity method, which the street misleads, is rejected.

The set's README gives three reference runs of the CMU toolbox (about 2.7 cm and 1.2 deg apart); the solve starts
3 deg (each of yaw, pitch, roll) and 5 cm off run 1, as a tape measure would give it.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest

from backend.calib.board.detection import detect_board
from backend.calib.lidar_camera import service
from backend.calib.lidar_camera.lens_uncertainty import LensUncertainty
from backend.calib.lidar_camera.target import TargetObservation, camera_board_pose
from backend.calib.lidar_camera.target_evidence import shares_in_image_outline
from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.core.result import TransformResult
from backend.core.transforms import from_xyz_ypr, invert, make_T, transform_error, transform_points
from backend.core.verdict import CROSS_CHECK_SIGMAS, REJECT_SIGMAS
from backend.exports.ros_camera_info import load_camera_info
from tests.calib.lidar_camera.cmu_reference import board_plane, clicks_on_boards, reproduce, scan_points
from tests.conftest import SHARED_DATA

pytestmark = pytest.mark.slow

VLP16 = SHARED_DATA / "vlp16_camera_checkerboard"
BOARD = "checkerboard:7x6:0.05"
AGREES_M, AGREES_DEG = 0.03, 1.2
"""Within the reference runs' own spread (the set's README): a result this close to one run agrees with them."""
CAMERA, _ = load_camera_info(VLP16 / "camera.yaml")
RUN_RE = re.compile(r"- run (\d): t = (\[[^\]]*\]), R = (\[\[.*\]\])")


def reference_runs() -> list[np.ndarray]:
    """The README's three ``T_camera_lidar`` (4x4, m), read from it (the set fails, not skips, when missing)."""
    runs = RUN_RE.findall((VLP16 / "README.md").read_text())
    assert [run[0] for run in runs] == ["1", "2", "3"], runs
    return [make_T(np.array(json.loads(R)), np.array(json.loads(t))) for _, t, R in runs]


@pytest.fixture(scope="module")
def real_pairs() -> list[service.PairData]:
    """The eight pairs read, with the board's corners found in each image (once for the module: about 10 s)."""
    pairs = service.read_pair_files([(VLP16 / f"vlp{i}.jpg", VLP16 / f"lidar{i}.ply") for i in range(1, 9)])
    return [replace(pair, detection=detect_board(pair.image, BoardSpec.parse(BOARD))) for pair in pairs]


def start() -> np.ndarray:
    """Run 1 turned 3 deg in yaw, pitch and roll and moved 5 cm: a tape measure's guess."""
    return reference_runs()[0] @ from_xyz_ypr(np.full(3, 0.05 / np.sqrt(3)), np.radians([3.0, 3.0, 3.0]))


def apart(T: np.ndarray, T_other: np.ndarray) -> tuple[float, float]:
    """(translation norm in m, rotation angle in deg) of ``T`` from ``T_other``."""
    trans_m, rot_deg = transform_error(T, T_other)
    return float(np.linalg.norm(trans_m)), float(np.linalg.norm(rot_deg))


def solve(pairs: list[service.PairData]) -> TransformResult:
    return service.solve_pairs(CAMERA, BoardSpec.parse(BOARD), pairs, start())


@pytest.fixture(scope="module")
def result(real_pairs) -> TransformResult:
    """The target solve of the eight pairs as the CLI runs it, from :func:`start` (once for the module)."""
    return solve(real_pairs)


def test_the_verdict_follows_the_cross_check_rule_on_the_real_set(result) -> None:
    runs = reference_runs()
    assert result.converged, result.warnings

    off = [apart(result.T_parent_child, T_run) for T_run in runs]
    agrees = any(t_m <= AGREES_M and r_deg <= AGREES_DEG for t_m, r_deg in off)
    print("from the runs: " + ", ".join(f"{100 * t:.1f} cm / {r:.2f} deg" for t, r in off)
          + f"; verdict {result.verdict.level}: {result.verdict.reasons}")
    if not agrees:  # a result outside the references' spread must not read as trusted
        assert result.verdict.level != "trusted", result.verdict.reasons

    # The leave-one-pose-out cross-check, in sigmas, and the level the rule gives it
    spread = np.array(result.diagnostics["std_spread"], float)
    jacobian = np.array(result.diagnostics["std_jacobian"], float)
    sigmas = float(np.max(spread / jacobian))
    reason = next(r for r in result.verdict.reasons if "leave one of the poses out" in r)
    assert f"({sigmas:.1f} sigma" in reason, reason
    if sigmas > REJECT_SIGMAS:
        assert result.verdict.level == "reject", result.verdict.reasons
    elif sigmas > CROSS_CHECK_SIGMAS:
        assert result.verdict.level != "trusted", result.verdict.reasons
    if sigmas > CROSS_CHECK_SIGMAS:  # the failed check names the pose to look at first
        worst = max(result.diagnostics["poses"], key=lambda pose: pose["without_sigmas"])
        assert f"; without {worst['name']} the result moves most: " in reason, reason


def test_with_the_lens_sigma_the_set_states_the_sigma_covers_the_reference_runs(real_pairs) -> None:
    # The set's README: the intrinsics are "weakly determined (kc sigma up to 37, fc sigma 25 px)". Carried into the
    # board poses (fx and fy alone, uncorrelated), they widen the sigma to cover the runs: 0.6-0.85 sigmas away
    # (5 or more without them).
    fc_sigma_px = float(re.search(r"fc σ (\d+) px", (VLP16 / "README.md").read_text()).group(1))
    lens = LensUncertainty.from_sigmas(CAMERA, [fc_sigma_px, fc_sigma_px, 0, 0, 0, 0, 0, 0], "the set's README")
    result = service.solve_pairs(CAMERA, BoardSpec.parse(BOARD), real_pairs, start(), lens=lens)
    assert result.diagnostics["lens_uncertainty"].startswith("carried into the board poses, from the set's README")
    for T_run in reference_runs():
        trans_m, rot_deg = transform_error(result.T_parent_child, T_run)
        assert np.all(np.abs(np.r_[trans_m, np.radians(rot_deg)]) <= 3 * result.std_vector), (trans_m, rot_deg)
    assert result.verdict.level != "trusted"


def test_the_intensity_method_misled_by_the_street_is_rejected(real_pairs) -> None:
    """Started at run 1, the street's intensities favour an alignment 6 deg away, at the edge of the search, and the
    pairs are one place (a rig standing still), so nothing cross-checks it. Before pairs counted by place, all eight
    answered 7 deg and 24 cm off with a 0.3 deg sigma, 'check', its leave-one-pair-out check passing. Every other pair
    (four: half the solve's time) is enough to show it: the other four end the same way (r_x +5.9 of 6 deg)."""
    pairs = real_pairs[::2]
    result = service.solve_pairs(CAMERA, None, pairs, reference_runs()[0], method="intensity")
    reasons = " ".join(result.verdict.reasons)
    assert not result.converged and result.verdict.level == "reject", result.verdict.reasons
    assert "the best alignment lies at the edge of the search (r_x +" in reasons, reasons
    assert "no cross-check over places: the 4 pairs were taken in one place" in reasons, reasons
    assert result.diagnostics["places"] == [[pair.name for pair in pairs]]


def test_the_result_puts_the_board_points_on_the_board_the_camera_saw(real_pairs, result) -> None:
    # A check in the image, apart from the solve's own residuals: the share of each pose's board points that a
    # transform projects inside the board's outline as the camera saw it. With the set's own intrinsics the three
    # reference runs put the scan lines 20-110 px above the board (their vertical translation rests on the board
    # normals' few degrees of vertical spread): shares 0.72-0.79 against the result's 0.91 (hand and arm points
    # fall outside at any transform).
    margin_m = result.diagnostics["plate_margin_m"]
    assert 0.005 < margin_m < 0.025  # a thin printed border, and the beam's footprint: 14 mm
    board = BoardSpec.parse(BOARD)
    settings = replace(service.target_settings(board), plate_margin_m=margin_m)
    transforms = [result.T_parent_child, *reference_runs()]
    shares = [shares_in_image_outline(TargetObservation(camera_board_pose(pair.image, CAMERA, board,
                                                                          detection=pair.detection), pair.points,
                                                        pair.name), transforms, CAMERA, board, settings)
              for pair in real_pairs]
    mean = np.mean(shares, axis=0)
    print(f"board points inside the board in the image: result {mean[0]:.2f}, runs {np.round(mean[1:], 2)}")
    assert mean[0] > 0.85 and np.all(mean[0] > mean[1:] + 0.05), mean


def test_the_runs_come_from_the_off_board_points_the_toolbox_keeps(real_pairs, result) -> None:
    """The reference runs' own method (the CMU toolbox's two plane stages, :mod:`cmu_reference`) redone on the same
    input. With the points the toolbox keeps (within 2 cm of the board's plane and 1 m of the click) it lands near the
    runs; those points include the hand, arm and body on half the poses. On the board's own points the same method
    lands within the runs' spread (3 cm, 1.2 deg) of this project's solve, and 3-5 deg from every run. So the solve's
    distance from the runs is the toolbox's selection, and the solve agrees with the reference method on the board.

    Over RANSAC seeds 0-4 (``benchmarks/lidar_camera_target_cmu.py``): the toolbox's points 0-27 mm / 0.13-0.96 deg
    from the nearest run and 1.8-2.6 deg from the solve; the board's 14-19 mm / 0.72-1.12 deg from the solve (within
    its 3 sigma on every axis) and 3.2-4.7 deg from the runs. Seed 0 is the board selection's farthest."""
    board, runs = BoardSpec.parse(BOARD), reference_runs()
    T_camera_boards = [camera_board_pose(pair.image, CAMERA, board, detection=pair.detection) for pair in real_pairs]
    clouds = [scan_points(pair.points) for pair in real_pairs]
    clicks = clicks_on_boards(clouds, T_camera_boards, board.object_points.mean(axis=0), runs[0])
    found = reproduce([board_plane(T) for T in T_camera_boards], clouds, clicks, seed=0)

    toolbox, on_board, ours = found["toolbox"], found["board"], result.T_parent_child
    for name, found_by in (("toolbox's", toolbox), ("board's", on_board)):
        print(f"the {name} points: from the runs {[apart(found_by.T_camera_lidar, T) for T in runs]}, from the "
              f"solve {apart(found_by.T_camera_lidar, ours)}, off the board {found_by.off_board_share}")
    nearest_run_deg = min(apart(toolbox.T_camera_lidar, T)[1] for T in runs)
    assert nearest_run_deg <= AGREES_DEG < apart(toolbox.T_camera_lidar, ours)[1]
    assert sum(share > 0.05 for share in toolbox.off_board_share) >= 4, toolbox.off_board_share
    assert max(on_board.off_board_share) == 0
    trans_m, rot_deg = apart(on_board.T_camera_lidar, ours)
    assert trans_m <= AGREES_M and rot_deg <= AGREES_DEG, (trans_m, rot_deg)
    assert all(apart(on_board.T_camera_lidar, T)[1] > 2 * AGREES_DEG for T in runs)
    # the solve's sigma covers its distance from the reference method on the board's points
    trans_m, rot_deg = transform_error(ours, on_board.T_camera_lidar)
    assert np.all(np.abs(np.r_[trans_m, np.radians(rot_deg)]) <= 3 * result.std_vector), (trans_m, rot_deg)


# ---------------------------------------------------------------- bad input, on the real set


def without_board(pair: service.PairData) -> service.PairData:
    """``pair`` with every cloud point within 0.6 m of where reference run 1 puts the camera's board removed."""
    T_camera_board = camera_board_pose(pair.image, CAMERA, BoardSpec.parse(BOARD), detection=pair.detection)
    centre = transform_points(invert(reference_runs()[0]) @ T_camera_board, np.array([[0.15, 0.125, 0.0]]))[0]
    far = np.linalg.norm(pair.points - centre, axis=1) > 0.6
    return replace(pair, points=pair.points[far], intensity=pair.intensity[far])


def test_poses_without_the_board_are_named_skipped_and_the_rest_solved(real_pairs) -> None:
    pairs = list(real_pairs)
    pairs[2] = without_board(pairs[2])  # the person walked out of the LiDAR's view
    pairs[4] = replace(pairs[4], image=np.full_like(pairs[4].image, 128), detection=None)  # covered lens
    result = solve(pairs)
    assert result.converged, result.warnings
    assert [pose["name"] for pose in result.diagnostics["poses"]] == [
        f"vlp{i}.jpg:lidar{i}.ply" for i in (1, 2, 4, 6, 7, 8)]
    blank, no_points = result.diagnostics["skipped"]
    assert blank == f"{VLP16 / 'vlp5.jpg'}: the board {BOARD} was not found in the image"
    assert no_points.startswith("vlp3.jpg:lidar3.ply: the board was not found in the LiDAR cloud: ")
    assert [w for w in result.warnings if w.endswith("; skipped")] == [f"{blank}; skipped", f"{no_points}; skipped"]


def test_fewer_than_three_usable_poses_are_refused_with_the_count(real_pairs) -> None:
    # Four poses whose boards face differently enough (the set's eight barely do: the smallest eigenvalue of their
    # normals' scatter is 0.0012, the limit 0.001), two of them without the board: the first, wide round takes the
    # person behind it for the board, the next round about the refined estimate finds nothing there
    pairs = [real_pairs[0], real_pairs[4], without_board(real_pairs[5]), without_board(real_pairs[7])]
    with pytest.raises(InputError, match=r"^2 of 4 board poses are usable \(vlp6.jpg:lidar6.ply: the board was not "
                       r"found .*; vlp8.jpg:lidar8.ply: the board was not found .*\); at least 3 are needed") as info:
        solve(pairs)
    assert info.value.input == "poses"


def test_a_cloud_in_millimetres_is_named(real_pairs) -> None:
    pairs = list(real_pairs)
    pairs[1] = replace(pairs[1], points=1000.0 * pairs[1].points)
    with pytest.raises(InputError, match="looks like millimetres, not metres .* scale by 0.001") as info:
        solve(pairs)
    assert info.value.input == "vlp2.jpg:lidar2.ply: cloud"


def test_intrinsics_for_another_image_size_are_refused_with_both_sizes(real_pairs) -> None:
    other = replace(CAMERA, width=1920, height=1080)
    with pytest.raises(InputError, match="the image is 1920x1020 px but the camera's intrinsics are for 1920x1080") \
            as info:
        service.solve_pairs(other, BoardSpec.parse(BOARD), real_pairs, start())
    assert info.value.input == str(VLP16 / "vlp1.jpg")
