"""The wall test field's spec and survey file, and the V-target's spec and geometry: what they hold, and bad input
named by file, line and field."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from backend.core.errors import InputError
from backend.core.test_field import SESSION_SURVEY, TestField, parse_survey, survey_text
from backend.core.v_target import VTarget

SPEC = "vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50"


def _survey(folder: Path, text: str, name: str = "wall.csv") -> Path:
    path = folder / name
    path.write_text(text)
    return path


def test_a_survey_reads_with_header_comments_and_either_separator(tmp_path: Path):
    path = _survey(tmp_path, "# surveyed 2026-11-30\nid,x,y,z\n" + "".join(
        f"{i}{',' if i % 2 else ' '}{0.45 * i:.3f}{', ' if i % 2 else '  '}0.5,-0.01  # marker {i}\n"
        for i in range(7)))
    field = TestField.parse(f"testfield:DICT_4X4_50:0.15:{path}")
    assert field.ids == tuple(range(7))
    np.testing.assert_allclose(field.centres_m[:, 0], 0.45 * np.arange(7), atol=1e-9)
    np.testing.assert_allclose(field.centres_m[:, 1:], [[0.5, -0.01]] * 7)
    assert str(field) == f"testfield:DICT_4X4_50:0.15:{path}"
    assert field.plane_xy.shape == (7, 2)


def test_survey_text_round_trips():
    ids, centres = np.arange(6) * 3, np.random.default_rng(0).uniform(-2, 2, (6, 3))
    read_ids, read_centres = parse_survey(survey_text(ids, centres).encode(), "s.csv")
    assert read_ids == tuple(ids) and np.abs(read_centres - centres).max() < 6e-5


@pytest.mark.parametrize(("text", "input_name", "says"), [
    ("0,0,0,0\n1,1,0,0\n2,2,0,0\n1,3,0,0\n4,4,0,0\n5,5,0,0\n", "wall.csv:4",
     ["line 4", "marker id 1 is surveyed twice", "first on line 2"]),
    ("0,0,0\n", "wall.csv:1", ["line 1", "has 3 fields", "id, X, Y, Z"]),
    ("a,0,0,0\n", "wall.csv:1", ["line 1", "marker id 'a' is not a whole number"]),
    ("0,0,0,north\n", "wall.csv:1", ["line 1", "not numbers in metres"]),
    ("0,0,0,nan\n", "wall.csv:1", ["finite X, Y, Z"]),
    ("0,0,0,0\n1,0,0,1\n", "wall.csv", ["surveys 2 marker(s)", "at least 6"]),
])
def test_a_bad_survey_names_the_file_line_and_field(tmp_path: Path, text: str, input_name: str, says: list[str]):
    path = _survey(tmp_path, text)
    with pytest.raises(InputError) as info:
        TestField.parse(f"testfield:DICT_4X4_50:0.15:{path}")
    assert info.value.input == str(tmp_path / input_name)
    for phrase in says:
        assert phrase in info.value.message


@pytest.mark.parametrize(("spec", "says"), [
    ("testfield:DICT_4X4_50:0.15", "is not testfield:DICT:MARKER:SURVEY"),
    ("testfield:DICT_9X9_1:0.15:{survey}", "unknown marker dictionary"),
    ("testfield:DICT_4X4_50:big:{survey}", "is not a number in metres"),
    ("testfield:DICT_4X4_50:15:{survey}", "between 0 and 2"),
    ("testfield:DICT_4X4_50:0.15:{missing}", "cannot read the survey file"),
])
def test_a_bad_test_field_spec_names_the_field(tmp_path: Path, spec: str, says: str):
    survey = _survey(tmp_path, survey_text(np.arange(6), np.zeros((6, 3))))
    with pytest.raises(InputError, match=says):
        TestField.parse(spec.format(survey=survey, missing=tmp_path / "none.csv"))


def test_an_id_beyond_the_dictionary_is_refused(tmp_path: Path):
    survey = _survey(tmp_path, survey_text(np.array([0, 1, 2, 3, 4, 60]), np.zeros((6, 3))))
    with pytest.raises(InputError, match="marker id 60 is not in DICT_4X4_50"):
        TestField.parse(f"testfield:DICT_4X4_50:0.15:{survey}")


def test_a_session_reads_only_its_own_survey(tmp_path: Path):
    _survey(tmp_path, survey_text(np.arange(6), np.zeros((6, 3))), SESSION_SURVEY)
    assert TestField.parse(f"testfield:DICT_4X4_50:0.15:{SESSION_SURVEY}", tmp_path).ids == tuple(range(6))
    for escape in ("../survey.csv", "/etc/passwd", "other.csv"):
        with pytest.raises(InputError, match="reads the survey the session holds"):
            TestField.parse(f"testfield:DICT_4X4_50:0.15:{escape}", tmp_path)


def test_the_v_target_geometry():
    target = VTarget.parse(SPEC)
    assert str(target) == "vtarget:1x0.6:120:3x2:0.15:DICT_4X4_50"
    normals = target.face_planes[:, :3]
    assert np.degrees(np.arccos(normals[0] @ normals[1])) == pytest.approx(180 - 120)
    assert np.all(normals[:, 2] < 0)  # both faces look at the viewer (target z points away from it)
    corners = target.plate_corners()
    np.testing.assert_allclose(corners[0, 1], corners[1, 0], atol=1e-12)  # the ridge: face 0's right, face 1's left
    assert np.linalg.norm(corners[0, 1] - corners[0, 0]) == pytest.approx(1.0)
    assert corners[0, 0, 2] < 0  # below 180 deg the outer edges come towards the viewer
    for face in range(2):  # every marker corner on its face's plane, ids face 0 then face 1
        on_face = target.marker_corners[target.face_of(target.marker_ids) == face].reshape(-1, 3)
        assert np.abs(on_face @ target.face_planes[face, :3] + target.face_planes[face, 3]).max() < 1e-12
    side = np.linalg.norm(target.marker_corners[:, 1] - target.marker_corners[:, 0], axis=1)
    np.testing.assert_allclose(side, 0.15)
    assert list(target.face_of([0, 5, 6, 11, 12, -1])) == [0, 0, 1, 1, -1, -1]


@pytest.mark.parametrize(("spec", "says"), [
    ("vtarget:1.0x0.6:120:3x2:0.15", "is not vtarget:WxH:ANGLE"),
    ("vtarget:1.0x0.6:170:3x2:0.15:DICT_4X4_50", "from flat"),
    ("vtarget:1.0x0.6:120:3x2:0.3:DICT_4X4_50", "at most 0.24 m"),
    ("vtarget:9x0.6:120:3x2:0.15:DICT_4X4_50", "0.1 to 5"),
    ("vtarget:1.0x0.6:120:6x5:0.05:DICT_4X4_50", "DICT_4X4_50 has 50 markers"),
    ("vtarget:1.0xwide:120:3x2:0.15:DICT_4X4_50", "not a number"),
    ("vtarget:1.0x0.6:120:3x2:0.15:DICT_NONE", "unknown marker dictionary"),
])
def test_a_bad_v_target_spec_names_the_field(spec: str, says: str):
    with pytest.raises(InputError, match=says) as info:
        VTarget.parse(spec)
    assert info.value.input == "target"
