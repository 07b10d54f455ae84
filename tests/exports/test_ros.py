"""The rig as ROS loads it: URDF (parsed by yourdfpy), a ROS 2 launch file (run with stand-in launch modules), the
optical and body conventions, refusals, and the urdf/launch/rig exports through the service, the API and the CLI."""

from __future__ import annotations

import importlib.util
import re
import sys
import types
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import get_args

import numpy as np
import pytest
import yaml
import yourdfpy
from fastapi.testclient import TestClient
from scipy.spatial.transform import Rotation

from backend.api.app import create_app
from backend.core.errors import InputError
from backend.core.rig import Frame, Rig
from backend.core.transforms import from_xyz_ypr, make_T
from backend.exports.formats import CONVENTIONS, EXPORT_FORMATS, Convention, ExportFormat
from backend.exports.frame_tree import OPTICAL_SUFFIX, export_frames
from backend.exports.kalibr_camchain import load_kalibr_camchain
from backend.exports.rig_transforms import dump_rig_transforms, load_rig_transforms
from backend.exports.ros2_launch import dump_ros2_launch
from backend.exports.urdf import dump_urdf
from backend.services import exports as export_service
from backend.sim.demo_rig import demo_rig
from backend.store.session import SessionStore
from tests.conftest import cli_in_process

R_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
"""Optical axes in body axes, written out here as REP 103 states them (optical z forward = body x, x right =
body -y, y down = body -z), independently of the exporter's constant."""
COV_CAM = np.diag([1e-6, 4e-6, 9e-6, np.radians(0.01) ** 2, np.radians(0.02) ** 2, np.radians(0.03) ** 2])
COV_LIDAR = np.diag([1e-4, 4e-4, 9e-4, np.radians(0.1) ** 2, np.radians(0.2) ** 2, np.radians(0.3) ** 2])


def optical_mount(xyz_m: list[float], ypr_deg: list[float]) -> np.ndarray:
    """``T_parent_camera`` of an optical frame looking along the turned parent x axis."""
    T = from_xyz_ypr(np.array(xyz_m), np.radians(ypr_deg))
    T[:3, :3] = T[:3, :3] @ R_OPTICAL
    return T


def make_rig() -> Rig:
    """base_link -> lidar_top -> cam_front -> board_mount (a frame on the camera); base_link -> cam_wide, scanner_2d
    (pitched 90 deg: gimbal lock in yaw/pitch/roll); every rotation generic."""
    rig = Rig()
    rig.add(Frame("lidar_top", "base_link", from_xyz_ypr([0.12, -0.2, 1.5], np.radians([30.0, -5.0, 2.0])),
                  "lidar3d", covariance=COV_LIDAR))
    rig.add(Frame("cam_front", "lidar_top", optical_mount([0.2, 0.05, -0.3], [-3.0, 12.0, 1.5]), "camera",
                  covariance=COV_CAM))
    rig.add(Frame("board_mount", "cam_front", from_xyz_ypr([0.0, 0.1, 1.2], np.radians([170.0, 20.0, -40.0]))))
    rig.add(Frame("cam_wide", "base_link", optical_mount([0.3, -0.09, 0.46], [-6.0, 4.5, 1.2]), "camera"))
    rig.add(Frame("scanner_2d", "base_link", from_xyz_ypr([0.38, 0.01, 0.18], np.radians([25.0, 90.0, 0.0])),
                  "lidar2d", covariance=COV_LIDAR))
    return rig


def tree_edges(rig: Rig) -> dict[str, tuple[str, np.ndarray]]:
    """The rig's own ``child -> (parent, T_parent_child)``."""
    return {f.name: (f.parent, f.T_parent_child) for f in rig.frames.values() if f.parent is not None}


def compose(edges: dict[str, tuple[str, np.ndarray]], frame: str, root: str = "base_link") -> np.ndarray:
    """``T_root_frame`` from ``child -> (parent, T_parent_child)`` edges, as a TF listener composes them."""
    T = np.eye(4)
    while frame != root:
        parent, T_parent_child = edges[frame]
        T, frame = T_parent_child @ T, parent
    return T


def where_exported(rig: Rig, name: str, convention: Convention) -> str:
    """The exported frame where the rig's frame ``name`` is: a camera's optical frame in the body convention."""
    return name + OPTICAL_SUFFIX if convention == "body" and rig.get(name).kind == "camera" else name


def quiet(function, *args):
    """Call an exporter with scipy's gimbal-lock warning (scanner_2d is pitched 90 deg) silenced."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock")
        return function(*args)


# --- URDF ---------------------------------------------------------------------------------------


def urdf_joints(text: str) -> dict[str, tuple[str, np.ndarray]]:
    """``child -> (parent, T_parent_child)`` recomputed from the XML: URDF rpy is fixed-axis x, y, z."""
    joints = {}
    for joint in ET.fromstring(text).iter("joint"):
        assert joint.get("type") == "fixed"
        origin = joint.find("origin")
        xyz = [float(v) for v in origin.get("xyz").split()]
        rpy = [float(v) for v in origin.get("rpy").split()]
        R = Rotation.from_euler("xyz", rpy).as_matrix()  # lower case: extrinsic (fixed) axes, R = Rz Ry Rx
        joints[joint.find("child").get("link")] = (joint.find("parent").get("link"), make_T(R, xyz))
    return joints


@pytest.mark.parametrize("convention", get_args(Convention))
def test_urdf_read_by_yourdfpy_gives_the_rig(tmp_path: Path, convention: Convention) -> None:
    rig = make_rig()
    path = tmp_path / "rig.urdf"
    path.write_text(quiet(dump_urdf, rig, "test_rig", convention))
    robot = yourdfpy.URDF.load(str(path), build_scene_graph=True, load_meshes=False)
    assert robot.robot.name == "test_rig" and robot.base_link == "base_link"
    exported = {f.child: f for f in export_frames(rig, convention)}
    assert sorted(link.name for link in robot.robot.links) == sorted(["base_link", *exported])
    assert len(robot.robot.joints) == len(exported)
    joints = urdf_joints(path.read_text())
    for joint in robot.robot.joints:
        frame = exported[joint.child]
        assert joint.type == "fixed" and joint.parent == frame.parent and joint.name == f"{joint.child}_joint"
        np.testing.assert_allclose(joint.origin, frame.T_parent_child, rtol=0, atol=1e-9)
        np.testing.assert_allclose(joints[joint.child][1], frame.T_parent_child, rtol=0, atol=1e-9)
    for name in rig.frames:  # every rig frame where the rig has it, in either convention
        np.testing.assert_allclose(robot.get_transform(where_exported(rig, name, convention), "base_link"),
                                   rig.T_root_frame(name), rtol=0, atol=1e-9)
    if convention == "optical":
        assert {child: parent for child, (parent, _) in joints.items()} == {
            child: parent for child, (parent, _) in tree_edges(rig).items()}


def test_urdf_carries_the_sigma_in_a_comment() -> None:
    text = quiet(dump_urdf, make_rig(), "r")
    assert text.startswith('<?xml version="1.0" encoding="utf-8"?>\n<robot name="r">')
    joint = text[text.index('<joint name="lidar_top_joint"'):text.index("</joint>")]
    found = re.search(r"<!-- 1-sigma: trans_m (\[.*?\]), rot_deg (\[.*?\]) \(about the child's x, y, z\) -->", joint)
    assert found, joint
    np.testing.assert_allclose(yaml.safe_load(found.group(1)), [0.01, 0.02, 0.03], rtol=1e-12)
    np.testing.assert_allclose(yaml.safe_load(found.group(2)), [0.1, 0.2, 0.3], rtol=1e-12)
    assert '<joint name="cam_wide_joint" type="fixed">\n    <parent' in text  # no sigma, no comment


# --- ROS 2 launch file ---------------------------------------------------------------------------


class _LaunchDescription:
    def __init__(self, entities):
        self.entities = list(entities)


class _Node:
    def __init__(self, **kwargs):
        self.kwargs = kwargs


def run_launch_file(path: Path, monkeypatch: pytest.MonkeyPatch) -> list[dict]:
    """Load the launch file as ``ros2 launch`` does (import it, call ``generate_launch_description``) with stand-in
    ``launch`` and ``launch_ros`` modules; returns every Node's keyword arguments."""
    launch = types.ModuleType("launch")
    launch.LaunchDescription = _LaunchDescription
    launch_ros = types.ModuleType("launch_ros")
    actions = types.ModuleType("launch_ros.actions")
    actions.Node = _Node
    launch_ros.actions = actions
    for name, module in (("launch", launch), ("launch_ros", launch_ros), ("launch_ros.actions", actions)):
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("rig_launch", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    assert isinstance(description, _LaunchDescription)
    assert all(isinstance(entity, _Node) for entity in description.entities)
    return [entity.kwargs for entity in description.entities]


def parse_static_transform_arguments(arguments: list[str]) -> tuple[str, str, np.ndarray]:
    """``(frame_id, child_frame_id, T)`` as tf2_ros's static_transform_publisher reads its new-style flags
    (ros2/geometry2 static_transform_broadcaster_program.cpp: every flag takes a value, no positional words, not
    both a quaternion and Euler angles; missing values default to the identity)."""
    assert all(isinstance(word, str) for word in arguments) and len(arguments) % 2 == 0, arguments
    flags = dict(zip(arguments[::2], arguments[1::2], strict=True))
    assert len(flags) == len(arguments) // 2, "a flag given twice"
    known = {"--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw", "--roll", "--pitch", "--yaw", "--frame-id",
             "--child-frame-id"}
    assert set(flags) <= known, set(flags) - known
    assert not ({"--qx", "--qy", "--qz", "--qw"} & set(flags) and {"--roll", "--pitch", "--yaw"} & set(flags))
    number = {k: float(v) for k, v in flags.items() if k not in ("--frame-id", "--child-frame-id")}
    q = np.array([number.get(k, 0.0) for k in ("--qx", "--qy", "--qz")] + [number.get("--qw", 1.0)])
    assert abs(np.linalg.norm(q) - 1.0) < 1e-12
    T = make_T(Rotation.from_quat(q).as_matrix(), [number.get(k, 0.0) for k in ("--x", "--y", "--z")])
    return flags["--frame-id"], flags["--child-frame-id"], T


@pytest.mark.parametrize("convention", get_args(Convention))
def test_launch_file_publishes_the_rig(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       convention: Convention) -> None:
    rig = make_rig()
    path = tmp_path / "rig.launch.py"
    path.write_text(dump_ros2_launch(rig, convention, "for session test"))
    nodes = run_launch_file(path, monkeypatch)
    exported = export_frames(rig, convention)
    assert len(nodes) == len(exported)
    published = {}
    for node, frame in zip(nodes, exported, strict=True):
        assert set(node) == {"package", "executable", "name", "arguments"}
        assert (node["package"], node["executable"]) == ("tf2_ros", "static_transform_publisher")
        assert node["arguments"][::2][:7] == ["--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw"]  # new-style only
        parent, child, T = parse_static_transform_arguments(node["arguments"])
        assert (parent, child) == (frame.parent, frame.child)
        np.testing.assert_allclose(T, frame.T_parent_child, rtol=0, atol=1e-9)
        published[child] = (parent, T)
    assert len({node["name"] for node in nodes}) == len(nodes)
    for name in rig.frames:
        np.testing.assert_allclose(compose(published, where_exported(rig, name, convention)), rig.T_root_frame(name),
                                   rtol=0, atol=1e-9)
    if convention == "optical":
        assert {c: p for c, (p, _) in published.items()} == {c: p for c, (p, _) in tree_edges(rig).items()}


def test_launch_node_names_are_ros_names_and_distinct(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    rig = Rig()
    rig.add(Frame("front-lidar", "base_link"))
    rig.add(Frame("front_lidar", "base_link"))
    path = tmp_path / "names.launch.py"
    path.write_text(dump_ros2_launch(rig))
    names = [node["name"] for node in run_launch_file(path, monkeypatch)]
    assert names == ["static_tf_front_lidar", "static_tf_front_lidar_2"]


# --- conventions ---------------------------------------------------------------------------------


def test_body_convention_round_trip() -> None:
    rig = make_rig()
    body = {f.child: f for f in export_frames(rig, "body")}
    for camera in ("cam_front", "cam_wide"):
        stored = rig.get(camera)
        body_frame, optical = body[camera], body[camera + OPTICAL_SUFFIX]
        assert (body_frame.parent, optical.parent) == (stored.parent, camera)
        np.testing.assert_allclose(body_frame.T_parent_child @ optical.T_parent_child, stored.T_parent_child,
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(optical.T_parent_child, make_T(R_OPTICAL, np.zeros(3)), rtol=0, atol=0)
        R_parent_body, R_parent_optical = body_frame.T_parent_child[:3, :3], stored.T_parent_child[:3, :3]
        # x forward = the optical z, y left = -optical x, z up = -optical y; the same origin
        np.testing.assert_allclose(R_parent_body, np.column_stack(
            [R_parent_optical[:, 2], -R_parent_optical[:, 0], -R_parent_optical[:, 1]]), rtol=0, atol=1e-12)
        np.testing.assert_array_equal(body_frame.T_parent_child[:3, 3], stored.T_parent_child[:3, 3])
    # the frame on the camera hangs from its optical frame with its stored transform
    assert body["board_mount"].parent == "cam_front" + OPTICAL_SUFFIX
    np.testing.assert_array_equal(body["board_mount"].T_parent_child, rig.get("board_mount").T_parent_child)
    for name in ("lidar_top", "scanner_2d"):  # LiDARs unchanged
        assert body[name].parent == rig.get(name).parent
        np.testing.assert_array_equal(body[name].T_parent_child, rig.get(name).T_parent_child)
        np.testing.assert_array_equal(body[name].covariance, rig.get(name).covariance)


def test_body_convention_sigma_turns_with_the_axes() -> None:
    """Rotation sigmas are about the child's axes: the body x is the optical z, y the optical x, z the optical y."""
    frames = yaml.safe_load(quiet(dump_rig_transforms, make_rig(), "body"))["frames"]
    sigma = {f["child"]: f["sigma"] for f in frames}
    np.testing.assert_allclose(sigma["cam_front"]["trans_m"], [0.001, 0.002, 0.003], rtol=0, atol=1e-15)
    np.testing.assert_allclose(sigma["cam_front"]["rot_deg"], [0.03, 0.01, 0.02], rtol=0, atol=1e-15)
    assert sigma["cam_front_optical_frame"] == {"trans_m": [0.0] * 3, "rot_deg": [0.0] * 3}  # exact by definition
    assert sigma["cam_wide"] is None


@pytest.mark.parametrize("convention", get_args(Convention))
def test_rig_transforms_in_either_convention_read_back(convention: Convention) -> None:
    rig = make_rig()
    text = quiet(dump_rig_transforms, rig, convention)
    assert yaml.safe_load(text)["convention"] == convention
    loaded = {f["child"]: (f["parent"], f["T_parent_child"]) for f in load_rig_transforms(text)}
    for name in rig.frames:
        np.testing.assert_allclose(compose(loaded, where_exported(rig, name, convention)), rig.T_root_frame(name),
                                   rtol=0, atol=1e-9)
    with pytest.raises(InputError, match="'convention' is 'sideways'; expected one of"):
        load_rig_transforms(text.replace(f"convention: {convention}", "convention: sideways"))


def test_formats_and_conventions_list_their_literals() -> None:
    assert list(EXPORT_FORMATS) == list(get_args(ExportFormat))
    assert list(CONVENTIONS) == list(get_args(Convention))


# --- refusals ------------------------------------------------------------------------------------


@pytest.mark.parametrize("convention", get_args(Convention))
@pytest.mark.parametrize("dump", [dump_rig_transforms, dump_ros2_launch, lambda rig, c: dump_urdf(rig, "r", c)],
                         ids=["rig", "launch", "urdf"])
def test_a_frame_with_no_parent_is_named(dump, convention: Convention) -> None:
    rig = demo_rig()
    rig.frames["lidar_rear"] = Frame("lidar_rear", None, kind="lidar3d")  # nothing connects it (set behind the rig)
    rig.frames["cam_rear"] = Frame("cam_rear", "lidar_rear", kind="camera")
    with pytest.raises(InputError) as error:
        dump(rig, convention)
    assert error.value.status_code == 409 and error.value.input == "lidar_rear"
    assert error.value.message.startswith("frame 'lidar_rear' has no parent: nothing connects it to 'base_link'")


def test_broken_trees_are_named() -> None:
    rig = demo_rig()
    rig.frames["ghost"] = Frame("ghost", "nowhere")
    with pytest.raises(InputError, match="frame 'ghost' hangs from 'nowhere', which is not in the rig"):
        export_frames(rig)
    del rig.frames["ghost"]
    rig.frames["a"], rig.frames["b"] = Frame("a", "b"), Frame("b", "a")
    with pytest.raises(InputError, match=r"frame 'a': its parents loop \(a -> b -> a\)"):
        export_frames(rig)


def test_body_convention_refuses_a_name_clash() -> None:
    rig = demo_rig()
    rig.add(Frame("cam_front_optical_frame", "base_link"))
    assert export_frames(rig, "optical")
    with pytest.raises(InputError) as error:
        export_frames(rig, "body")
    assert error.value.input == "cam_front_optical_frame" and "rename" in error.value.message


def test_non_finite_transform_is_refused_naming_the_frame() -> None:
    rig = make_rig()
    rig.get("cam_wide").T_parent_child[0, 3] = np.nan  # set behind the frame's back
    for dump in (dump_ros2_launch, lambda r: dump_urdf(r, "r")):
        with pytest.raises(InputError) as error:
            quiet(dump, rig)
        assert "'cam_wide'" in error.value.message and error.value.input == "cam_wide"


# --- through the service, the API and the CLI ------------------------------------------------------


@pytest.fixture
def session(tmp_path: Path):
    return SessionStore(tmp_path / "sessions").create("ros_rig", rig=demo_rig())


@pytest.mark.parametrize(("fmt", "convention", "filename"), [
    ("urdf", None, "ros_rig.urdf"), ("urdf", "body", "ros_rig_body.urdf"),
    ("launch", None, "ros_rig_static_tf.launch.py"), ("launch", "body", "ros_rig_static_tf_body.launch.py"),
    ("rig", "body", "ros_rig_transforms_body.yaml"),
])
def test_export_text(session, fmt: ExportFormat, convention: Convention | None, filename: str) -> None:
    name, text = export_service.export_text(session, fmt, convention=convention)
    expected = {"urdf": dump_urdf(session.rig, "ros_rig", convention or "optical"),
                "launch": dump_ros2_launch(session.rig, convention or "optical", "for session ros_rig"),
                "rig": dump_rig_transforms(session.rig, convention or "optical")}[fmt]
    assert (name, text) == (filename, expected)


@pytest.mark.parametrize(("fmt", "options", "field"), [
    ("kalibr", {"convention": "body"}, "convention"),
    ("camera_info", {"convention": "optical"}, "convention"),
    ("urdf", {"cameras": ["cam_front"]}, "cameras"),
    ("rig", {"convention": "sideways"}, "convention"),
    ("tf", {}, "format"),
])
def test_export_text_refuses_options_that_do_not_apply(session, fmt, options: dict, field: str) -> None:
    with pytest.raises(InputError) as error:
        export_service.export_text(session, fmt, "cam_front", **options)
    assert error.value.input == field and error.value.status_code == 422
    assert field in error.value.message


def test_exports_through_the_api(tmp_path: Path) -> None:
    app = create_app(tmp_path)
    with TestClient(app) as client:
        session = app.state.studio.store.create("ros_rig", rig=demo_rig())
        formats = client.get("/api/exports/formats").json()
        assert list(formats) == list(EXPORT_FORMATS) and "urdf" in formats and "launch" in formats
        response = client.get("/api/sessions/ros_rig/export/urdf", params={"convention": "body"})
        assert response.status_code == 200, response.text
        assert response.headers["content-type"].startswith("application/xml")
        assert 'filename="ros_rig_body.urdf"' in response.headers["content-disposition"]
        assert response.text == dump_urdf(session.rig, "ros_rig", "body")
        response = client.get("/api/sessions/ros_rig/export/launch")
        assert response.status_code == 200 and response.headers["content-type"].startswith("text/x-python")
        assert response.text == dump_ros2_launch(session.rig, "optical", "for session ros_rig")
        for params, field in (({"convention": "sideways"}, "convention"), ({"cameras": "cam_front"}, "cameras")):
            response = client.get("/api/sessions/ros_rig/export/urdf", params=params)
            assert response.status_code == 422, response.text
            assert field in response.text
        response = client.get("/api/sessions/ros_rig/export/kalibr", params={"convention": "body"})
        assert response.status_code == 422 and response.json()["error"]["input"] == "convention"
        session.rig.add(Frame("lidar_rear", "base_link", kind="lidar3d", mount_sigma=None))
        response = client.get("/api/sessions/ros_rig/export/launch")
        assert response.status_code == 409
        assert response.json()["error"]["input"] == "lidar_rear"
        assert response.json()["error"]["message"].startswith("lidar_rear: not connected to base_link by any edge")
    app.state.studio.jobs.shutdown()


@pytest.fixture
def loose_session(tmp_path: Path):
    """The demo rig with a LiDAR and a camera whose mounting is unknown and that no calibration places."""
    rig = demo_rig()
    rig.add(Frame("lidar_rear", "base_link", kind="lidar3d", mount_sigma=None))
    rig.add(Frame("cam_rear", "base_link", kind="camera", intrinsics=rig.get("cam_front").intrinsics,
                  mount_sigma=None))
    return SessionStore(tmp_path / "sessions").create("loose", rig=rig)


@pytest.mark.parametrize("fmt", ["rig", "urdf", "launch"])
def test_a_frame_no_edge_connects_is_named(loose_session, fmt: ExportFormat) -> None:
    with pytest.raises(InputError) as error:
        export_service.export_text(loose_session, fmt)
    assert (error.value.status_code, error.value.input) == (409, "lidar_rear, cam_rear")
    assert error.value.message.startswith("lidar_rear, cam_rear: not connected to base_link by any edge")
    assert "lidar_rear connects to no other frame; cam_rear connects to no other frame" in error.value.message


def test_kalibr_leaves_out_a_camera_no_edge_connects(loose_session) -> None:
    _, text = export_service.export_text(loose_session, "kalibr")
    assert "# left out: cam_rear is not connected to base_link by any edge\n" in text
    assert [name for name, _ in load_kalibr_camchain(text)[0]] == ["cam_front", "cam_right"]
    with pytest.raises(InputError) as error:
        export_service.export_text(loose_session, "kalibr", cameras=["cam_front", "cam_rear"])
    assert (error.value.status_code, error.value.input) == (409, "cam_rear")


@pytest.mark.slow
def test_an_unconnected_frame_through_the_cli(loose_session) -> None:
    run = cli_in_process("export", loose_session.path, "--format", "urdf")
    assert run.returncode == 2 and run.stdout == ""
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("error: lidar_rear, cam_rear: not connected to base_link by any edge"), run.stderr


@pytest.mark.slow
def test_exports_through_the_cli(session, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    out = tmp_path / "rig.urdf"
    run = cli_in_process("export", session.path, "--format", "urdf", "--convention", "body", "--out", out)
    assert run.returncode == 0 and run.stdout == "", run.stderr
    assert out.read_text() == dump_urdf(session.rig, "ros_rig", "body")
    run = cli_in_process("export", session.path, "--format", "launch")
    assert run.returncode == 0, run.stderr
    assert run.stdout == dump_ros2_launch(session.rig, "optical", "for session ros_rig")
    launch_file = tmp_path / "rig.launch.py"
    launch_file.write_text(run.stdout)
    assert len(run_launch_file(launch_file, monkeypatch)) == len(session.rig.frames) - 1

    run = cli_in_process("export", session.path, "--format", "kalibr", "--convention", "body")
    assert run.returncode == 2 and run.stdout == ""
    assert run.stderr.strip().splitlines()[-1].startswith("error: convention: the kalibr export has no convention")
    run = cli_in_process("export", session.path, "--format", "urdf", "--convention", "sideways")
    assert run.returncode == 2 and "invalid choice: 'sideways'" in run.stderr
