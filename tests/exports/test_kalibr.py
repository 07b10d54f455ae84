"""Kalibr camchain export: round trip, the T_cn_cnm1 chain, Kalibr's field rules, refusals, bad files, the session;
with an IMU, the camchain-imucam keys."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.rig import Frame
from backend.core.transforms import from_xyz_ypr, invert
from backend.exports.kalibr_camchain import K3_TOLERANCE_PX, dump_kalibr_camchain, load_kalibr_camchain
from backend.services import exports as export_service
from backend.sim.demo_rig import demo_rig
from backend.store.session import SessionStore
from tests.conftest import cli_in_process

LEFT = CameraIntrinsics(
    "pinhole-radtan", 752, 480,
    [[461.6291234567891, 0.0, 362.6801234567], [0.0, 460.1523456789012, 246.0491234], [0.0, 0.0, 1.0]],
    [-0.27695497123456, 0.06712482987654, 0.00087538123, 0.00011556789, 0.0],
)
FISHEYE = CameraIntrinsics(
    "fisheye-equidistant", 1280, 800,
    [[412.3456789012345, 0.0, 641.2], [0.0, 411.9876543210987, 398.7], [0.0, 0.0, 1.0]],
    [-0.01316123456789, 0.05008123456, -0.04506123456789, 0.01241234567],
)
RIGHT = CameraIntrinsics(
    "pinhole-radtan", 752, 480,
    [[458.6548765432109, 0.0, 367.2151234], [0.0, 457.2961234567, 248.3751234], [0.0, 0.0, 1.0]],
    [-0.28340811234, 0.07395907654, -0.00019359, 1.76187114e-05, 0.0],
)
CAMERAS = [("cam_left", LEFT), ("cam_fisheye", FISHEYE), ("cam_right", RIGHT)]
T_REF_CAM = {
    "cam_left": np.eye(4),
    "cam_fisheye": from_xyz_ypr(np.array([0.05, -0.12, 0.02]), np.radians([30.0, -12.0, 4.0])),
    "cam_right": from_xyz_ypr(np.array([0.11003785, 0.0004, -0.0009]), np.radians([0.3, -0.2, 0.6])),
}
"""cam_right 11 cm to the right (+x) of cam_left, as in the stereo example of Kalibr's wiki; the fisheye off-axis."""


def assert_same_camera(a: CameraIntrinsics, b: CameraIntrinsics) -> None:
    assert (a.model, a.width, a.height) == (b.model, b.width, b.height)
    np.testing.assert_allclose(a.K, b.K, rtol=0, atol=1e-12)
    np.testing.assert_allclose(a.dist, b.dist, rtol=0, atol=1e-12)


@pytest.fixture
def camchain_file(tmp_path: Path) -> Path:
    path = tmp_path / "rig-camchain.yaml"
    path.write_text(dump_kalibr_camchain(CAMERAS, T_REF_CAM), encoding="utf-8")
    return path


# --- round trip and layout ---------------------------------------------------------------------


@pytest.mark.parametrize("from_file", [False, True], ids=["text", "file"])
def test_round_trip(camchain_file: Path, from_file: bool) -> None:
    source = camchain_file if from_file else camchain_file.read_text()
    cameras, T_ref_cam = load_kalibr_camchain(source)
    assert [name for name, _ in cameras] == [name for name, _ in CAMERAS]
    for (_, loaded), (_, original) in zip(cameras, CAMERAS, strict=True):
        assert_same_camera(loaded, original)
    assert list(T_ref_cam) == list(T_REF_CAM)
    for name, T in T_REF_CAM.items():
        np.testing.assert_allclose(T_ref_cam[name], T, rtol=0, atol=1e-12)


def test_round_trip_is_relative_to_cam0() -> None:
    """Only relative poses are written: a reference that is not cam0 comes back as cam0."""
    T_world_left = from_xyz_ypr(np.array([1.5, -2.0, 0.7]), np.radians([80.0, 10.0, -5.0]))
    T_world_cam = {name: T_world_left @ T for name, T in T_REF_CAM.items()}
    _, T_ref_cam = load_kalibr_camchain(dump_kalibr_camchain(CAMERAS, T_world_cam))
    for name, T in T_REF_CAM.items():
        np.testing.assert_allclose(T_ref_cam[name], T, rtol=0, atol=1e-12)


def test_kalibr_layout_and_field_types() -> None:
    """What Kalibr's ConfigReader checks: pinhole [fu, fv, pu, pv] as floats, 4 coefficients, int resolution."""
    document = yaml.safe_load(dump_kalibr_camchain(CAMERAS, T_REF_CAM))
    assert list(document) == ["cam0", "cam1", "cam2"]
    assert "T_cn_cnm1" not in document["cam0"]
    for i, (name, camera) in enumerate(CAMERAS):
        entry = document[f"cam{i}"]
        assert list(entry) == sorted(entry), "keys in the alphabetical order of Kalibr's own writer"
        assert entry["camera_model"] == "pinhole"
        assert entry["intrinsics"] == [camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]]
        assert all(type(v) is float for v in entry["intrinsics"])
        assert entry["resolution"] == [camera.width, camera.height]
        assert all(type(v) is int for v in entry["resolution"])
        assert len(entry["distortion_coeffs"]) == 4 and all(type(v) is float for v in entry["distortion_coeffs"])
        assert entry["rostopic"] == f"/{name}/image_raw"
        assert entry["cam_overlaps"] == [j for j in range(3) if j != i]
    assert [document[f"cam{i}"]["distortion_model"] for i in range(3)] == ["radtan", "equidistant", "radtan"]
    assert document["cam0"]["distortion_coeffs"] == LEFT.dist[:4].tolist()  # k1 k2 r1 r2 = OpenCV k1 k2 p1 p2
    assert document["cam1"]["distortion_coeffs"] == FISHEYE.dist.tolist()


def test_chain_semantics_on_three_cameras() -> None:
    """T_cn_cnm1 maps points in camera n-1 into camera n (Kalibr: T_c1_c0 takes cam0 to cam1 coordinates)."""
    document = yaml.safe_load(dump_kalibr_camchain(CAMERAS, T_REF_CAM))
    T_c1_c0 = np.array(document["cam1"]["T_cn_cnm1"])
    T_c2_c1 = np.array(document["cam2"]["T_cn_cnm1"])
    assert T_c1_c0.shape == T_c2_c1.shape == (4, 4)

    # one point seen by all three cameras, expressed in each camera's optical frame
    p_ref = np.array([0.3, -0.2, 2.5, 1.0])
    p_cam = [invert(T_REF_CAM[name]) @ p_ref for name, _ in CAMERAS]
    np.testing.assert_allclose(T_c1_c0 @ p_cam[0], p_cam[1], atol=1e-12)
    np.testing.assert_allclose(T_c2_c1 @ p_cam[1], p_cam[2], atol=1e-12)
    # composing the chain gives cam2 <- cam0 directly
    np.testing.assert_allclose(T_c2_c1 @ T_c1_c0, invert(T_REF_CAM["cam_right"]), atol=1e-12)

    # a plain stereo pair, right camera 11 cm along +x of the left: Kalibr writes t = (-0.11, 0, 0)
    T_ref = {"cam_left": np.eye(4), "cam_right": from_xyz_ypr(np.array([0.11, 0.0, 0.0]), np.zeros(3))}
    stereo = yaml.safe_load(dump_kalibr_camchain([("cam_left", LEFT), ("cam_right", RIGHT)], T_ref))
    np.testing.assert_allclose(np.array(stereo["cam1"]["T_cn_cnm1"])[:3, 3], [-0.11, 0.0, 0.0], atol=1e-15)


def test_topics_overlaps_and_names() -> None:
    topics = {"cam_left": "/stereo/left/image_raw", "cam_right": "/stereo/right/image_raw"}
    overlaps = {"cam_left": ["cam_right"], "cam_right": ["cam_left"], "cam_fisheye": []}
    text = dump_kalibr_camchain(CAMERAS, T_REF_CAM, topics=topics, overlaps=overlaps)
    document = yaml.safe_load(text)
    assert document["cam0"]["rostopic"] == "/stereo/left/image_raw"
    assert document["cam1"]["rostopic"] == "/cam_fisheye/image_raw"
    assert [document[f"cam{i}"]["cam_overlaps"] for i in range(3)] == [[2], [], [0]]
    cameras, _ = load_kalibr_camchain(text)
    assert [name for name, _ in cameras] == ["stereo_left", "cam_fisheye", "stereo_right"]

    # no topic, or two topics naming one camera: camN
    del document["cam0"]["rostopic"]
    document["cam2"]["rostopic"] = "/cam_fisheye/image_raw"
    cameras, T_ref_cam = load_kalibr_camchain(yaml.safe_dump(document))
    assert [name for name, _ in cameras] == ["cam0", "cam_fisheye", "cam2"]
    np.testing.assert_allclose(T_ref_cam["cam2"], T_REF_CAM["cam_right"], atol=1e-12)

    with pytest.raises(InputError, match="cam_fisheye.*'nowhere'"):
        dump_kalibr_camchain(CAMERAS, T_REF_CAM, overlaps={"cam_fisheye": ["nowhere"]})


# --- refusals ---------------------------------------------------------------------------------


def _k3_corner_shift_px(camera: CameraIntrinsics) -> float:
    """Largest move (px) of the image corners' pixels when k3 is set to 0 (same rays)."""
    w, h = camera.width - 1.0, camera.height - 1.0
    rays = camera.undistort_points(np.array([[0.0, 0.0], [w, 0.0], [0.0, h], [w, h]]))
    no_k3 = CameraIntrinsics(camera.model, camera.width, camera.height, camera.K, [*camera.dist[:4], 0.0])
    return float(np.max(np.linalg.norm(camera.project_normalised(rays) - no_k3.project_normalised(rays), axis=1)))


def test_k3_is_refused_naming_the_camera() -> None:
    wide = CameraIntrinsics("pinhole-radtan", 752, 480, RIGHT.K, [-0.25, 0.0925, 0.0003, 0.0004, -0.0115])
    with pytest.raises(InputError) as error:
        dump_kalibr_camchain([("cam_left", LEFT), ("cam_wide", wide)], {"cam_left": np.eye(4), "cam_wide": np.eye(4)})
    assert error.value.input == "cam_wide"
    message = error.value.message
    assert message.startswith("cam_wide: k3 = -0.0115") and "Kalibr's radtan" in message and "k3 fixed at 0" in message
    # the shift it reports is what dropping k3 does to the image corners (27 px here)
    shift_px = float(message.split(" by ")[1].split(" px")[0])
    assert shift_px == pytest.approx(_k3_corner_shift_px(wide), rel=0.01)
    assert shift_px > 20

    # a k3 whose effect stays under K3_TOLERANCE_PX at the corners is dropped (Kalibr's file cannot hold it)
    tiny = CameraIntrinsics("pinhole-radtan", 752, 480, RIGHT.K, [*RIGHT.dist[:4], 1e-7])
    assert 0 < _k3_corner_shift_px(tiny) < K3_TOLERANCE_PX
    text = dump_kalibr_camchain([("a", LEFT), ("b", tiny)], {"a": np.eye(4), "b": np.eye(4)})
    cameras, _ = load_kalibr_camchain(text)
    np.testing.assert_array_equal(cameras[1][1].dist, [*RIGHT.dist[:4], 0.0])


def test_other_refusals() -> None:
    skewed = CameraIntrinsics("pinhole-radtan", 752, 480, [[460.0, 0.5, 360.0], [0.0, 460.0, 240.0], [0, 0, 1]])
    with pytest.raises(InputError, match="cam_skew: K has skew"):
        dump_kalibr_camchain([("cam_skew", skewed)], {"cam_skew": np.eye(4)})
    with pytest.raises(InputError, match="no T_ref_cam for camera 'cam_right'"):
        dump_kalibr_camchain(CAMERAS, {"cam_left": np.eye(4), "cam_fisheye": np.eye(4)})
    not_rigid = dict(T_REF_CAM, cam_fisheye=np.diag([1.0, 1.0, 2.0, 1.0]))
    with pytest.raises(InputError, match="T_ref_cam of 'cam_fisheye' is not a rigid"):
        dump_kalibr_camchain(CAMERAS, not_rigid)
    with pytest.raises(InputError, match="'cam_left' is listed twice"):
        dump_kalibr_camchain([("cam_left", LEFT), ("cam_left", RIGHT)], T_REF_CAM)


# --- bad files --------------------------------------------------------------------------------


def _edit(path: Path, change) -> Path:
    document = yaml.safe_load(path.read_text())
    change(document)
    path.write_text(yaml.safe_dump(document, sort_keys=False))
    return path


BAD_FILES = {
    "row_missing": (lambda d: d["cam1"]["T_cn_cnm1"].pop(), "cam1.T_cn_cnm1", "has 3 rows"),
    "short_row": (lambda d: d["cam2"]["T_cn_cnm1"][2].pop(), "cam2.T_cn_cnm1[2]", "has 3 values"),
    "not_rigid": (lambda d: d["cam2"]["T_cn_cnm1"][0].__setitem__(0, 2.0), "cam2.T_cn_cnm1", "not rigid"),
    "text_number": (lambda d: d["cam0"]["intrinsics"].__setitem__(1, "four hundred"), "cam0.intrinsics[1]",
                    "'four hundred'"),
    "three_coeffs": (lambda d: d["cam0"]["distortion_coeffs"].pop(), "cam0.distortion_coeffs", "has 3 values"),
    "omni": (lambda d: d["cam1"].__setitem__("camera_model", "omni"), "cam1.camera_model", "not supported"),
    "fov": (lambda d: d["cam2"].__setitem__("distortion_model", "fov"), "cam2.distortion_model", "not supported"),
    "float_resolution": (lambda d: d["cam0"].__setitem__("resolution", [752.0, 480]), "cam0.resolution", "752.0"),
    "no_chain": (lambda d: d["cam1"].pop("T_cn_cnm1"), "cam1.T_cn_cnm1", "is missing"),
    "gap": (lambda d: d.pop("cam1"), "cam1", "is missing"),
    "overlap_range": (lambda d: d["cam0"].__setitem__("cam_overlaps", [1, 3]), "cam0.cam_overlaps[1]", "is 3"),
}


@pytest.mark.parametrize("case", list(BAD_FILES))
def test_garbled_file_names_file_and_field(camchain_file: Path, case: str) -> None:
    change, field, problem = BAD_FILES[case]
    _edit(camchain_file, change)
    with pytest.raises(InputError) as error:
        load_kalibr_camchain(camchain_file)
    assert error.value.input == str(camchain_file)
    assert error.value.message.startswith(f"{camchain_file}: field '{field}' ")
    assert problem in error.value.message


def test_truncated_file(camchain_file: Path) -> None:
    text = camchain_file.read_text()
    # cut inside cam2's T_cn_cnm1: a flow list left open is a YAML error with its position
    cut = text.index("[", text.index("T_cn_cnm1", text.index("cam2:"))) + 12
    camchain_file.write_text(text[:cut])
    with pytest.raises(InputError) as error:
        load_kalibr_camchain(camchain_file)
    assert error.value.input == str(camchain_file)
    assert error.value.message.startswith(f"{camchain_file}: not valid YAML at line ")
    assert "truncated" in error.value.message

    # cut at a line end after two rows of that matrix: the fields that are gone are named
    lines = text.splitlines(keepends=True)
    row = next(i for i, line in enumerate(lines) if line.startswith("cam2:")) + 3
    camchain_file.write_text("".join(lines[:row]))
    with pytest.raises(InputError, match=rf"^{camchain_file}: field 'cam2\.camera_model' is missing"):
        load_kalibr_camchain(camchain_file)

    camchain_file.write_text("")
    with pytest.raises(InputError, match="the document is empty"):
        load_kalibr_camchain(camchain_file)
    with pytest.raises(InputError, match="cannot read the file"):
        load_kalibr_camchain(camchain_file.with_name("missing.yaml"))


# --- through the session, the API and the CLI -------------------------------------------------


@pytest.fixture
def session(tmp_path: Path):
    """The demo rig's cam_front and cam_wide (cam_right taken out), with cam_wide recalibrated with k3 fixed at 0,
    as the studio does."""
    rig = demo_rig()
    del rig.frames["cam_right"]
    rig.get("cam_wide").intrinsics.dist[4] = 0.0
    return SessionStore(tmp_path).create("stereo_rig", rig=rig)


def test_export_text_kalibr(session) -> None:
    assert export_service.EXPORT_FORMATS["kalibr"] == ("Kalibr camchain YAML (T_cn_cnm1 chain; with an IMU, "
                                                       "camchain-imucam)")
    filename, text = export_service.export_text(session, "kalibr")
    assert filename == "stereo_rig_camchain.yaml"
    cameras, T_ref_cam = load_kalibr_camchain(text)
    rig = session.rig
    assert [name for name, _ in cameras] == [f.name for f in rig.sensors("camera")] == ["cam_front", "cam_wide"]
    for name, camera in cameras:
        assert_same_camera(camera, rig.get(name).intrinsics)
    np.testing.assert_allclose(T_ref_cam["cam_front"], np.eye(4), atol=0)
    np.testing.assert_allclose(T_ref_cam["cam_wide"], rig.T_a_b("cam_front", "cam_wide"), rtol=0, atol=1e-12)
    T_c1_c0 = np.array(yaml.safe_load(text)["cam1"]["T_cn_cnm1"])
    np.testing.assert_allclose(T_c1_c0, rig.T_a_b("cam_wide", "cam_front"), rtol=0, atol=1e-12)


def test_with_an_imu_the_export_is_kalibrs_camchain_imucam(session) -> None:
    """Each camera gets ``T_cam_imu`` (IMU points into the camera, from the rig) and ``timeshift_cam_imu``
    (``t_imu = t_cam + shift``, from the clock offsets); the first IMU is written, the comment names both."""
    rig = session.rig
    rig.add(Frame("imu0", "base_link", from_xyz_ypr(np.array([0.02, -0.07, 0.01]), np.radians([90.0, 1.0, -2.0])),
                  kind="imu", clock_offset_s=0.0123))
    rig.add(Frame("imu1", "base_link", kind="imu"))
    rig.get("cam_wide").clock_offset_s = -0.004
    _, text = export_service.export_text(session, "kalibr")
    assert text.startswith("# camchain-imucam: T_cam_imu maps points in IMU imu0 (the rig's first IMU; not written: "
                           "imu1) into each camera; timeshift_cam_imu (s) is t_imu = t_cam + timeshift\n"), text
    document = yaml.safe_load(text)
    for index, name in enumerate(["cam_front", "cam_wide"]):
        entry = document[f"cam{index}"]
        np.testing.assert_allclose(entry["T_cam_imu"], rig.T_a_b(name, "imu0"), rtol=0, atol=1e-12)
        assert entry["timeshift_cam_imu"] == pytest.approx(0.0123 - rig.get(name).clock_offset_s, abs=1e-15)
        assert list(entry)[0] == "T_cam_imu" and list(entry)[-1] == "timeshift_cam_imu"  # Kalibr's (sorted) order
    cameras, T_ref_cam = load_kalibr_camchain(text)  # Kalibr's camchain reader ignores the IMU's keys; so do we
    assert [name for name, _ in cameras] == ["cam_front", "cam_wide"]
    np.testing.assert_allclose(T_ref_cam["cam_wide"], rig.T_a_b("cam_front", "cam_wide"), rtol=0, atol=1e-12)


def test_export_text_kalibr_refusals(session) -> None:
    session.rig.get("cam_wide").intrinsics = None
    with pytest.raises(InputError) as error:
        export_service.export_text(session, "kalibr")
    assert error.value.status_code == 409
    assert error.value.input == "cam_wide"
    assert ("at least two cameras with intrinsics Kalibr can describe; cam_wide has no intrinsics yet"
            in error.value.message)


def test_a_camera_outside_the_subset_no_longer_blocks_the_export(tmp_path: Path) -> None:
    """The demo rig as it is: cam_wide's lens has a k3 Kalibr's radtan cannot hold."""
    session = SessionStore(tmp_path).create("demo_rig", rig=demo_rig())
    rig = session.rig
    _, text = export_service.export_text(session, "kalibr")
    cameras, T_ref_cam = load_kalibr_camchain(text)
    assert [name for name, _ in cameras] == ["cam_front", "cam_right"]
    np.testing.assert_allclose(T_ref_cam["cam_right"], rig.T_a_b("cam_front", "cam_right"), rtol=0, atol=1e-12)
    assert text.startswith("# left out: cam_wide: k3 = -0.0115 moves the farthest image corner by ")
    assert "recalibrate cam_wide with k3 fixed at 0" in text.splitlines()[0]

    _, text = export_service.export_text(session, "kalibr", cameras=["cam_right", "cam_front"])
    assert not text.startswith("#")
    cameras, T_ref_cam = load_kalibr_camchain(text)
    assert [name for name, _ in cameras] == ["cam_right", "cam_front"]
    np.testing.assert_allclose(T_ref_cam["cam_front"], rig.T_a_b("cam_right", "cam_front"), rtol=0, atol=1e-12)
    cameras, _ = load_kalibr_camchain(export_service.export_text(session, "kalibr", cameras=["cam_front"])[1])
    assert [name for name, _ in cameras] == ["cam_front"]


@pytest.mark.parametrize(("cameras", "status", "start"), [
    (["cam_front", "cam_wide"], 422, "cam_wide: k3 = -0.0115"),
    (["cam_front", "lidar_top"], 422, "lidar_top is a lidar3d, not a camera"),
    (["cam_front", "cam_rear"], 404, "no sensor or frame named 'cam_rear'"),
    (["cam_front", "cam_front"], 422, "camera 'cam_front' is listed twice"),
    ([], 422, "the kalibr export needs at least one camera"),
])
def test_a_camera_inside_the_subset_kalibr_cannot_describe_is_named(tmp_path: Path, cameras, status: int,
                                                                     start: str) -> None:
    session = SessionStore(tmp_path).create("demo_rig", rig=demo_rig())
    with pytest.raises(InputError) as error:
        export_service.export_text(session, "kalibr", cameras=cameras)
    assert error.value.status_code == status and error.value.message.startswith(start), error.value.message


def test_a_camera_without_intrinsics_inside_the_subset_is_named(session) -> None:
    session.rig.get("cam_wide").intrinsics = None
    with pytest.raises(InputError) as error:
        export_service.export_text(session, "kalibr", cameras=["cam_front", "cam_wide"])
    assert (error.value.status_code, error.value.input) == (409, "cam_wide")
    assert error.value.message.startswith("cam_wide has no intrinsics yet")
    assert export_service.export_text(session, "kalibr", cameras=["cam_front"])  # without it the export goes


@pytest.mark.slow
def test_kalibr_through_api_and_cli(session, tmp_path: Path) -> None:
    app = create_app(tmp_path)
    with TestClient(app) as client:
        assert "kalibr" in client.get("/api/exports/formats").json()
        response = client.get(f"/api/sessions/{session.name}/export/kalibr")
        assert response.status_code == 200, response.text
        assert 'filename="stereo_rig_camchain.yaml"' in response.headers["content-disposition"]
        assert [name for name, _ in load_kalibr_camchain(response.text)[0]] == ["cam_front", "cam_wide"]
        demo = app.state.studio.store.create("demo_rig", rig=demo_rig())
        for cameras in (["cam_right,cam_front"], ["cam_right", "cam_front"]):  # comma-separated, or repeated
            response = client.get("/api/sessions/demo_rig/export/kalibr", params={"cameras": cameras})
            assert response.status_code == 200, response.text
            assert [name for name, _ in load_kalibr_camchain(response.text)[0]] == ["cam_right", "cam_front"]
        response = client.get("/api/sessions/demo_rig/export/kalibr", params={"cameras": "cam_front,cam_wide"})
        assert response.status_code == 422
        assert response.json()["error"]["input"] == "cam_wide"
        assert response.json()["error"]["message"].startswith("cam_wide: k3 = -0.0115")
    app.state.studio.jobs.shutdown()

    run = cli_in_process("export", demo.path, "--format", "kalibr", "--cameras", "cam_front,cam_right")
    assert run.returncode == 0, run.stderr
    assert [name for name, _ in load_kalibr_camchain(run.stdout)[0]] == ["cam_front", "cam_right"]
    run = cli_in_process("export", demo.path, "--format", "kalibr", "--cameras", "cam_front,cam_wide")
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.strip().splitlines()[-1].startswith("error: cam_wide: k3 = -0.0115")
