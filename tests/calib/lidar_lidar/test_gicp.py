"""LiDAR-to-LiDAR registration: simulated pairs with ground truth, bad input, the real OpenCalib pair, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.calib.lidar_lidar.gicp import LidarLidarSettings, evaluate_alignment, register_pair
from backend.core.clouds import check_cloud
from backend.core.errors import InputError
from backend.core.result import TransformResult
from backend.core.transforms import (
    check_transform,
    invert,
    make_T,
    rotation_angle_deg,
    to_xyz_ypr,
    transform_error,
    transform_points,
)
from tests.calib.lidar_lidar.conftest import PLACEMENTS, SCENE_KEYS, T_TRUE, perturbed, scan_pair
from tests.conftest import SHARED_DATA, cli_in_process, cli_subprocess

REAL_PAIR = SHARED_DATA / "opencalib_lidar2lidar_pair"
SUMMARY_KEYS = {"T_target_source", "fitness", "rmse_m", "c2c_m", "std", "seconds", "verdict", "scenes", "scene_spread"}
"""The CLI's JSON (conventions.md)."""

def assert_recovered(result, T_true: np.ndarray) -> None:
    """Within 5 mm and 0.1 deg of the truth, and every axis's error below 3 reported sigmas."""
    assert result.converged, result.warnings
    err_t, err_r_deg = transform_error(result.T_parent_child, T_true)
    assert np.linalg.norm(err_t) < 0.005, err_t
    assert rotation_angle_deg(invert(T_true)[:3, :3] @ result.T_parent_child[:3, :3]) < 0.1, err_r_deg
    error = np.r_[err_t, np.radians(err_r_deg)]
    assert np.all(np.abs(error) < 3 * result.std_vector), (error, result.std_vector)


# --- simulated pairs --------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_recovers_simulated_pair_from_20cm_10deg(scene, seed: int) -> None:
    source, target = scan_pair(scene, seed)
    T_init = perturbed(T_TRUE, seed, 0.20, 10.0)
    result = register_pair(source, target, T_init)
    assert_recovered(result, T_TRUE)
    diagnostics, residuals = result.diagnostics, result.residuals
    assert diagnostics["spread_source"] == "sectors" and diagnostics["init_method"] == "given"
    max_m = result.settings["max_correspondence_m"]
    assert residuals["fitness"] > 0.5 and 0 < residuals["rmse_m"] < max_m
    c2c = residuals["c2c_m"]
    assert 0 < c2c["median"] <= c2c["p95"] <= max_m and c2c["std"] > 0
    # the reported sigma is the larger of the Hessian's and the sector spread's, per axis
    np.testing.assert_allclose(result.std_vector, np.fmax(diagnostics["std_hessian"], diagnostics["std_spread"]))


def test_result_is_a_transform_result_whose_record_is_json(scene) -> None:
    source, target = scan_pair(scene, 3)
    result = register_pair(source, target, perturbed(T_TRUE, 3, 0.05, 2.0), LidarLidarSettings(spread=False))
    assert isinstance(result, TransformResult)
    assert (result.kind, result.method, result.parent, result.child) == ("lidar_lidar", "gicp", "target", "source")
    assert set(result.residuals) == {"fitness", "rmse_m", "c2c_m"}
    assert set(result.residuals["c2c_m"]) == {"mean", "median", "p95", "std"}
    assert set(result.diagnostics) == {"scenes", "scene_spread", "std_hessian", "std_spread", "spread_source",
                                       "T_init", "init_method", "iterations", "num_inliers"}
    assert result.diagnostics["std_spread"] is None and result.diagnostics["spread_source"] is None
    assert result.diagnostics["num_inliers"] > 6 and result.diagnostics["iterations"] >= 1
    np.testing.assert_allclose(result.diagnostics["T_init"], perturbed(T_TRUE, 3, 0.05, 2.0))
    record = json.loads(json.dumps(result.to_record(), allow_nan=False))
    assert record["kind"] == "lidar_lidar" and record["converged"] is True
    assert np.array(record["covariance"]).shape == (6, 6) and record["settings"]["num_threads"] == 2
    # sigma reported in degrees about the source axes = sqrt of the rotation block of the covariance (rad)
    assert np.allclose(np.degrees(np.sqrt(np.diag(result.covariance)[3:])), record["std"]["rot_deg"])
    # without the spread, the sigma is the Hessian's
    np.testing.assert_allclose(result.std_vector, result.diagnostics["std_hessian"])
    back = TransformResult.from_record(record)
    np.testing.assert_allclose(back.T_parent_child, result.T_parent_child)
    np.testing.assert_allclose(back.covariance, result.covariance)
    assert back.verdict.to_dict() == result.verdict.to_dict()
    # one scene: no cross-check, so never more than 'check', whatever the sigmas
    assert record["verdict"]["level"] == "check"
    assert "no cross-check across scenes: only one scene: capture the rig in two more places" in \
        record["verdict"]["reasons"]
    scenes = record["diagnostics"]["scenes"]
    assert len(scenes) == 1 and scenes[0]["agrees"] is None and record["diagnostics"]["scene_spread"] is None
    np.testing.assert_allclose(scenes[0]["T_target_source"], result.T_parent_child)
    named = result.named("lidar_top", "lidar_front")
    assert (named.parent, named.child) == ("lidar_top", "lidar_front") and named.residuals == result.residuals


@pytest.mark.slow
def test_global_initial_guess_when_none_is_given(scene) -> None:
    source, target = scan_pair(scene, 4)
    result = register_pair(source, target, None)
    assert result.diagnostics["init_method"] == "global" and any("global registration" in w for w in result.warnings)
    assert_recovered(result, T_TRUE)


# --- bad input ----------------------------------------------------------------------------------------------------


def test_bad_clouds_raise_input_error_naming_the_cloud() -> None:
    good = np.random.default_rng(0).uniform(-5, 5, (500, 3))
    with pytest.raises(InputError, match="empty") as exc:
        register_pair(np.zeros((0, 3)), good, np.eye(4), source_name="a.pcd")
    assert exc.value.input == "a.pcd"
    with pytest.raises(InputError, match="finite") as exc:
        register_pair(good, np.full((100, 3), np.nan), np.eye(4), target_name="b.pcd")
    assert exc.value.input == "b.pcd"
    with pytest.raises(InputError, match="finite"):
        register_pair(good, np.where(np.arange(100)[:, None] % 2, np.inf, np.nan) * np.ones((100, 3)), np.eye(4))
    with pytest.raises(InputError, match="millimetres") as exc:
        register_pair(good * 1000.0, good, np.eye(4))
    assert exc.value.input == "source"
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        register_pair(good[:, :2], good, np.eye(4))
    with pytest.raises(InputError, match="not a rotation") as exc:
        register_pair(good, good, np.diag([1.0, 1.0, 2.0, 1.0]))
    assert exc.value.input == "T_init"
    with pytest.raises(InputError, match="4x4"):
        register_pair(good, good, np.eye(3))


def test_some_non_finite_points_are_dropped_with_a_warning(scene) -> None:
    source, target = scan_pair(scene, 5)
    source = source.copy()
    source[::50] = np.nan
    result = register_pair(source, target, T_TRUE, LidarLidarSettings(spread=False))
    assert result.converged
    assert any("dropped" in w and "non-finite" in w for w in result.warnings)
    assert check_cloud(source, "s")[1] == len(source[::50])


def test_no_overlap_is_not_converged_and_says_so(scene) -> None:
    source, target = scan_pair(scene, 6)
    far = make_T(np.eye(3), [200.0, 0.0, 0.0]) @ T_TRUE  # the source lands 200 m away from anything
    result = register_pair(source, target, far)
    assert not result.converged
    assert result.residuals["fitness"] < 0.01
    assert any("do not overlap" in w for w in result.warnings)
    assert result.verdict.level == "reject" and "do not overlap" in result.verdict.reasons[0]
    json.dumps(result.to_record(), allow_nan=False)  # undetermined sigmas are null, not NaN


def test_poor_fit_below_min_fitness_is_not_converged(scene) -> None:
    source, target = scan_pair(scene, 6)
    result = register_pair(source, target, T_TRUE, LidarLidarSettings(min_fitness=0.99, spread=False))
    assert not result.converged and any("poor fit" in w for w in result.warnings)


def test_slightly_non_orthonormal_init_is_projected_with_a_warning() -> None:
    T = make_T(0.99 * Rotation.from_euler("z", 60, degrees=True).as_matrix(), [1, 2, 3])
    fixed, deviation = check_transform(T, "T")
    assert 0.01 < deviation < 0.05
    assert np.allclose(fixed[:3, :3].T @ fixed[:3, :3], np.eye(3))
    assert rotation_angle_deg(fixed[:3, :3]) == pytest.approx(60.0)


# --- the real OpenCalib pair --------------------------------------------------------------------------------------


def read_reference() -> np.ndarray:
    data = json.loads((REAL_PAIR / "p64-to-qt-extrinsic.json").read_text())
    return np.array(next(iter(data.values()))["param"]["sensor_calib"]["data"], dtype=float)


@pytest.mark.slow
def test_real_pair_p64_to_qt() -> None:
    """OpenCalib's p64 -> qt pair: ~60 deg apart, partial overlap, 77k vs 12k points.

    Findings (see the report): the stored reference is not rigid: its 3x3 is a rotation scaled
    by 0.989 (|R^T R - I| = 0.021), so at 30 m range it is off by ~0.3 m. That is why
    Open3D's ``evaluate_registration`` gives 0.124 with it, against 0.153 for the same matrix
    projected onto a rotation. From the (rigid) reference perturbed by 5 cm / 2 deg, GICP
    returns within 0.7 deg of it, but 13-16 cm from it along the qt z axis. The refinement
    is the better fit: higher fitness at 0.2 m, the p64 ground lying 2-3 cm from qt's ground
    plane where the reference puts it 8-10 cm above, and Open3D's own GICP agreeing with it
    to a few cm. So the 5 cm translation check is made against that evidence, not the
    reference; the rotation check stays at 1 deg from the reference.
    """
    from backend.devices.cloud_files import read_cloud

    source = read_cloud(REAL_PAIR / "p64.pcd").points
    target = read_cloud(REAL_PAIR / "qt.pcd").points
    T_raw = read_reference()
    T_ref, deviation = check_transform(T_raw, "reference")
    assert deviation == pytest.approx(0.0215, abs=0.001)
    fitness_raw = evaluate_alignment(source, target, T_raw, 0.2)["fitness"]
    fitness_ref = evaluate_alignment(source, target, T_ref, 0.2)["fitness"]
    assert fitness_raw == pytest.approx(0.124, abs=0.002)

    results = [register_pair(source, target, perturbed(T_ref, seed, 0.05, 2.0), LidarLidarSettings(spread=seed == 0))
               for seed in range(2)]
    for result in results:
        assert result.converged, result.warnings
        err_t, _ = transform_error(result.T_parent_child, T_ref)
        assert rotation_angle_deg(T_ref[:3, :3].T @ result.T_parent_child[:3, :3]) < 1.0
        assert np.all(np.abs(err_t[:2]) < 0.05) and abs(err_t[2]) < 0.2, err_t
        assert evaluate_alignment(source, target, result.T_parent_child, 0.2)["fitness"] >= fitness_ref + 0.01
    # the same answer from different starts
    spread_t, spread_r = transform_error(results[1].T_parent_child, results[0].T_parent_child)
    assert np.all(np.abs(spread_t) < 0.01) and np.all(np.abs(spread_r) < 0.05)
    T = results[0].T_parent_child
    assert results[0].std_vector[:3].max() < 0.1  # a few cm: the honest spread on this hard pair
    # its verdict: one scene and sigmas of a few cm / 0.4 deg, so 'check', saying both
    verdict = results[0].verdict
    assert verdict.level == "check", verdict.reasons
    assert any(r.startswith("translation sigma") and "above the tolerance" in r for r in verdict.reasons)
    assert any("no cross-check across scenes: only one scene" in r for r in verdict.reasons)

    # ground: p64's ground points against qt's dominant plane (the ground), along its normal
    import open3d as o3d

    target_o3d = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target))
    o3d.utility.random.seed(0)
    plane, inliers = target_o3d.segment_plane(0.03, 3, 2000)
    ground = target[inliers]
    normal, offset = np.array(plane[:3]), plane[3]

    def ground_gap(T_target_source: np.ndarray) -> float:
        from scipy.spatial import cKDTree

        aligned = transform_points(T_target_source, source)
        d, _ = cKDTree(ground).query(aligned, distance_upper_bound=0.3)
        signed = aligned[np.isfinite(d)] @ normal + offset
        return float(np.median(signed[np.abs(signed) < 0.3]))

    assert abs(ground_gap(T)) < 0.04 < abs(ground_gap(T_ref)), (ground_gap(T), ground_gap(T_ref))

    # an independent implementation lands within a few cm of the refinement
    reg = o3d.pipelines.registration
    clouds = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(p)).voxel_down_sample(0.1) for p in (source, target)]
    o3d_gicp = reg.registration_generalized_icp(clouds[0], clouds[1], 0.5, T_ref,
                                                reg.TransformationEstimationForGeneralizedICP(),
                                                reg.ICPConvergenceCriteria(max_iteration=100))
    diff_t, diff_r = transform_error(np.asarray(o3d_gicp.transformation), T)
    assert np.all(np.abs(diff_t) < 0.05) and np.all(np.abs(diff_r) < 0.3), (diff_t, diff_r)


# --- the CLI ------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def cloud_files(scene, tmp_path_factory) -> tuple[Path, Path]:
    folder = tmp_path_factory.mktemp("lidar_lidar")
    source, target = scan_pair(scene, 8)
    np.save(folder / "source.npy", source)
    np.save(folder / "target.npy", target)
    return folder / "source.npy", folder / "target.npy"


@pytest.mark.slow
def test_cli_json_with_init_xyzypr(cloud_files: tuple[Path, Path]) -> None:
    xyz, ypr = to_xyz_ypr(perturbed(T_TRUE, 9, 0.10, 5.0))
    init = ",".join(f"{v:.6f}" for v in [*xyz, *np.degrees(ypr)])
    run = cli_subprocess("lidar-lidar", *cloud_files, "--init-xyzypr", init, "--json")
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().count("\n") == 0  # exactly one JSON object, progress on stderr
    body = json.loads(run.stdout)
    assert set(body) == SUMMARY_KEYS
    assert set(body["c2c_m"]) == {"mean", "median", "p95", "std"}
    assert set(body["std"]) == {"trans_m", "rot_deg"}
    assert all(len(body["std"][k]) == 3 for k in ("trans_m", "rot_deg"))
    err_t, err_r = transform_error(np.array(body["T_target_source"]), T_TRUE)
    assert np.linalg.norm(err_t) < 0.005 and np.abs(err_r).max() < 0.1
    assert "fine GICP" in run.stderr


@pytest.mark.slow
def test_cli_json_is_the_contract(cloud_files: tuple[Path, Path], tmp_path: Path, capsys) -> None:
    """In process: exactly the keys of conventions.md, each from the solver's TransformResult, on one line."""
    from studio.cli import main

    init = tmp_path / "T.txt"
    np.savetxt(init, perturbed(T_TRUE, 9, 0.02, 1.0))
    assert main(["lidar-lidar", str(cloud_files[0]), str(cloud_files[1]), "--init", str(init), "--json"]) == 0
    out = capsys.readouterr().out
    assert out.strip().count("\n") == 0
    body = json.loads(out)
    assert set(body) == SUMMARY_KEYS and set(body["c2c_m"]) == {"mean", "median", "p95", "std"}
    assert set(body["std"]) == {"trans_m", "rot_deg"} and all(len(body["std"][k]) == 3 for k in body["std"])
    assert 0 < body["fitness"] <= 1 and 0 < body["c2c_m"]["median"] <= body["c2c_m"]["p95"] <= 0.2
    err_t, err_r = transform_error(np.array(body["T_target_source"]), T_TRUE)
    assert np.linalg.norm(err_t) < 0.005 and np.abs(err_r).max() < 0.1
    assert [set(scene) for scene in body["scenes"]] == [SCENE_KEYS] and body["scene_spread"] is None
    assert body["verdict"]["level"] == "check" and body["seconds"] > 0


def test_cli_bad_init_file_and_mm_cloud(cloud_files: tuple[Path, Path], tmp_path: Path) -> None:
    bad = tmp_path / "T.txt"
    bad.write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n")
    run = cli_in_process("lidar-lidar", *cloud_files, "--init", bad, "--json")
    assert run.returncode != 0
    body = json.loads(run.stdout)
    assert body["error"]["input"] == str(bad) and "4x4" in body["error"]["message"]
    assert run.stderr.strip().splitlines()[-1].startswith("error:")

    good = tmp_path / "T_good.txt"
    np.savetxt(good, T_TRUE)
    mm = tmp_path / "mm.npy"
    np.save(mm, np.load(cloud_files[0]) * 1000.0)
    run = cli_in_process("lidar-lidar", mm, cloud_files[1], "--init", good, "--json")
    assert run.returncode != 0
    body = json.loads(run.stdout)
    assert body["error"]["input"] == str(mm) and "millimetres" in body["error"]["message"]

    run = cli_in_process("lidar-lidar", *cloud_files, "--init-xyzypr", "1,2,3", "--json")
    assert run.returncode != 0 and json.loads(run.stdout)["error"]["input"] == "--init-xyzypr"


@pytest.mark.slow
def test_cli_pairs_of_two_scenes_with_a_negative_init_after_a_space(scene, tmp_path: Path) -> None:
    """``--pair`` per scene, and ``--init-xyzypr -0.7,...`` (a value that starts with '-') after a space.

    Source and target are swapped here, so the initial T_target_source is the inverse of T_TRUE: x < 0."""

    args = []
    for i, placement in enumerate(PLACEMENTS[:2]):
        source, target = scan_pair(scene, 30 + i, placement)
        np.save(tmp_path / f"front{i}.npy", source)
        np.save(tmp_path / f"top{i}.npy", target)
        args += ["--pair", f"{tmp_path / f'top{i}.npy'}:{tmp_path / f'front{i}.npy'}"]
    T_true = invert(T_TRUE)
    xyz, ypr = to_xyz_ypr(perturbed(T_true, 9, 0.05, 3.0))
    init = ",".join(f"{v:.6f}" for v in [*xyz, *np.degrees(ypr)])
    assert init.startswith("-")
    run = cli_in_process("lidar-lidar", *args, "--init-xyzypr", init, "--json")
    assert run.returncode == 0, run.stderr
    body = json.loads(run.stdout)
    assert set(body) == SUMMARY_KEYS and len(body["scenes"]) == 2 and set(body["scenes"][0]) == SCENE_KEYS
    assert [scene["pairs"] for scene in body["scenes"]] == [[0], [1]]
    err_t, err_r = transform_error(np.array(body["T_target_source"]), T_true)
    assert np.linalg.norm(err_t) < 0.005 and np.abs(err_r).max() < 0.1
    assert body["verdict"]["level"] in ("trusted", "check")
    assert any(r.startswith("cross-check across scenes") for r in body["verdict"]["reasons"])
    assert "verdict:" in run.stderr


def test_cli_negative_values_after_a_space_reach_the_command(tmp_path: Path) -> None:
    """argparse alone takes ``-0.07,...`` for an unknown option; every subcommand now takes it as the value."""
    missing = tmp_path / "missing.npy"
    run = cli_in_process("lidar-lidar", missing, missing, "--init-xyzypr", "-0.07,0.63,-0.35,90,0,0", "--json")
    assert run.returncode != 0 and "expected one argument" not in run.stderr
    assert json.loads(run.stdout)["error"]["input"] == str(missing)
    run = cli_in_process("lidar-camera", "--camera", tmp_path / "none.yaml", "--pair", "a.png:b.npy",
                         "--init-xyzypr", "-0.07,0.63,-0.35,90,0,0", "--json")
    assert run.returncode != 0 and "expected one argument" not in run.stderr
    assert json.loads(run.stdout)["error"]["input"] == str(tmp_path / "none.yaml")
    run = cli_in_process("lidar-lidar", "--init-xyzypr", "-1,2", missing, missing, "--json")
    assert json.loads(run.stdout)["error"]["input"] == "--init-xyzypr"  # parsed as the value, then refused


def test_cli_pair_and_positional_clouds_are_exclusive(cloud_files: tuple[Path, Path]) -> None:
    run = cli_in_process("lidar-lidar", *cloud_files, "--pair", f"{cloud_files[0]}:{cloud_files[1]}", "--json")
    assert run.returncode != 0 and json.loads(run.stdout)["error"]["input"] == "--pair"
    run = cli_in_process("lidar-lidar", "--pair", str(cloud_files[0]), "--json")
    assert json.loads(run.stdout)["error"]["message"].startswith("expected SRC:TGT")
