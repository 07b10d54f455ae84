"""``calib-studio sweep-corners`` on files: the servo-scanner session's sweeps as the session keeps them (``.npy`` and
its ``.json`` record) and the camera's images, the camera as the ROS YAML ``intrinsics --out`` writes; the corners
method at one pan reading and the pan axis from three, the JSON contract of ../shared/conventions.md (as
``lidar-camera``'s, with the pan axis beside it) and the bad inputs named."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from backend.calib.lidar_camera.sweep_corners_service import pan_reading_deg, sweep_pairs
from backend.core.transforms import transform_error
from backend.exports.ros_camera_info import write_camera_info
from backend.services.demo_servo_scanner import CAMERA_NAME, LIDAR_NAME, SERVO_SCANNER_NAME
from backend.sim.servo_scanner import BOARD
from backend.store.session import SessionStore
from tests.conftest import cli_in_process
from tests.servo_scanner_rig import servo_scanner_sessions, store_far_pair, true_T_camera_lidar

pytestmark = pytest.mark.slow

PER_READING = 2
"""Placements taken per pan reading: enough for the contract (the bars are the service test's, on all of them)."""


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """The folder holding camera.yaml, init.txt (the rig's tape-measured guess) and each pair's sweep and image
    files copied from the session; the ``SWEEP:IMAGE`` arguments by reading, the far board's, and the truth."""
    session = SessionStore(servo_scanner_sessions(tmp_path_factory, "servo_scanner_cli")).get(SERVO_SCANNER_NAME)
    far = store_far_pair(session)
    folder = tmp_path_factory.mktemp("sweep_corners_files")
    write_camera_info(folder / "camera.yaml", session.rig.get(CAMERA_NAME).intrinsics, CAMERA_NAME)
    np.savetxt(folder / "init.txt", session.rig.T_a_b(CAMERA_NAME, LIDAR_NAME))
    captures = session.path / "captures"
    by_reading: dict[float, list[str]] = {}
    for pair in sweep_pairs(session, CAMERA_NAME, LIDAR_NAME):
        for suffix in (".npy", ".json"):
            shutil.copy(captures / LIDAR_NAME / f"{pair.cloud.id}{suffix}", folder / f"sweep{pair.cloud.id}{suffix}")
        shutil.copy(captures / CAMERA_NAME / f"{pair.image.id}.png", folder / f"image{pair.image.id}.png")
        by_reading.setdefault(pan_reading_deg(pair.image), []).append(
            f"sweep{pair.cloud.id}.npy:image{pair.image.id}.png")
    return {"folder": folder, "by_reading": by_reading, "truth": true_T_camera_lidar(session),
            "far": f"sweep{far.cloud.id}.npy:image{far.image.id}.png"}


def _run(files: dict, *args: str) -> tuple[int, dict]:
    """The command in the files' folder with the camera, board and guess; its exit code and JSON."""
    done = cli_in_process("sweep-corners", "--camera", "camera.yaml", "--board", BOARD, *args, "--json",
                          cwd=files["folder"])
    assert len(done.stdout.strip().splitlines()) == 1, (done.stdout, done.stderr)
    return done.returncode, json.loads(done.stdout)


def _sweeps(arguments: list[str]) -> list[str]:
    return [part for argument in arguments for part in ("--sweep", argument)]


def test_the_corners_method_at_one_reading(files: dict) -> None:
    code, summary = _run(files, *_sweeps(files["by_reading"][0.0][:3]), "--init", "init.txt")
    assert code == 0, summary
    assert set(summary) == {"T_camera_lidar", "std", "residuals", "seconds", "verdict", "placements"}
    assert set(summary["std"]) == {"trans_m", "rot_deg"} and summary["verdict"]["level"] in ("trusted", "check")
    assert len(summary["placements"]) == 3 and summary["residuals"]["corners"] > 100
    error_m, error_deg = transform_error(np.array(summary["T_camera_lidar"]), files["truth"])
    assert np.linalg.norm(error_m) < 0.02 and np.linalg.norm(error_deg) < 0.6  # three placements only


def test_the_pan_axis_from_three_readings(files: dict) -> None:
    arguments, readings = [], []
    for reading, pairs in files["by_reading"].items():
        arguments += pairs[:PER_READING]
        readings += ["--pan-deg", f"{reading:g}"] * PER_READING
    code, summary = _run(files, *_sweeps(arguments), *readings, "--init", "init.txt")
    assert code == 0, summary
    assert set(summary) == {"T_camera_lidar", "std", "pan_axis", "residuals", "positions", "verdict", "seconds"}
    assert set(summary["pan_axis"]) == {"axis", "axis_point_m", "axis_sigma_deg", "axis_point_sigma_m"}
    assert sorted(p["pan_deg"] for p in summary["positions"]) == [-45.0, 0.0, 45.0]
    error_m, error_deg = transform_error(np.array(summary["T_camera_lidar"]), files["truth"])
    assert np.linalg.norm(error_m) < 0.02 and np.linalg.norm(error_deg) < 0.6


def test_bad_input_is_named(files: dict) -> None:
    centre = files["by_reading"][0.0]
    code, summary = _run(files, "--sweep", files["far"], "--init", "init.txt")
    assert code == 2 and summary["error"]["input"] == files["far"], summary
    assert "squares span" in summary["error"]["message"]
    cases = [
        (["--sweep", "nope.npy:image00005.png", "--init", "init.txt"], "nope.json"),
        ([*_sweeps(centre[:2]), "--pan-deg", "0", "--init", "init.txt"], "--pan-deg"),
        (_sweeps(centre[:2]), "--init"),
        (["--sweep", centre[0].replace(":", ""), "--init", "init.txt"], "--sweep"),
    ]
    for arguments, named in cases:
        code, summary = _run(files, *arguments)
        assert code == 2 and summary["error"]["input"] == named, (arguments, summary)
