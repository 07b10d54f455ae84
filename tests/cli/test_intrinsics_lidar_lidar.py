"""``calib-studio`` as a subprocess: the --json contract of ../shared/conventions.md, errors, exports. The refusals
run ``main`` in this process (:func:`conftest.cli_in_process`)."""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from backend.calib.intrinsics import service
from backend.calib.intrinsics.solver import IntrinsicsSettings
from backend.calib.rig import service as rig_service
from backend.core.rig import Frame
from backend.exports.ros_camera_info import load_camera_info
from backend.store.session import SessionStore
from tests.conftest import cli_in_process, cli_subprocess

BOARD = "checkerboard:9x6:0.025"


def assert_json_failure(run: subprocess.CompletedProcess) -> dict:
    """Non-zero exit, one 'error:' line last on stderr, ``{"error": {"message", "input"}}`` alone on stdout."""
    assert run.returncode != 0, run.stdout
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("error:"), run.stderr
    assert "\n" not in last
    body = json.loads(run.stdout)
    assert set(body) == {"error"} and set(body["error"]) == {"message", "input"}
    assert run.stdout.strip().count("\n") == 0
    # the stderr line carries the same message
    assert body["error"]["message"] in last
    return body["error"]


def copy_images(paths: list[Path], folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for path in paths:
        shutil.copy(path, folder / path.name)
    return folder


@pytest.fixture(scope="module")
def intrinsics_run(left_images, tmp_path_factory) -> tuple[subprocess.CompletedProcess, Path]:
    work = tmp_path_factory.mktemp("cli_intrinsics")
    images = copy_images(left_images, work / "images")
    run = cli_subprocess("intrinsics", images, "--board", BOARD, "--json", "--fix-aspect", "--k3",
                         "--out", "camera.yaml", cwd=work)
    return run, work


@pytest.mark.slow
def test_intrinsics_json_contract(intrinsics_run):
    run, _ = intrinsics_run
    assert run.returncode == 0, run.stderr
    lines = [line for line in run.stdout.splitlines() if line.strip()]
    assert len(lines) == 1, run.stdout
    out = json.loads(run.stdout)
    assert isinstance(out, dict)
    assert set(out) == {"camera", "rms_px", "views", "std", "correlation", "projection_sigma_px", "corners",
                        "cross_validation", "model_comparison", "verdict", "seconds", "rejected_corners",
                        "views_dropped", "board_flex", "jackknife"}
    assert out["rejected_corners"] == 0 and out["views_dropped"] == []  # OpenCV's clean set (mrcal rejects none)
    assert out["model_comparison"] is None  # only with --model auto
    assert out["verdict"]["level"] == "trusted" and out["verdict"]["reasons"]  # where the boards reach (44 %)
    assert out["board_flex"]["status"] == "solved" and len(out["board_flex"]["std_mm"]) == 2
    assert out["jackknife"]["ratio"] > 1
    assert out["cross_validation"]["status"] == "consistent" and "difference_px" not in out["cross_validation"]
    fits = out["corners"]["rms_px"]
    assert set(fits) == {"sb", "refined-0.3", "refined-0.4", "refined-0.5"}
    assert out["corners"]["chosen"] == min(fits, key=fits.get)
    assert set(out["projection_sigma_px"]) == {"max", "mean", "centre"}

    camera = out["camera"]
    assert set(camera) == {"model", "width", "height", "K", "dist"}
    assert camera["model"] == "pinhole-radtan" and (camera["width"], camera["height"]) == (640, 480)
    K = np.array(camera["K"])
    assert K.shape == (3, 3) and K[2].tolist() == [0, 0, 1]
    assert K[0, 0] == pytest.approx(K[1, 1])  # --fix-aspect
    assert 500 < K[0, 0] < 570 and 300 < K[0, 2] < 380 and 200 < K[1, 2] < 280
    assert len(camera["dist"]) == 5 and camera["dist"][4] != 0.0  # --k3 estimated

    assert 0 < out["rms_px"] < 0.5
    assert len(out["views"]) == 13
    for view in out["views"]:
        assert set(view) == {"image", "rms_px", "used", "rejected_corners"}
        assert view["used"] is True and 0 < view["rms_px"] < 1.0 and view["rejected_corners"] == 0
    assert sorted(v["image"] for v in out["views"]) == sorted(f"left{i:02d}.jpg" for i in (*range(1, 10), 11, 12,
                                                                                            13, 14))

    std = out["std"]
    assert set(std) == {"fx", "fy", "cx", "cy", "dist"}
    assert all(0 < std[k] < 5 for k in ("fx", "fy", "cx", "cy"))
    assert len(std["dist"]) == 5 and all(s > 0 for s in std["dist"])

    corr = out["correlation"]
    assert set(corr) == {"names", "matrix"}
    n = len(corr["names"])
    assert n >= 8 and {"fx", "cx", "cy", "k1", "k2", "k3"} <= set(corr["names"])
    matrix = np.array(corr["matrix"])
    assert matrix.shape == (n, n)
    np.testing.assert_allclose(np.diag(matrix), 1.0, atol=1e-9)
    np.testing.assert_allclose(matrix, matrix.T, atol=1e-9)
    assert out["seconds"] > 0


@pytest.mark.slow
def test_intrinsics_model_auto_says_which_model_won_and_why(left_images, tmp_path: Path):
    run = cli_subprocess("intrinsics", copy_images(left_images, tmp_path / "images"), "--board", BOARD,
                         "--model", "auto", "--fix-aspect", "--json")
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    comparison = out["model_comparison"]
    assert comparison["status"] == "compared"
    models = [c["model"] for c in comparison["candidates"]]
    assert models == ["pinhole-radtan k1-k2", "fisheye-equidistant", "pinhole-radtan k1-k3", "photogrammetric",
                      "pinhole-rational", "splined-stereographic"]
    assert all(0 < c["held_out_rms_px"] < 0.5 for c in comparison["candidates"])
    winner = next(c for c in comparison["candidates"] if c["recommended"])
    assert comparison["recommended"] == winner["model"] and comparison["reason"].startswith(winner["model"])
    assert out["camera"]["model"] == winner["model"].split(" ")[0]
    assert out["verdict"]["level"] in ("trusted", "check", "reject")


@pytest.mark.slow
def test_intrinsics_can_hold_the_board_flat_and_keep_every_corner(intrinsics_run):
    """``--flat-board`` and ``--keep-outlier-corners``: OpenCV's own problem (a flat board, every corner), so the fit
    is the flat board's, worse than with the flex the default solves (the contract test's run); the camera JSON
    says so as the JSON output does."""
    default, work = intrinsics_run
    run = cli_in_process("intrinsics", work / "images", "--board", BOARD, "--json", "--fix-aspect", "--k3",
                         "--flat-board", "--keep-outlier-corners", "--out", work / "flat.json")
    assert run.returncode == 0, run.stderr
    flat = json.loads(run.stdout)
    assert flat["board_flex"] == {"status": "not solved", "warp_mm": [0.0, 0.0], "std_mm": None,
                                  "detail": "switched off"}
    assert flat["rms_px"] > json.loads(default.stdout)["rms_px"] + 0.005
    assert json.loads((work / "flat.json").read_text())["board_flex"] == flat["board_flex"]  # the camera JSON too


@pytest.mark.slow
def test_intrinsics_progress_on_stderr_and_yaml_written(intrinsics_run):
    run, work = intrinsics_run
    assert run.returncode == 0, run.stderr
    assert "detecting the target" in run.stderr and "%]" in run.stderr
    assert "detecting" not in run.stdout and "%]" not in run.stdout
    out = json.loads(run.stdout)
    camera, name = load_camera_info(work / "camera.yaml")
    assert name == "camera"
    assert (camera.width, camera.height) == (640, 480)
    np.testing.assert_allclose(camera.K, out["camera"]["K"], rtol=1e-12)
    np.testing.assert_allclose(camera.dist, out["camera"]["dist"], rtol=1e-12)


def test_for_an_export_applies_to_model_auto_only(left_images, tmp_path: Path):
    folder = copy_images(left_images[:3], tmp_path / "three")
    error = assert_json_failure(cli_in_process("intrinsics", folder, "--board", BOARD, "--for", "kalibr", "--json"))
    assert error == {"message": "--for kalibr chooses among models: it applies to --model auto, not --model "
                                "pinhole-radtan", "input": "for"}


def test_too_few_images(left_images, tmp_path: Path):
    folder = copy_images(left_images[:2], tmp_path / "two")
    error = assert_json_failure(cli_in_process("intrinsics", folder, "--board", BOARD, "--json"))
    assert "at least 3" in error["message"] or "only 2" in error["message"]


def test_truncated_jpeg_among_good(left_images, tmp_path: Path):
    folder = copy_images(left_images[:5], tmp_path / "mixed")
    data = left_images[5].read_bytes()
    (folder / "broken.jpg").write_bytes(data[: int(len(data) * 0.6)])
    run = cli_in_process("intrinsics", folder, "--board", BOARD, "--json")
    error = assert_json_failure(run)
    assert "broken.jpg" in error["message"] and error["input"].endswith("broken.jpg")
    assert "broken.jpg" in run.stderr.strip().splitlines()[-1]


def test_truncated_jpeg_without_json(left_images, tmp_path: Path):
    folder = copy_images(left_images[:5], tmp_path / "mixed")
    data = left_images[5].read_bytes()
    (folder / "broken.jpg").write_bytes(data[: int(len(data) * 0.6)])
    run = cli_in_process("intrinsics", folder, "--board", BOARD)
    assert run.returncode != 0 and run.stdout == ""
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("error:") and "broken.jpg" in last


@pytest.mark.slow
def test_wrong_board_size(left_images, tmp_path: Path):
    folder = copy_images(left_images[:3], tmp_path / "images")  # as few as a solve takes: each is searched in vain
    error = assert_json_failure(cli_in_process("intrinsics", folder, "--board", "checkerboard:7x6:0.025", "--json"))
    assert "checkerboard:7x6:0.025" in error["message"] and "board spec" in error["message"]


def test_malformed_board_spec(left_images, tmp_path: Path):
    folder = copy_images(left_images[:3], tmp_path / "images")
    error = assert_json_failure(cli_in_process("intrinsics", folder, "--board", "checkerboard:9by6", "--json"))
    assert error["input"] == "board" and "board" in error["message"] and "checkerboard:9by6" in error["message"]


def test_missing_folder(tmp_path: Path):
    missing = tmp_path / "no_such_folder"
    error = assert_json_failure(cli_in_process("intrinsics", missing, "--board", BOARD, "--json"))
    assert str(missing) in error["message"]


@pytest.mark.slow
def test_all_views_alike(left_images, tmp_path: Path):
    folder = tmp_path / "same"
    folder.mkdir()
    for i in range(5):
        shutil.copy(left_images[0], folder / f"shot{i}.jpg")
    error = assert_json_failure(cli_in_process("intrinsics", folder, "--board", BOARD, "--json"))
    assert "nearly the same place" in error["message"] and "move and tilt" in error["message"]
    assert error["input"] == "views"


@pytest.mark.slow
def test_export_camera_info_from_session(left_images, tmp_path: Path):
    store = SessionStore(tmp_path / "sessions")
    session = store.create("bench", board=BOARD)
    session.add_sensor(Frame("cam_left", "base_link", kind="camera"))
    report = service.import_images(session, "cam_left", [(p.name, p.read_bytes()) for p in left_images])
    assert len(report.added) == 13
    result_id, result = service.solve_session(session, "cam_left", IntrinsicsSettings())
    # 13 VGA views pin the lens where their boards reach (the image corners' looser sigma is named): trusted
    assert result.verdict.level == "trusted", result.verdict
    rig_service.accept(session, result_id)

    run = cli_in_process("export", session.path, "--format", "camera_info", "--sensor", "cam_left")
    assert run.returncode == 0, run.stderr
    doc = yaml.safe_load(run.stdout)
    assert doc["camera_name"] == "cam_left" and doc["image_width"] == 640 and doc["image_height"] == 480
    np.testing.assert_allclose(doc["camera_matrix"]["data"], result.camera.K.ravel(), rtol=1e-12)

    out = tmp_path / "cam_left.yaml"
    run = cli_in_process("export", session.path, "--format", "camera_info", "--sensor", "cam_left", "--out", out)
    assert run.returncode == 0 and run.stdout == ""
    camera, _ = load_camera_info(out)
    np.testing.assert_allclose(camera.K, result.camera.K, rtol=1e-12)

    # a camera without an accepted result: non-zero exit, one error line naming it
    session.add_sensor(Frame("cam_right", "base_link", kind="camera"))
    run = cli_in_process("export", session.path, "--format", "camera_info", "--sensor", "cam_right")
    assert run.returncode != 0 and run.stdout == ""
    assert run.stderr.strip().splitlines()[-1].startswith("error: cam_right")


def test_the_photogrammetric_model_is_refused_for_camera_info_before_any_work(left_images, tmp_path: Path):
    folder = copy_images(left_images[:3], tmp_path / "three")
    error = assert_json_failure(cli_in_process("intrinsics", folder, "--board", BOARD, "--model", "photogrammetric",
                                               "--out", str(tmp_path / "camera.yaml"), "--json"))
    assert error == {"message": f"--out {tmp_path / 'camera.yaml'} is ROS camera_info YAML, which cannot carry the "
                                "photogrammetric model; write the camera JSON instead (--out camera.json)",
                     "input": "out"}
    error = assert_json_failure(cli_in_process("intrinsics", folder, "--board", BOARD, "--model", "photogrammetric",
                                               "--pixel-size-um", "-4.8", "--json"))
    assert error["input"] == "pixel-size-um" and "pixel pitch in micrometres" in error["message"]


@pytest.mark.slow
def test_the_photogrammetric_model_in_mm_to_camera_json(left_images, tmp_path: Path):
    from backend.exports.camera_json import load_camera

    folder = copy_images(left_images[:6], tmp_path / "images")  # six views: the fewest the two halves need
    run = cli_in_process("intrinsics", folder, "--board", BOARD, "--model", "photogrammetric", "--pixel-size-um", "6",
                         "--out", str(tmp_path / "camera.json"), "--json")
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    camera, name = load_camera(tmp_path / "camera.json")
    assert name == "camera" and camera.model == out["camera"]["model"] == "photogrammetric"
    np.testing.assert_array_equal(camera.dist, out["camera"]["dist"])
    c = out["photogrammetric"]["parameters"]["c"]
    assert c["value_mm"] == pytest.approx(c["value_px"] * 0.006)
    assert c["sigma_mm"] == pytest.approx(c["sigma_px"] * 0.006)
    saved = json.loads((tmp_path / "camera.json").read_text())
    assert saved["photogrammetric"] == out["photogrammetric"] and saved["std"] == out["std"]


def test_the_splined_model_options_are_checked_before_any_work(left_images, tmp_path: Path):
    folder = copy_images(left_images[:3], tmp_path / "three")
    error = assert_json_failure(cli_in_process("intrinsics", folder, "--board", BOARD, "--model",
                                               "splined-stereographic", "--out", str(tmp_path / "camera.yaml"),
                                               "--json"))
    assert error["input"] == "out" and "cannot carry the splined-stereographic model" in error["message"]
    error = assert_json_failure(cli_in_process("intrinsics", folder, "--board", BOARD, "--model",
                                               "splined-stereographic", "--spline-knots", "12by10", "--json"))
    assert error == {"message": "--spline-knots is '12by10'; expected the knots across and down as NXxNY, e.g. 12x10",
                     "input": "spline-knots"}
    error = assert_json_failure(cli_in_process("intrinsics", folder, "--board", BOARD, "--spline-fov", "80", "--json"))
    assert error["input"] == "spline-fov" and "--model pinhole-radtan" in error["message"]


@pytest.mark.slow
def test_the_splined_model_to_camera_json(left_images, tmp_path: Path):
    """mrcal's knots for the set (12x10 over 80 degrees): the JSON names mrcal's model, the knots no corner reaches
    and the OpenCV model fitted to it; the camera JSON loads back as the same splined camera."""
    from backend.exports.camera_json import load_camera

    folder = copy_images(left_images, tmp_path / "images")
    run = cli_in_process("intrinsics", folder, "--board", BOARD, "--model", "splined-stereographic",
                         "--spline-knots", "12x10", "--spline-fov", "80", "--out", str(tmp_path / "camera.json"),
                         "--json")
    assert run.returncode == 0, run.stderr
    out = json.loads(run.stdout)
    spline = out["splined"]
    assert spline["lensmodel"] == "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=12_Ny=10_fov_x_deg=80"
    assert 0 < spline["unconstrained_knots"] < spline["knots_under_image"] <= 120
    assert len(spline["unconstrained_map"]) == 10 and spline["opencv"]["max_residual_px"] > 0
    assert out["correlation"] == {"names": [], "matrix": []} and len(out["std"]["dist"]) == 240
    camera, _ = load_camera(tmp_path / "camera.json")
    assert camera.model == "splined-stereographic" and (camera.spline.nx, camera.spline.ny) == (12, 10)
    np.testing.assert_array_equal(camera.dist, out["camera"]["dist"])
    assert json.loads((tmp_path / "camera.json").read_text())["splined"] == spline
    text = cli_in_process("intrinsics", folder, "--board", BOARD, "--model", "splined-stereographic",
                          "--spline-knots", "12x10", "--spline-fov", "80")
    assert text.returncode == 0 and "the OpenCV model fitted to it" in text.stdout, text.stderr
