"""A wall test field on the simulated disaster-response Blackfly (photogrammetric truth, affine terms included):
the intrinsics from the demo session's 12 wall images (six positions, straight and turned 90 deg) and the exterior
orientation, through the CLI as a user runs it, against the simulator's truth; markers the survey lacks, and a
survey that is wrong."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from backend.calib.test_field.detection import detect_test_field
from backend.core.test_field import SESSION_SURVEY, TestField, survey_text
from backend.core.transforms import invert, transform_error
from backend.exports.camera_json import dump_camera_json
from backend.services.demo_disaster_response import DISASTER_RESPONSE_NAME
from backend.sim.disaster_response import CAMERA as CAMERA_NAME
from backend.sim.marker_targets import disaster_response_camera, field_views
from backend.store.session import SessionStore
from tests.conftest import cli_in_process, disaster_response_template

CAMERA = disaster_response_camera()
PIXEL_SIZE_UM = 4.8


@pytest.fixture(scope="module")
def wall(tmp_path_factory) -> tuple[Path, str, list[np.ndarray]]:
    """A folder of the 12 wall images the disaster-response demo renders (its session, built once per run), the
    test field's spec (the session's survey) and each image's true ``T_camera_wall``."""
    session = SessionStore(disaster_response_template(tmp_path_factory)).get(DISASTER_RESPONSE_NAME)
    images = tmp_path_factory.mktemp("test_field") / "images"
    images.mkdir()
    for capture in session.captures(CAMERA_NAME):
        if capture.source and capture.source.startswith("wall_"):
            shutil.copyfile(session.path / "captures" / CAMERA_NAME / f"{capture.id}.png", images / capture.source)
    assert len(list(images.iterdir())) == 12
    return images, f"testfield:DICT_4X4_50:0.15:{session.path / SESSION_SURVEY}", field_views()


def _json(run) -> dict:
    assert run.returncode == 0, run.stderr
    return json.loads(run.stdout)


def test_photogrammetric_intrinsics_from_the_wall(wall, tmp_path: Path):
    """Every interior-orientation parameter within 3 sigma of the truth (A1 and A2 included), a RMS of a fraction of
    a pixel as the paper's 0.392 px, and the camera file written."""
    images, spec, _ = wall
    out = tmp_path / "camera.json"
    summary = _json(cli_in_process("intrinsics", images, "--board", spec, "--model", "photogrammetric",
                                   "--pixel-size-um", PIXEL_SIZE_UM, "--out", out, "--json"))
    assert summary["rms_px"] < 0.3
    # markers whose centres render off their own view's noise (steep, blurred) are rejected as mrcal would: 40 on
    # this wall; wall_10 would lose more than a quarter of its markers, so it is dropped whole, and named
    used = [v["image"] for v in summary["views"] if v["used"]]
    assert len(used) >= 11 and sorted(used + summary["views_dropped"]) == sorted(v["image"] for v in summary["views"])
    parameters = summary["photogrammetric"]["parameters"]
    truth = dict(zip(["c", "xp", "yp", "K1", "K2", "K3", "P1", "P2", "A1", "A2"],
                     [CAMERA.K[0, 0], CAMERA.K[0, 2], CAMERA.K[1, 2], *CAMERA.dist], strict=True))
    for name, value in truth.items():
        estimate = parameters[name]
        assert abs(estimate["value_px"] - value) < 3 * estimate["sigma_px"], (name, estimate, value)
    assert parameters["c"]["value_mm"] == pytest.approx(4.0, abs=0.01)  # the 4 mm lens on 4.8 um pixels
    assert summary["verdict"]["level"] in ("trusted", "check")
    assert json.loads(out.read_text())["model"] == "photogrammetric"


def test_the_exterior_orientation_in_the_wall_frame(wall, tmp_path: Path):
    images, spec, poses = wall
    camera_file = tmp_path / "camera.json"
    camera_file.write_text(dump_camera_json(CAMERA, "blackfly"))
    chosen = [images / "wall_04.png", images / "wall_09.png"]
    summary = _json(cli_in_process("exterior", *chosen, "--camera", camera_file, "--field", spec, "--json"))
    for path in chosen:
        pose = summary["poses"][path.name]
        T_true = invert(poses[int(path.stem[-2:])])
        trans_m, rot_deg = transform_error(np.array(pose["T_wall_camera"]), T_true)
        assert np.abs(trans_m).max() < 0.003 and np.abs(rot_deg).max() < 0.03, (trans_m, rot_deg)
        sigma_m, sigma_deg = np.array(pose["std"]["trans_m"]), np.array(pose["std"]["rot_deg"])
        assert np.all(np.abs(trans_m) < 4 * sigma_m + 2e-4) and np.all(np.abs(rot_deg) < 4 * sigma_deg + 2e-3)
        assert pose["verdict"]["level"] == "trusted", pose["verdict"]
        assert pose["residuals"]["markers_used"] >= 30
        np.testing.assert_allclose([pose["exterior_orientation"][k] for k in ("X0_m", "Y0_m", "Z0_m")],
                                   T_true[:3, 3], atol=0.003)

    # the lens's own sigma, given, widens each pose's sigma and is said to be carried; a wrong count is refused
    lens_std = "0.5,0.4,0.4,1e-9,1e-15,1e-21,1e-7,1e-7,1e-4,1e-4"  # c, xp, yp, K1-K3, P1, P2, A1, A2
    carried = _json(cli_in_process("exterior", chosen[0], "--camera", camera_file, "--field", spec, "--json",
                                   "--intrinsics-std", lens_std))["poses"][chosen[0].name]
    assert np.all(np.array(carried["std"]["trans_m"]) > np.array(summary["poses"][chosen[0].name]["std"]["trans_m"]))
    said = "the camera's intrinsics' sigma (--intrinsics-std) is carried into the pose's"
    assert said in carried["verdict"]["reasons"]
    run = cli_in_process("exterior", chosen[0], "--camera", camera_file, "--field", spec, "--intrinsics-std", "0.5,0.4")
    assert run.returncode == 2 and "expected 10 sigmas" in run.stderr and "--intrinsics-std" in run.stderr


def test_markers_the_survey_lacks_are_named_and_left_out(wall, tmp_path: Path):
    images, spec, _ = wall
    field = TestField.parse(spec)
    partial = tmp_path / "partial.csv"
    partial.write_text(survey_text(np.array(field.ids[:-2]), field.centres_m[:-2]))
    found = detect_test_field(cv2.imread(str(images / "wall_04.png"), cv2.IMREAD_GRAYSCALE),
                              TestField.parse(f"testfield:DICT_4X4_50:0.15:{partial}"), "wall_04.png")
    assert found.detection is not None and len(found.detection.ids) == 38
    assert found.notes == [f"wall_04.png: marker id(s) 38, 39 are not in the survey file {partial}; left out "
                           "(survey them, or check that the file is this wall's)"]


def test_a_survey_with_a_repeated_id_is_refused_naming_it(wall, tmp_path: Path):
    images, spec, _ = wall
    survey = Path(spec.split(":", 3)[3])
    repeated = tmp_path / "repeated.csv"
    lines = survey.read_text().splitlines()
    repeated.write_text("\n".join([*lines, lines[5]]) + "\n")
    run = cli_in_process("intrinsics", images, "--board", f"testfield:DICT_4X4_50:0.15:{repeated}", "--json")
    assert run.returncode == 2
    error = json.loads(run.stdout)["error"]
    assert error["input"] == f"{repeated}:{len(lines) + 1}"
    assert f"marker id {lines[5].split(',')[0]} is surveyed twice (first on line 6)" in error["message"]
    assert len(run.stderr.strip().splitlines()) == 1
