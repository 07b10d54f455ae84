"""The camera JSON file, and what each camera export does with the photogrammetric model."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from backend.core.errors import InputError
from backend.core.rig import Frame
from backend.exports.camera_json import dump_camera_json, load_camera
from backend.exports.kalibr_camchain import dump_kalibr_camchain
from backend.exports.opencv_yaml import dump_opencv_yaml, read_opencv_yaml
from backend.exports.ros_camera_info import dump_camera_info, write_camera_info
from backend.services import exports as export_service
from backend.sim.demo_rig import demo_rig
from backend.store.session import SessionStore
from tests.core.test_photogrammetric_model import blackfly


def test_camera_json_round_trip_carries_every_model(tmp_path: Path):
    camera = blackfly(A1=4e-4, A2=-2.5e-4)
    path = tmp_path / "camera.json"
    path.write_text(dump_camera_json(camera, "blackfly", {"std": {"fx": 0.5}}))
    loaded, name = load_camera(path)
    assert name == "blackfly" and loaded.model == "photogrammetric" and (loaded.width, loaded.height) == (1280, 1024)
    np.testing.assert_array_equal(loaded.K, camera.K)
    np.testing.assert_array_equal(loaded.dist, camera.dist)
    assert json.loads(path.read_text())["std"] == {"fx": 0.5}
    # the suffix picks the reader: a camera.yaml is ROS camera_info, as before
    ros = demo_rig().get("cam_front").intrinsics
    write_camera_info(tmp_path / "camera.yaml", ros, "cam_front")
    assert load_camera(tmp_path / "camera.yaml")[0].model == "pinhole-radtan"


@pytest.mark.parametrize(("edit", "fragments"), [
    (lambda d: d.update(model="brown"), ("field 'model' is 'brown'", "'photogrammetric'")),
    (lambda d: d.update(width=0), ("field 'width' is 0", "a positive integer (pixels)")),
    (lambda d: d.pop("height"), ("field 'height' is missing",)),
    (lambda d: d.update(K=[[800, 0, 640], [0, 800, 512]]), ("field 'K'", "[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")),
    (lambda d: d.update(dist=[0.0] * 5),
     ("field 'dist'", "7 numbers for photogrammetric: [K1, K2, K3, P1, P2, A1, A2]")),
    (lambda d: d.update(camera_name=3), ("field 'camera_name' is 3", "a string")),
])
def test_camera_json_bad_fields_are_named(tmp_path: Path, edit, fragments: tuple[str, ...]):
    document = json.loads(dump_camera_json(blackfly(), "blackfly"))
    edit(document)
    path = tmp_path / "camera.json"
    path.write_text(json.dumps(document))
    with pytest.raises(InputError) as error:
        load_camera(path)
    assert error.value.message.startswith(f"{path}: ") and error.value.input == str(path)
    for fragment in fragments:
        assert fragment in error.value.message, error.value.message


def test_camera_json_that_is_not_json_is_named(tmp_path: Path):
    path = tmp_path / "camera.json"
    path.write_text('{"model": "photogrammetric",')
    with pytest.raises(InputError, match=r"camera\.json: not JSON \(.*\); expected a camera JSON object"):
        load_camera(path)


def test_ros_and_kalibr_refuse_the_photogrammetric_model_naming_it():
    camera = blackfly()
    with pytest.raises(InputError) as error:
        dump_camera_info(camera, "blackfly")
    assert error.value.input == "model"
    assert error.value.message.startswith("camera_info cannot carry the photogrammetric model: ROS's distortion "
                                          "models here are plumb_bob and equidistant")
    with pytest.raises(InputError, match="blackfly: Kalibr's camchain cannot carry the photogrammetric model"):
        dump_kalibr_camchain([("blackfly", camera)], {"blackfly": np.eye(4)})


def test_opencv_yaml_carries_the_model_under_its_name(tmp_path: Path):
    camera = blackfly(A1=4e-4, A2=-2.5e-4)
    path = tmp_path / "camera.yaml"
    text = dump_opencv_yaml(camera)
    assert "distortion_model: photogrammetric" in text
    path.write_text(text)
    loaded = read_opencv_yaml(path)
    assert loaded.model == "photogrammetric"
    np.testing.assert_array_equal(loaded.dist, camera.dist)


def test_the_session_exports_a_photogrammetric_camera_as_json_and_refuses_camera_info(tmp_path: Path):
    rig = demo_rig()
    rig.add(Frame("blackfly", "base_link", kind="camera", intrinsics=blackfly()))
    session = SessionStore(tmp_path / "sessions").create("rescue", rig=rig)
    support = export_service.camera_exports("blackfly", blackfly())
    assert support["camera-json"] is None and support["opencv"] is None
    assert support["camera_info"].startswith("camera_info cannot carry the photogrammetric model")
    name, text = export_service.export_text(session, "camera-json", "blackfly")
    assert name == "blackfly.json" and json.loads(text)["model"] == "photogrammetric"
    with pytest.raises(InputError, match="camera_info cannot carry the photogrammetric model"):
        export_service.export_text(session, "camera_info", "blackfly")
