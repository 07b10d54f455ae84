"""``calib-studio`` error paths (issue 12, item 7): every failure is the one-line error (and the JSON error with
``--json``); output paths are refused before the solve; an output that fails after the solve loses no result;
echoed values are truncated; YAML alias, size and nesting bombs are refused. The refusals run ``main`` in this
process (:func:`conftest.cli_in_process`); an argument error and the outputs failing after a solve run the command
as a subprocess."""

from __future__ import annotations

import json
import re
import stat
import subprocess
from pathlib import Path

import numpy as np
import pytest

from backend.cli import intrinsics as intrinsics_cli
from backend.core.errors import InputError, shorten
from backend.exports.rig_transforms import load_rig_transforms
from backend.exports.ros_camera_info import dump_camera_info, load_camera_info
from backend.sim.demo_rig import CAM_FRONT
from backend.store.session import SessionStore
from studio import cli as cli_module
from tests.cli.test_intrinsics_lidar_lidar import BOARD, assert_json_failure, copy_images
from tests.conftest import cli_in_process, cli_subprocess

PAIR = "board.png:board.pcd"  # never read: every refusal below comes first


def assert_plain_failure(run: subprocess.CompletedProcess) -> str:
    """Without --json: non-zero exit, nothing on stdout, the one 'error:' line last on stderr; returns that line."""
    assert run.returncode != 0 and run.stdout == "", (run.stdout, run.stderr)
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("error: "), run.stderr
    return last


@pytest.fixture()
def images(left_images, tmp_path: Path) -> Path:
    """Six real views: enough for a full intrinsics solve (with its cross-validation) in a few seconds."""
    return copy_images(left_images[:6], tmp_path / "images")


# -- output paths refused before the solve -------------------------------------------------------------------------

def _unwritable_outputs(tmp_path: Path) -> dict[str, tuple[Path, str]]:
    """Output paths that fail for root too (chmod would not stop root): each with words its error must hold."""
    a_file = tmp_path / "notes.txt"
    a_file.write_text("a file, not a folder")
    (tmp_path / "out_dir").mkdir()
    return {
        "parent is a file": (a_file / "camera.yaml", "is a file, not a folder"),
        "is a folder": (tmp_path / "out_dir", "is a folder"),
        "missing folder": (tmp_path / "no_such_dir" / "camera.yaml", "does not exist"),
        "proc": (Path("/proc/self/camera.yaml"), "cannot create a file in the folder /proc/self"),
    }


@pytest.mark.parametrize("case", ["parent is a file", "is a folder", "missing folder", "proc"])
def test_intrinsics_unwritable_out_refused_before_the_solve(images, tmp_path: Path, case: str):
    out, words = _unwritable_outputs(tmp_path)[case]
    run = cli_in_process("intrinsics", images, "--board", BOARD, "--out", out, "--json")
    error = assert_json_failure(run)
    assert error["input"] == str(out) and words in error["message"] and str(out) in error["message"]
    assert "detecting the target" not in run.stderr  # refused before any image was read
    assert "Traceback" not in run.stderr


def test_multicam_outputs_refused_before_the_solve(images, tmp_path: Path):
    out, words = _unwritable_outputs(tmp_path)["parent is a file"]
    run = cli_in_process("multicam", "--camera", f"left={images}", "--camera", f"right={images}", "--board", BOARD,
                         "--transforms", out)
    last = assert_plain_failure(run)
    assert last == f"error: {out}: {out.parent} is a file, not a folder"
    assert "%]" not in run.stderr  # no progress: nothing was solved
    run = cli_in_process("multicam", "--camera", f"left={images}", "--camera", f"right={images}", "--board", BOARD,
                         "--kalibr", tmp_path, "--json")
    assert assert_json_failure(run)["message"] == f"{tmp_path}: is a folder; expected the path of a file to write"


def test_export_out_refused_before_the_session_is_read(tmp_path: Path):
    out, words = _unwritable_outputs(tmp_path)["is a folder"]
    last = assert_plain_failure(cli_in_process("export", tmp_path / "no_such_session", "--format", "rig", "--out", out))
    assert words in last and str(out) in last and "no_such_session" not in last


def test_export_replaces_an_existing_out_whole_keeping_its_mode(tmp_path: Path):
    session = SessionStore(tmp_path / "sessions").create("bench", board=BOARD)
    out = tmp_path / "rig.yaml"
    out.write_text("old contents\n")
    out.chmod(0o640)
    run = cli_in_process("export", session.path, "--format", "rig", "--out", out)
    assert run.returncode == 0 and run.stdout == "", run.stderr
    assert load_rig_transforms(out) == [] and stat.S_IMODE(out.stat().st_mode) == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.yaml", "sessions"]  # no temp or probe file left


# -- an output that fails after the solve: the result is kept ------------------------------------------------------

def _kept_folder(message: str, tmp_path: Path) -> Path:
    found = re.search(r"the result is kept in (\S+) \(result\.json, full\)", message)
    assert found, message
    folder = Path(found.group(1))
    assert folder.parent == tmp_path and folder.is_dir()
    return folder


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs Linux's /dev/full (every write: no space left)")
@pytest.mark.slow
def test_out_failing_after_the_solve_keeps_the_result_json(images, tmp_path: Path):
    keep = tmp_path / "tmp"
    keep.mkdir()
    # /dev/full passes every check before the solve (it exists and is writable, by root too) and then fails the
    # write with ENOSPC: a full disk after a long solve
    run = cli_subprocess("intrinsics", images, "--board", BOARD, "--out", "/dev/full", "--camera-name", "left",
                         "--json", env={"TMPDIR": str(keep)})
    error = assert_json_failure(run)
    assert "detecting the target" in run.stderr and "Traceback" not in run.stderr  # it failed after the solve
    assert error["input"] == "/dev/full"
    assert error["message"].startswith("/dev/full: cannot write the file (No space left on device)")
    folder = _kept_folder(error["message"], keep)

    # the kept result is the --json output the failure replaced, and the file that was not written is beside it
    result = json.loads((folder / "result.json").read_text())
    assert {"camera", "rms_px", "views", "std", "verdict", "seconds"} <= set(result)
    assert len(result["views"]) == 6 and 0 < result["rms_px"] < 0.5
    camera, name = load_camera_info(folder / "full")
    assert name == "left"
    np.testing.assert_allclose(camera.K, result["camera"]["K"], rtol=1e-12)
    np.testing.assert_allclose(camera.dist, result["camera"]["dist"], rtol=1e-12)


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs Linux's /dev/full (every write: no space left)")
@pytest.mark.slow
def test_out_failing_after_the_solve_without_json(images, tmp_path: Path):
    run = cli_subprocess("intrinsics", images, "--board", BOARD, "--out", "/dev/full", env={"TMPDIR": str(tmp_path)})
    last = assert_plain_failure(run)
    assert last.startswith("error: /dev/full: cannot write the file (No space left on device); the result is kept")
    folder = _kept_folder(last, tmp_path)
    assert json.loads((folder / "result.json").read_text())["camera"]["width"] == 640


# -- YAML bombs --------------------------------------------------------------------------------------------------

def _alias_bomb() -> str:
    """A ~400-byte YAML whose aliases stand for 9^8 (43 million) strings, the last one as image_width."""
    lines = ['a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for prev, name in zip("abcdefg", "bcdefgh", strict=True):
        lines.append(f"{name}: &{name} [{', '.join([f'*{prev}'] * 9)}]")
    return "\n".join([*lines, "image_width: *h", ""])


def test_alias_bomb_as_camera_refused(tmp_path: Path):
    bomb = tmp_path / "camera.yaml"
    bomb.write_text(_alias_bomb())
    assert bomb.stat().st_size < 600
    run = cli_in_process("lidar-camera", "--camera", bomb, "--pair", PAIR, "--init-xyzypr", "0,0,0,0,0,0", "--json")
    error = assert_json_failure(run)
    assert error["input"] == str(bomb)
    assert "alias (*a)" in error["message"] and "aliases are not accepted" in error["message"]
    assert len(error["message"]) < 400 and len(run.stderr) < 1000 and len(run.stdout) < 1000


def test_size_bomb_and_endless_file_as_camera_refused(tmp_path: Path):
    big = tmp_path / "camera.yaml"
    big.write_text(dump_camera_info(CAM_FRONT, "cam") + "# padding\n" * 200_000)  # 2 MB of a valid file
    error = assert_json_failure(cli_in_process("lidar-camera", "--camera", big, "--pair", PAIR, "--json"))
    assert error["input"] == str(big) and "1000000-byte limit" in error["message"]
    # a device that never ends is refused after the limit is read, not read until memory runs out
    error = assert_json_failure(cli_in_process("lidar-camera", "--camera", "/dev/zero", "--pair", PAIR, "--json"))
    assert error["input"] == "/dev/zero" and "1000000-byte limit" in error["message"]


def test_deep_nesting_refused(tmp_path: Path):
    deep = tmp_path / "camera.yaml"
    deep.write_text("image_width: " + "[" * 50_000 + "]" * 50_000 + "\n")
    error = assert_json_failure(cli_in_process("lidar-camera", "--camera", deep, "--pair", PAIR, "--json"))
    assert "nested more than 20 levels deep" in error["message"] and error["input"] == str(deep)


def test_camera_yaml_without_aliases_still_reads(tmp_path: Path):
    good = tmp_path / "camera.yaml"
    good.write_text(dump_camera_info(CAM_FRONT, "cam_front"))
    camera, name = load_camera_info(good)
    assert name == "cam_front" and np.array_equal(camera.K, CAM_FRONT.K)


# -- echoed values truncated -------------------------------------------------------------------------------------

def test_long_values_truncated_in_messages(tmp_path: Path):
    huge = "x" * 100_000
    camera = tmp_path / "camera.yaml"
    camera.write_text(dump_camera_info(CAM_FRONT, "cam").replace("image_width: 1280", f"image_width: {huge}"))
    error = assert_json_failure(cli_in_process("lidar-camera", "--camera", camera, "--pair", PAIR, "--json"))
    assert error["message"].startswith(f"{camera}: field 'image_width' is 'xxx")
    assert "xxx...xxx" in error["message"] and len(error["message"]) < 400
    assert error["message"].endswith("expected a positive integer (pixels)")  # what was expected survives the cut

    good = tmp_path / "good.yaml"
    good.write_text(dump_camera_info(CAM_FRONT, "cam"))
    runs = {
        "--pair": cli_in_process("lidar-camera", "--camera", good, "--pair", huge, "--json"),
        "--init-xyzypr": cli_in_process("lidar-camera", "--camera", good, "--pair", PAIR, "--method", "edges",
                                        "--init-xyzypr", huge, "--json"),
        "board": cli_in_process("intrinsics", tmp_path, "--board", huge, "--json"),
    }
    for option, run in runs.items():
        error = assert_json_failure(run)
        assert error["input"] == option and "xxx...xxx" in error["message"], (option, error["message"][:300])
        assert len(error["message"]) < 600 and len(run.stderr.strip().splitlines()[-1]) < 700, option


def test_error_line_bounded_whatever_the_message():
    error = InputError("line one\nline two " + "y" * 1_000_000, "z" * 10_000)
    line = error.one_line()
    assert "\n" not in line and len(line) < 2100
    assert len(error.to_dict()["message"]) <= 1000 and len(error.to_dict()["input"]) <= 1000
    # a value that stands for 10^8 strings is summarised without building its repr
    nested: list = ["lol"] * 9
    for _ in range(8):
        nested = [nested] * 9
    assert len(shorten(nested)) <= 200 and shorten("abc") == "'abc'" and shorten(10**5000).startswith("<")


# -- every other failure is the one-line error too ---------------------------------------------------------------

def test_argument_errors_follow_the_contract():
    error = assert_json_failure(cli_in_process("intrinsics", "--json"))
    assert "required" in error["message"] and "--board" in error["message"]
    assert error["input"] == "calib-studio intrinsics"


def test_os_error_and_bug_are_one_line_errors(monkeypatch, capsys):
    def no_permission(args):
        raise PermissionError(13, "Permission denied", "/srv/images/left01.jpg")

    monkeypatch.setattr(intrinsics_cli, "run_intrinsics", no_permission)
    assert cli_module.main(["intrinsics", "x", "--board", BOARD, "--json"]) == cli_module.EXIT_INPUT_ERROR
    out, err = capsys.readouterr()
    assert err.strip() == "error: /srv/images/left01.jpg: Permission denied"
    assert json.loads(out) == {"error": {"message": "Permission denied", "input": "/srv/images/left01.jpg"}}

    def bug(args):
        raise KeyError("views")

    monkeypatch.setattr(intrinsics_cli, "run_intrinsics", bug)
    assert cli_module.main(["intrinsics", "x", "--board", BOARD, "--json"]) == cli_module.EXIT_INTERNAL_ERROR
    out, err = capsys.readouterr()
    assert "Traceback" in err  # for the bug report, before the error line
    assert err.strip().splitlines()[-1].startswith("error: internal error (KeyError: 'views')")
    assert json.loads(out)["error"]["message"].startswith("internal error (KeyError: 'views')")
