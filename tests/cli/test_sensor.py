"""``calib-studio sensor``: list, edit (previewed first), remove and restore a session's sensors from the command
line, with the JSON the API answers and one-line errors for what cannot be done."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from backend.core.transforms import from_xyz_ypr
from backend.store.session import Session
from tests.conftest import cli_in_process, fresh_demo


@pytest.fixture
def demo(tmp_path: Path, demo_template: Path) -> Path:
    return fresh_demo(demo_template, tmp_path / "sessions") / "demo"


def run_json(*args) -> dict:
    run = cli_in_process("sensor", *args, "--json")
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def test_edit_remove_and_restore_from_the_command_line(demo):
    listed = run_json("list", demo)
    assert [s["name"] for s in listed["sensors"]][:2] == ["cam_front", "cam_wide"] and listed["removed"] == []

    preview = run_json("edit", demo, "scanner_2d", "--xyzypr", "0.4,-0.05,0.2,-5,0,0", "--preview")
    assert preview["applied"] is False and [m["frame"] for m in preview["moves"]] == ["scanner_2d"]
    assert Session.load(demo).rig.get("scanner_2d").T_mount[0, 3] != pytest.approx(0.4)

    run_json("edit", demo, "scanner_2d", "--xyzypr", "0.4,-0.05,0.2,-5,0,0", "--mount-sigma", "0.01,1")
    frame = Session.load(demo).rig.get("scanner_2d")
    np.testing.assert_allclose(frame.T_mount, from_xyz_ypr(np.array([0.4, -0.05, 0.2]), np.radians([-5, 0, 0])),
                               atol=1e-12)
    assert frame.mount_sigma == (0.01, 1.0)
    # --device takes what 'calib-studio node --device' takes: a short form, opened before anything is written
    device = run_json("edit", demo, "scanner_2d", "--device", "sim-lidar:lidar_front", "--preview")
    assert device["applied"] is False and device["moves"] == []
    assert Session.load(demo).rig.get("scanner_2d").device["sensor"] == "scanner_2d"

    text = cli_in_process("sensor", "remove", demo, "cam_front")
    assert text.returncode == 0, text.stderr
    assert "cam_front/intrinsics: emptied" in text.stdout and "kept aside as cam_front-1" in text.stdout
    assert [r["id"] for r in run_json("list", demo)["removed"]] == ["cam_front-1"]
    restored = run_json("restore", demo, "cam_front-1")
    assert restored["restored"] == ["cam_front/intrinsics"]
    assert Session.load(demo).accepted("cam_front/intrinsics") is not None


@pytest.mark.parametrize(("args", "field", "words"), [
    (("edit", "DEMO", "ghost", "--parent", "base_link"), "sensor", "no sensor or frame named 'ghost'"),
    (("edit", "DEMO", "cam_front", "--xyzypr", "1,2,3"), "--xyzypr", "six comma-separated numbers"),
    (("edit", "DEMO", "cam_front", "--mount-sigma", "0.01"), "--mount-sigma", "two comma-separated numbers"),
    (("edit", "DEMO", "cam_front", "--device", "{uvc"), "device", "not valid JSON"),
    (("edit", "DEMO", "cam_front", "--device", "sim-cam:cam_wide"), "device", "unknown device spec"),
    (("edit", "DEMO", "cam_front"), "body", "nothing to change"),
    (("remove", "DEMO", "base_link"), "sensor", "the rig's root"),
    (("restore", "DEMO", "cam_front-9"), "removal", "no removal 'cam_front-9'"),
])
def test_refusals_are_one_line_errors(demo, args, field, words):
    before = (demo / "session.json").read_bytes()
    run = cli_in_process("sensor", *[str(demo) if a == "DEMO" else a for a in args], "--json")
    assert run.returncode == 2 and run.stderr.strip().splitlines()[-1].startswith("error: ")
    error = json.loads(run.stdout)["error"]
    assert error["input"] == field and words in error["message"]
    assert (demo / "session.json").read_bytes() == before
