"""Export and import formats: ROS camera_info YAML, OpenCV FileStorage YAML, rig transforms."""

from __future__ import annotations

import shlex
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from backend.core.camera import ROS_DISTORTION_NAMES, CameraIntrinsics
from backend.core.errors import InputError
from backend.core.rig import Frame, Rig
from backend.core.transforms import from_xyz_ypr, to_quaternion_xyzw
from backend.exports.opencv_yaml import dump_opencv_yaml, read_opencv_yaml, write_opencv_yaml
from backend.exports.rig_transforms import dump_rig_transforms, load_rig_transforms
from backend.exports.ros_camera_info import dump_camera_info, load_camera_info, projection_matrix, write_camera_info

ROS_KEYS = [
    "image_width",
    "image_height",
    "camera_name",
    "camera_matrix",
    "distortion_model",
    "distortion_coefficients",
    "rectification_matrix",
    "projection_matrix",
]
"""In the order ``writeCalibrationYml`` (camera_calibration_parsers/src/parse_yml.cpp) emits them."""

PINHOLE = CameraIntrinsics(
    "pinhole-radtan",
    1280,
    720,
    [[910.1234567891234, 0.0, 640.3141592653589], [0.0, 905.5000000000001, 359.9], [0.0, 0.0, 1.0]],
    [-0.2812345678901234, 0.07123456789, 1.0e-05, -2.5e-04, -0.008312345],
)
FISHEYE = CameraIntrinsics(
    "fisheye-equidistant",
    1920,
    1080,
    [[612.3456789012345, 0.0, 961.2], [0.0, 611.9876543210987, 538.7], [0.0, 0.0, 1.0]],
    [0.031234567, -0.0071234, 0.0012345678901, -0.000123456789],
)
CAMERAS = pytest.mark.parametrize("camera", [PINHOLE, FISHEYE], ids=["pinhole-radtan", "fisheye-equidistant"])


def assert_same_camera(a: CameraIntrinsics, b: CameraIntrinsics) -> None:
    assert (a.model, a.width, a.height) == (b.model, b.width, b.height)
    np.testing.assert_allclose(a.K, b.K, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.dist, b.dist, rtol=0, atol=1e-12)


# --- ROS camera_info -------------------------------------------------------------------------


@CAMERAS
def test_ros_camera_info_round_trip(tmp_path: Path, camera: CameraIntrinsics) -> None:
    path = tmp_path / "calib" / "camera.yaml"
    write_camera_info(path, camera, "front_cam")
    loaded, name = load_camera_info(path)
    assert name == "front_cam"
    assert_same_camera(loaded, camera)
    assert path.read_text() == dump_camera_info(camera, "front_cam")


@CAMERAS
def test_ros_camera_info_layout(camera: CameraIntrinsics) -> None:
    text = dump_camera_info(camera, "narrow_stereo/left")
    document = yaml.safe_load(text)
    assert list(document) == ROS_KEYS
    assert document["image_width"] == camera.width and document["image_height"] == camera.height
    assert document["camera_name"] == "narrow_stereo/left"
    assert document["distortion_model"] == ROS_DISTORTION_NAMES[camera.model]
    shapes = {
        "camera_matrix": (3, 3),
        "distortion_coefficients": (1, camera.dist.size),
        "rectification_matrix": (3, 3),
        "projection_matrix": (3, 4),
    }
    for key, (rows, cols) in shapes.items():
        assert list(document[key]) == ["rows", "cols", "data"]
        assert (document[key]["rows"], document[key]["cols"]) == (rows, cols)
        assert len(document[key]["data"]) == rows * cols
        assert all(isinstance(value, float) for value in document[key]["data"])
    assert document["rectification_matrix"]["data"] == np.eye(3).ravel().tolist()
    # yaml-cpp's layout: block maps, each data list in flow style on one line.
    assert "  data: [" in text and text.count("\n") == 3 + 4 * 4 + 1


def test_ros_projection_matrix_matches_ros_camera_calibration() -> None:
    # MonoCalibrator.set_alpha(0.0): getOptimalNewCameraMatrix(K, D, size, 0) for plumb_bob ...
    expected, _ = cv2.getOptimalNewCameraMatrix(PINHOLE.K, PINHOLE.dist, (1280, 720), 0.0)
    P = np.array(yaml.safe_load(dump_camera_info(PINHOLE, "c"))["projection_matrix"]["data"]).reshape(3, 4)
    np.testing.assert_array_equal(P[:, :3], expected)
    np.testing.assert_array_equal(P[:, 3], 0.0)
    # ... and K itself (fx, fy divided by 1 + alpha) for equidistant.
    np.testing.assert_array_equal(projection_matrix(FISHEYE), np.column_stack([FISHEYE.K, np.zeros(3)]))


def test_ros_camera_info_reads_files_written_by_ros(tmp_path: Path) -> None:
    # Integers in data, no distortion_model (ROS assumes plumb_bob), exponents YAML 1.1 reads as strings.
    path = tmp_path / "ost.yaml"
    path.write_text(
        "image_width: 800\nimage_height: 600\ncamera_name: 00b09d0100990bb2\ncamera_matrix:\n  rows: 3\n"
        "  cols: 3\n  data: [1454.03, 0, 469.791, 0, 1458.92, 180.359, 0, 0, 1]\ndistortion_coefficients:\n"
        "  rows: 1\n  cols: 5\n  data: [-0.0118792, -1.61905, 1e-05, -0.00135465, 0]\nrectification_matrix:\n"
        "  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\nprojection_matrix:\n  rows: 3\n  cols: 4\n"
        "  data: [1454.03, 0, 469.791, 0, 0, 1458.92, 180.359, 0, 0, 0, 1, 0]\n"
    )
    camera, name = load_camera_info(path)
    assert name == "00b09d0100990bb2"
    assert camera.model == "pinhole-radtan" and camera.image_size == (800, 600)
    np.testing.assert_array_equal(camera.dist, [-0.0118792, -1.61905, 1e-05, -0.00135465, 0.0])


def _ros_file(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "bad_camera.yaml"
    path.write_text(text)
    return path


def _assert_input_error(load, path: Path, *fragments: str) -> InputError:
    with pytest.raises(InputError) as info:
        load(path)
    message = info.value.message
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message, message
    assert info.value.input == str(path)
    return info.value


def test_ros_camera_info_truncated_file(tmp_path: Path) -> None:
    text = dump_camera_info(PINHOLE, "front_cam")
    cut_in_list = text[: text.index("data: [", text.index("projection_matrix")) + 20]
    _assert_input_error(load_camera_info, _ros_file(tmp_path, cut_in_list), "not valid YAML", "line 20", "truncated")
    cut_at_line = text[: text.index("projection_matrix")]
    _assert_input_error(load_camera_info, _ros_file(tmp_path, cut_at_line), "'projection_matrix'", "is missing")


def test_ros_camera_info_missing_camera_matrix(tmp_path: Path) -> None:
    document = yaml.safe_load(dump_camera_info(PINHOLE, "front_cam"))
    del document["camera_matrix"]
    path = _ros_file(tmp_path, yaml.safe_dump(document, sort_keys=False))
    _assert_input_error(load_camera_info, path, "'camera_matrix'", "is missing", "rows, cols, data")


def test_ros_camera_info_data_length_does_not_match_rows_cols(tmp_path: Path) -> None:
    document = yaml.safe_load(dump_camera_info(PINHOLE, "front_cam"))
    document["camera_matrix"]["data"] = document["camera_matrix"]["data"][:8]
    path = _ros_file(tmp_path, yaml.safe_dump(document, sort_keys=False))
    _assert_input_error(load_camera_info, path, "'camera_matrix.data'", "has 8 values", "rows*cols = 3*3", "9 numbers")


@pytest.mark.parametrize(
    ("edit", "fragments"),
    [
        (lambda d: d.update(distortion_model="rational_polynomial"), ("'distortion_model'", "plumb_bob")),
        (lambda d: d["camera_matrix"]["data"].__setitem__(4, "abc"), ("'camera_matrix.data[4]'", "finite number")),
        (lambda d: d["camera_matrix"].update(rows=4), ("'camera_matrix.rows'", "expected 3")),
        (lambda d: d.update(image_width=-640), ("'image_width'", "positive integer")),
        (lambda d: d.update(distortion_model="equidistant"), ("'distortion_coefficients.data'", "4 for equidistant")),
        (lambda d: d["projection_matrix"].pop("data"), ("'projection_matrix.data'", "is missing")),
        (lambda d: d["camera_matrix"]["data"].__setitem__(8, 2.0), ("'camera_matrix.data'", "fx, fy > 0")),
    ],
    ids=["unknown-model", "non-numeric", "rows", "width", "coefficient-count", "no-P-data", "K-last-row"],
)
def test_ros_camera_info_bad_fields(tmp_path: Path, edit, fragments: tuple[str, ...]) -> None:
    document = yaml.safe_load(dump_camera_info(PINHOLE, "front_cam"))
    edit(document)
    _assert_input_error(load_camera_info, _ros_file(tmp_path, yaml.safe_dump(document, sort_keys=False)), *fragments)


def test_ros_camera_info_unreadable_or_empty_file(tmp_path: Path) -> None:
    _assert_input_error(load_camera_info, tmp_path / "absent.yaml", "cannot read the file")
    _assert_input_error(load_camera_info, _ros_file(tmp_path, ""), "is empty")


# --- OpenCV FileStorage YAML -----------------------------------------------------------------


@CAMERAS
def test_opencv_yaml_round_trip(tmp_path: Path, camera: CameraIntrinsics) -> None:
    path = tmp_path / "camera_opencv.yaml"
    extra: dict[str, float | str] = {"avg_reprojection_error": 0.2134, "board": "checkerboard:9x6:0.025"}
    write_opencv_yaml(path, camera, extra)
    assert_same_camera(read_opencv_yaml(path), camera)
    assert path.read_text() == dump_opencv_yaml(camera, extra)


def test_opencv_yaml_is_readable_by_filestorage(tmp_path: Path) -> None:
    path = tmp_path / "camera_opencv.yaml"
    write_opencv_yaml(path, PINHOLE, {"avg_reprojection_error": 0.2134})
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        assert storage.getNode("image_width").real() == 1280 and storage.getNode("image_height").real() == 720
        np.testing.assert_array_equal(storage.getNode("camera_matrix").mat(), PINHOLE.K)
        np.testing.assert_array_equal(storage.getNode("distortion_coefficients").mat().ravel(), PINHOLE.dist)
        assert storage.getNode("distortion_model").string() == "pinhole-radtan"
        assert storage.getNode("avg_reprojection_error").real() == 0.2134
    finally:
        storage.release()


def test_opencv_yaml_reads_the_opencv_calibration_sample_layout(tmp_path: Path) -> None:
    # No distortion_model: the sample's fisheye_model flag decides, else OpenCV's default pinhole model.
    storage = cv2.FileStorage(str(tmp_path / "out_camera_data.yml"), cv2.FILE_STORAGE_WRITE)
    storage.write("image_width", FISHEYE.width)
    storage.write("image_height", FISHEYE.height)
    storage.write("fisheye_model", 1)
    storage.write("camera_matrix", FISHEYE.K)
    storage.write("distortion_coefficients", FISHEYE.dist.reshape(-1, 1))
    storage.release()
    assert_same_camera(read_opencv_yaml(tmp_path / "out_camera_data.yml"), FISHEYE)


def test_opencv_yaml_bad_files(tmp_path: Path) -> None:
    text = dump_opencv_yaml(PINHOLE)
    truncated = tmp_path / "truncated.yaml"
    truncated.write_text(text[: text.index("data: [", text.index("distortion_coefficients")) + 20])
    _assert_input_error(read_opencv_yaml, truncated, "OpenCV cannot parse", "truncated")
    truncated.write_text(text[: text.index("dt: d", text.index("distortion_coefficients"))])
    _assert_input_error(read_opencv_yaml, truncated, "'distortion_coefficients'", "truncated")
    missing = tmp_path / "missing.yaml"
    missing.write_text(text.replace("camera_matrix", "camera_matrx"))
    _assert_input_error(read_opencv_yaml, missing, "'camera_matrix'", "is missing")
    ros = tmp_path / "ros.yaml"
    ros.write_text("%YAML:1.0\n---\n" + dump_camera_info(PINHOLE, "c"))
    _assert_input_error(read_opencv_yaml, ros, "'camera_matrix'", "!!opencv-matrix")
    _assert_input_error(read_opencv_yaml, tmp_path / "absent.yaml", "cannot read the file")


def test_opencv_yaml_rejects_extras_that_clash() -> None:
    with pytest.raises(ValueError, match="camera_matrix"):
        dump_opencv_yaml(PINHOLE, {"camera_matrix": 1.0})


# --- Rig transforms --------------------------------------------------------------------------

T_BASE_LIDAR = from_xyz_ypr([0.12, -0.2, 1.5], np.radians([30.0, -5.0, 2.0]))
T_LIDAR_CAM = from_xyz_ypr([0.05, 0.0, -0.1], np.radians([-90.0, 0.0, -90.0]))
COV_LIDAR = np.diag([1e-4, 4e-4, 9e-4, np.radians(0.1) ** 2, np.radians(0.2) ** 2, np.radians(0.3) ** 2])


def make_rig() -> Rig:
    rig = Rig()
    rig.add(Frame("lidar", "base_link", T_BASE_LIDAR, "lidar3d", covariance=COV_LIDAR))
    rig.add(Frame("cam_front", "lidar", T_LIDAR_CAM, "camera"))
    return rig


def test_rig_transforms_round_trip(tmp_path: Path) -> None:
    path = tmp_path / "rig_transforms.yaml"
    path.write_text(dump_rig_transforms(make_rig()))
    lidar, cam = load_rig_transforms(path)
    assert [(f["parent"], f["child"]) for f in (lidar, cam)] == [("base_link", "lidar"), ("lidar", "cam_front")]
    np.testing.assert_allclose(lidar["T_parent_child"], T_BASE_LIDAR, rtol=0, atol=1e-9)
    np.testing.assert_allclose(cam["T_parent_child"], T_LIDAR_CAM, rtol=0, atol=1e-9)
    np.testing.assert_allclose(lidar["sigma"]["trans_m"], [0.01, 0.02, 0.03], rtol=0, atol=1e-12)
    np.testing.assert_allclose(lidar["sigma"]["rot_deg"], [0.1, 0.2, 0.3], rtol=0, atol=1e-12)
    assert cam["sigma"] is None


def test_rig_transforms_document() -> None:
    document = yaml.safe_load(dump_rig_transforms(make_rig()))
    assert document["format"] == "calib-studio-rig-transforms"
    assert (document["version"], document["root"]) == (1, "base_link")
    lidar = document["frames"][0]
    assert list(lidar) == [
        "parent",
        "child",
        "translation_m",
        "quaternion_xyzw",
        "yaw_pitch_roll_deg",
        "sigma",
        "static_transform_publisher",
    ]
    assert lidar["translation_m"] == {"x": 0.12, "y": -0.2, "z": 1.5}
    ypr = lidar["yaw_pitch_roll_deg"]
    np.testing.assert_allclose([ypr["yaw"], ypr["pitch"], ypr["roll"]], [30.0, -5.0, 2.0], rtol=0, atol=1e-12)
    q = lidar["quaternion_xyzw"]
    np.testing.assert_allclose([q["x"], q["y"], q["z"], q["w"]], to_quaternion_xyzw(T_BASE_LIDAR), rtol=0, atol=1e-15)
    assert document["frames"][1]["sigma"] is None


def test_rig_transforms_quaternion_and_ypr_agree_with_from_xyz_ypr() -> None:
    for frame in yaml.safe_load(dump_rig_transforms(make_rig()))["frames"]:
        t = [frame["translation_m"][k] for k in "xyz"]
        ypr_rad = np.radians([frame["yaw_pitch_roll_deg"][k] for k in ("yaw", "pitch", "roll")])
        q = np.array([frame["quaternion_xyzw"][k] for k in "xyzw"])
        assert q[3] >= 0
        np.testing.assert_allclose(to_quaternion_xyzw(from_xyz_ypr(t, ypr_rad)), q, rtol=0, atol=1e-12)


def test_rig_transforms_static_transform_publisher_command() -> None:
    command = yaml.safe_load(dump_rig_transforms(make_rig()))["frames"][0]["static_transform_publisher"]
    words = shlex.split(command)
    assert words[:4] == ["ros2", "run", "tf2_ros", "static_transform_publisher"]
    flags = dict(zip(words[4::2], words[5::2], strict=True))
    assert flags.pop("--frame-id") == "base_link" and flags.pop("--child-frame-id") == "lidar"
    xyz = [float(flags[f"--{k}"]) for k in "xyz"]
    ypr_rad = [float(flags[f"--{k}"]) for k in ("yaw", "pitch", "roll")]
    np.testing.assert_allclose(from_xyz_ypr(xyz, ypr_rad), T_BASE_LIDAR, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ypr_rad, np.radians([30.0, -5.0, 2.0]), rtol=0, atol=1e-12)


def test_rig_transforms_accepts_text_and_either_rotation() -> None:
    document = yaml.safe_load(dump_rig_transforms(make_rig()))
    del document["frames"][0]["quaternion_xyzw"]
    del document["frames"][1]["yaw_pitch_roll_deg"]
    lidar, cam = load_rig_transforms(yaml.safe_dump(document))
    np.testing.assert_allclose(lidar["T_parent_child"], T_BASE_LIDAR, rtol=0, atol=1e-9)
    np.testing.assert_allclose(cam["T_parent_child"], T_LIDAR_CAM, rtol=0, atol=1e-9)


@pytest.mark.parametrize(
    ("edit", "fragments"),
    [
        (lambda d: d["frames"][0]["yaw_pitch_roll_deg"].update(yaw=31.0), ("'frames[0].yaw_pitch_roll_deg'", "1 deg")),
        (lambda d: d["frames"][1].pop("translation_m"), ("'frames[1].translation_m'", "is missing")),
        (lambda d: d["frames"][1].update(parent="imu"), ("'frames[1].parent'", "an earlier child")),
        (lambda d: d["frames"][0]["quaternion_xyzw"].update(w=2.0), ("'frames[0].quaternion_xyzw'", "unit")),
        (lambda d: d["frames"][0]["sigma"].update(rot_deg=[0.1, -0.2]), ("'frames[0].sigma.rot_deg'", "3 non-neg")),
        (lambda d: d["frames"][0]["translation_m"].update(z="1.5 m"), ("'frames[0].translation_m.z'", "finite")),
        (lambda d: d.update(format="tf"), ("'format'", "calib-studio-rig-transforms")),
    ],
    ids=["ypr-vs-quaternion", "no-translation", "unknown-parent", "not-unit", "sigma", "non-numeric", "format"],
)
def test_rig_transforms_bad_fields(tmp_path: Path, edit, fragments: tuple[str, ...]) -> None:
    document = yaml.safe_load(dump_rig_transforms(make_rig()))
    edit(document)
    path = tmp_path / "rig_transforms.yaml"
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    _assert_input_error(load_rig_transforms, path, *fragments)


def test_rig_transforms_truncated_file(tmp_path: Path) -> None:
    text = dump_rig_transforms(make_rig())
    path = tmp_path / "rig_transforms.yaml"
    path.write_text(text[: text.index("quaternion_xyzw") + 30])
    _assert_input_error(load_rig_transforms, path, "not valid YAML", "line")
