"""One broken file breaks only itself: broken sessions are listed with their reason, broken results and captures
are quarantined and reported by name, temp files of killed writes are cleaned, and no NaN or infinity enters
the rig, the session file or an export."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.imu import ImuSamples
from backend.core.rig import Frame, Rig
from backend.exports.opencv_yaml import dump_opencv_yaml, read_opencv_yaml
from backend.exports.rig_transforms import dump_rig_transforms, load_rig_transforms, static_transform_publisher
from backend.exports.ros_camera_info import dump_camera_info, load_camera_info
from backend.store.atomic import TEMP_NAME, UPLOAD_FOLDER_PREFIX
from backend.store.session import SESSION_FILE, Session, SessionStore
from tests.conftest import ROOT, button, studio_page, unfold, wait_body

BOARD = "checkerboard:9x6:0.025"


def intrinsics_record(fx: float = 500.0) -> dict:
    """A stored intrinsics result (only what accept reads)."""
    return {"kind": "intrinsics",
            "camera": {"model": "pinhole-radtan", "width": 640, "height": 480,
                       "K": [[fx, 0.0, 320.0], [0.0, fx, 240.0], [0.0, 0.0, 1.0]], "dist": [0.0] * 5},
            "rms_px": 0.2, "verdict": {"level": "trusted", "reasons": ["a test record"]}}


def assert_error(response, status: int, names: str) -> dict:
    """A 4xx with the documented body whose message or input names ``names``."""
    assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"error"} and set(body["error"]) == {"message", "input"}, body
    assert names in body["error"]["message"] or names in (body["error"]["input"] or ""), body
    return body["error"]


@pytest.fixture
def client_for():
    """``client_for(root)``: a test client of the API over the sessions in ``root`` (built beforehand on disk)."""
    apps = []

    def make(root: Path) -> TestClient:
        app = create_app(root)
        apps.append(app)
        return TestClient(app)

    yield make
    for app in apps:
        app.state.studio.jobs.shutdown()


def nan_session_json(path: Path) -> None:
    """Put a NaN into the translation of the session's first sensor (written as Python's json does: ``NaN``)."""
    raw = json.loads((path / SESSION_FILE).read_text())
    raw["rig"]["frames"][1]["T_parent_child"][0][3] = float("nan")
    (path / SESSION_FILE).write_text(json.dumps(raw))
    assert "NaN" in (path / SESSION_FILE).read_text()


# -- sessions -------------------------------------------------------------------------------


def test_broken_sessions_are_listed_and_the_others_open(tmp_path: Path, client_for):
    store = SessionStore(tmp_path)
    for name in ("alpha", "mangled", "nanrig", "zulu"):
        store.create(name, board=BOARD).add_sensor(Frame("cam", "base_link", kind="camera"))
    mangled = (tmp_path / "mangled" / SESSION_FILE)
    mangled.write_text(mangled.read_text()[:40])  # cut off mid-write by hand
    nan_session_json(tmp_path / "nanrig")
    before = {name: (tmp_path / name / SESSION_FILE).read_bytes() for name in ("mangled", "nanrig")}

    client = client_for(tmp_path)
    response = client.get("/api/sessions")
    assert response.status_code == 200, response.text
    listing = {entry["name"]: entry for entry in response.json()}
    assert sorted(listing) == ["alpha", "mangled", "nanrig", "zulu"]
    for good in ("alpha", "zulu"):
        assert listing[good]["broken"] is None and listing[good]["sensors"] == ["cam"]
    assert "not valid JSON" in listing["mangled"]["broken"]["message"]
    assert listing["mangled"]["broken"]["input"] == "mangled/session.json"  # never where the server keeps it
    reason = listing["nanrig"]["broken"]["message"]
    assert "rig.frames.1.T_parent_child.0.3" in reason and "finite" in reason, reason

    assert client.get("/api/sessions/alpha").json()["sensors"] == ["cam"]
    assert_error(client.get("/api/sessions/mangled"), 422, names="mangled/session.json")
    assert_error(client.get("/api/sessions/nanrig"), 422, names="T_parent_child")
    # a broken session file stays where it is, as it was, for the user to repair
    for name, data in before.items():
        assert (tmp_path / name / SESSION_FILE).read_bytes() == data


@pytest.mark.parametrize(("change", "field"), [
    (lambda raw: raw.update(created=float("inf")), "created"),
    (lambda raw: raw["rig"]["frames"][1].update(device={"driver": "sim", "rate_hz": float("nan")}),
     "rig.frames.1.device"),
    (lambda raw: raw["rig"]["frames"][1].update(covariance=[[float("-inf")] * 6] * 6), "covariance"),
])
def test_non_finite_session_file_is_broken_naming_the_field(tmp_path: Path, change, field: str):
    store = SessionStore(tmp_path)
    store.create("rig", board=BOARD).add_sensor(Frame("cam", "base_link", kind="camera"))
    raw = json.loads((tmp_path / "rig" / SESSION_FILE).read_text())
    change(raw)
    (tmp_path / "rig" / SESSION_FILE).write_text(json.dumps(raw))
    [entry] = SessionStore(tmp_path).listing()
    assert entry["name"] == "rig" and field in entry["broken"]["message"], entry


def test_saving_a_non_finite_camera_is_refused_and_the_file_kept(tmp_path: Path):
    store = SessionStore(tmp_path)
    session = store.create("rig", board=BOARD)
    session.add_sensor(Frame("cam", "base_link", kind="camera"))
    record = intrinsics_record()
    record["camera"]["K"][0][0] = float("nan")
    result_id = session.add_result("cam", record, inputs=[])
    saved = (session.path / SESSION_FILE).read_bytes()

    def apply(rig: Rig, rec: dict) -> None:
        rig.get("cam").intrinsics = CameraIntrinsics.from_dict(rec["camera"])

    with pytest.raises(InputError) as err:
        session.accept("cam/intrinsics", result_id, apply)
    assert "not saved" in err.value.message and "frames.1.intrinsics.K.0.0" in err.value.message
    assert (session.path / SESSION_FILE).read_bytes() == saved
    assert session.rig.get("cam").intrinsics is None and session.accepted("cam/intrinsics") is None
    assert SessionStore(tmp_path).get("rig").rig.get("cam").intrinsics is None


# -- results and captures -------------------------------------------------------------------


def test_corrupt_result_is_quarantined_and_reported_by_name(tmp_path: Path, client_for):
    session = SessionStore(tmp_path).create("rig", board=BOARD)
    session.add_sensor(Frame("cam", "base_link", kind="camera"))
    good = [session.add_result("cam", intrinsics_record(500.0 + i), inputs=[]) for i in range(3)]
    broken_id = good.pop(1)
    broken = session.path / "results" / f"{broken_id}.json"
    (session.path / "results" / broken_id).mkdir()
    (session.path / "results" / broken_id / "overlay.png").write_bytes(b"image bytes")
    data = broken.read_bytes()[:-25]  # truncated
    broken.write_bytes(data)

    client = client_for(tmp_path)
    base = "/api/sessions/rig"
    error = assert_error(client.post(f"{base}/sensors/cam/intrinsics/accept", json={"result_id": broken_id}), 422,
                         names=f"{broken_id}.json")
    assert "not valid JSON" in error["message"] and error["input"] == f"rig/results/{broken_id}.json"
    assert str(tmp_path) not in error["message"]

    # quarantined with its files and a note, never deleted
    quarantined = session.path / "quarantine" / "results"
    assert not broken.exists() and (quarantined / f"{broken_id}.json").read_bytes() == data
    assert (quarantined / broken_id / "overlay.png").read_bytes() == b"image bytes"
    note = json.loads((quarantined / f"{broken_id}.why.json").read_text())
    assert note["file"] == f"results/{broken_id}.json" and "not valid JSON" in note["reason"]
    assert sorted(note["moved"]) == [f"results/{broken_id}", f"results/{broken_id}.json"]

    # the listing shows the good ones and reports the broken one in the session's listing
    response = client.get(f"{base}/results")
    assert response.status_code == 200, response.text
    assert [r["id"] for r in response.json()] == good
    [entry] = [e for e in client.get("/api/sessions").json() if e["name"] == "rig"]
    assert [q["file"] for q in entry["quarantined"]] == [f"results/{broken_id}.json"]
    assert "not valid JSON" in entry["quarantined"][0]["reason"]

    # asked for again it is still reported by name (not a 404), and its id is never reused
    assert_error(client.get(f"{base}/results/{broken_id}"), 422, names=f"{broken_id}.json")
    assert client.get(f"{base}/results/{good[0]}").json()["id"] == good[0]
    assert client.post(f"{base}/sensors/cam/intrinsics/accept", json={"result_id": good[1]}).status_code == 200
    assert session.add_result("cam", intrinsics_record(), inputs=[]) not in (*good, broken_id)


def test_result_of_another_id_or_not_an_object_is_quarantined(tmp_path: Path):
    session = SessionStore(tmp_path).create("rig")
    first = session.add_result("cam", intrinsics_record(), inputs=[])
    second = session.add_result("cam", intrinsics_record(), inputs=[])
    (session.path / "results" / f"{second}.json").write_text(json.dumps({**session.result(first), "id": first}))
    third = session.add_result("cam", intrinsics_record(), inputs=[])
    (session.path / "results" / f"{third}.json").write_text("[1, 2, 3]")
    assert [r["id"] for r in session.results()] == [first]
    assert [q["file"] for q in session.quarantined()] == [f"results/{second}.json", f"results/{third}.json"]
    with pytest.raises(InputError) as err:
        session.result(third)
    assert err.value.status_code == 422 and "not a result record" in err.value.message


def test_quarantine_never_overwrites_an_earlier_copy(tmp_path: Path):
    session = SessionStore(tmp_path).create("rig")
    result_id = session.add_result("cam", intrinsics_record(), inputs=[])
    path = session.path / "results" / f"{result_id}.json"
    path.write_text("first broken copy")
    assert session.results() == []
    path.write_text("second broken copy")  # put back by hand, still broken
    assert session.results() == []
    quarantined = session.path / "quarantine" / "results"
    assert (quarantined / f"{result_id}.json").read_text() == "first broken copy"
    assert (quarantined / f"{result_id}.json.1").read_text() == "second broken copy"
    assert session.quarantined()[-1]["to"] == [f"quarantine/results/{result_id}.json.1"]


def lidar_session(root: Path) -> Session:
    """Session ``car``: LiDARs ``front`` and ``top``, two clouds each."""
    session = SessionStore(root).create("car")
    rng = np.random.default_rng(1)
    for name in ("front", "top"):
        session.add_sensor(Frame(name, "base_link", kind="lidar3d"))
        for i in range(2):
            session.add_cloud_capture(name, rng.uniform(-5, 5, (500, 3)), None,
                                      {"timestamp_s": float(i), "device": "test"})
    return session


def test_truncated_cloud_is_quarantined_and_reported_by_name(tmp_path: Path, client_for):
    session = lidar_session(tmp_path)
    folder = session.path / "captures" / "front"
    cloud = folder / "00001.npy"
    data = cloud.read_bytes()[: len(cloud.read_bytes()) // 2]
    cloud.write_bytes(data)

    client = client_for(tmp_path)
    error = assert_error(client.post("/api/sessions/car/lidar-lidar/solve", json={"source": "front", "target": "top"}),
                         422, names="00001.npy")
    assert error["input"] == "car/captures/front/00001.npy" and "truncated" in error["message"]
    assert "car/quarantine/captures/front/00001.npy" in error["message"]
    quarantined = session.path / "quarantine" / "captures" / "front"
    assert (quarantined / "00001.npy").read_bytes() == data and (quarantined / "00001.json").is_file()
    assert not cloud.exists() and not (folder / "00001.json").exists()
    assert json.loads((quarantined / "00001.why.json").read_text())["file"] == "captures/front/00001.npy"

    listing = client.get("/api/sessions/car/sensors/front/captures")
    assert listing.status_code == 200, listing.text
    assert [c["id"] for c in listing.json()] == ["00002"]
    # paired by time stamp (1 s each), not shifted by the quarantined capture's number
    assert client.get("/api/sessions/car/lidar-lidar/pairs", params={"source": "front", "target": "top"}).json() == [
        ["00002", "00002"]]
    with pytest.raises(InputError) as err:  # asked for again: still named, and the id is not given out again
        session.capture_cloud("front", "00001")
    assert err.value.status_code == 422 and "00001.npy" in err.value.message
    added = session.add_cloud_capture("front", np.zeros((10, 3)), None, {"timestamp_s": 3.0, "device": "test"})
    assert added.id not in ("00001", "00002")


def test_a_truncated_imu_capture_is_quarantined_and_named(tmp_path: Path):
    rig = Rig()
    rig.add(Frame("imu", "base_link", kind="imu"))
    session = SessionStore(tmp_path).create("rig", rig=rig)
    t_s = np.arange(0.0, 2.0, 0.005)
    imu = ImuSamples(t_s, np.column_stack([np.sin(t_s)] * 3), np.tile([0.0, 0.0, 9.81], (len(t_s), 1)))
    kept, broken = (session.add_imu_capture("imu", imu, {"timestamp_s": float(k), "device": "test"}) for k in (0, 2))
    read = session.imu_capture("imu", kept.id)
    assert kept.n_imu_samples == len(t_s) and np.array_equal(read.t_s, t_s) and np.array_equal(read.gyro_rad_s,
                                                                                               imu.gyro_rad_s)
    table = session.path / "captures" / "imu" / f"{broken.id}.imu.npy"
    table.write_bytes(table.read_bytes()[:100])
    with pytest.raises(InputError, match=f"{broken.id}.imu.npy.*N x 7 IMU table"):
        session.imu_capture("imu", broken.id)
    quarantined = session.path / "quarantine" / "captures" / "imu"
    assert (quarantined / f"{broken.id}.imu.npy").is_file() and (quarantined / f"{broken.id}.json").is_file()
    assert [c.id for c in session.captures("imu")] == [kept.id]


def test_corrupt_capture_metadata_and_image_are_quarantined(tmp_path: Path):
    session = SessionStore(tmp_path).create("rig")
    session.add_sensor(Frame("cam", "base_link", kind="camera"))
    ids = [session.add_capture("cam", np.full((24, 32, 3), v, np.uint8), {"timestamp_s": 0.0, "device": "t"}).id
           for v in (10, 20, 30)]
    folder = session.path / "captures" / "cam"
    (folder / f"{ids[0]}.json").write_text('{"id": "00001", "sensor": "cam", "timestamp_s": ')
    (folder / f"{ids[1]}.png").write_bytes((folder / f"{ids[1]}.png").read_bytes()[:60])

    assert [c.id for c in session.captures("cam")] == ids[1:]
    with pytest.raises(InputError) as err:
        session.capture_image("cam", ids[1])
    assert err.value.status_code == 422 and f"{ids[1]}.png" in err.value.message
    assert [c.id for c in session.captures("cam")] == ids[2:]
    quarantined = session.path / "quarantine" / "captures" / "cam"
    assert sorted(p.name for p in quarantined.iterdir()) == sorted(
        [f"{i}{suffix}" for i in ids[:2] for suffix in (".json", ".png", ".why.json")])
    assert [q["file"] for q in session.quarantined()] == [f"captures/cam/{ids[0]}.json", f"captures/cam/{ids[1]}.png"]


# -- finite numbers at the API, in the rig and in the exports --------------------------------


@pytest.mark.parametrize(("body", "field"), [
    ('{"name": "cam", "pose": {"xyz_m": [NaN, 0, 0]}}', "pose.xyz_m.0"),
    ('{"name": "cam", "pose": {"ypr_deg": [0, Infinity, 0]}}', "pose.ypr_deg.1"),
    ('{"name": "cam", "pose": {"xyz_m": [0, 0, -Infinity]}}', "pose.xyz_m.2"),
    ('{"name": "cam", "pose": {"xyz_m": [0, "nan", 0]}}', "pose.xyz_m.1"),
    ('{"name": "cam", "xyz_m": [NaN, 0, 0]}', "pose.xyz_m.0"),  # the deprecated spelling, folded into pose
    ('{"name": "cam", "device": {"driver": "sim", "noise": {"px": NaN}}}', "device"),
])
def test_non_finite_mountings_are_refused(tmp_path: Path, client_for, body: str, field: str):
    SessionStore(tmp_path).create("rig")
    client = client_for(tmp_path)
    response = client.post("/api/sessions/rig/sensors", content=body, headers={"Content-Type": "application/json"})
    error = assert_error(response, 422, names=field)
    assert error["input"] == field and "finite" in error["message"], error
    assert client.get("/api/sessions/rig").json()["sensors"] == []
    assert "NaN" not in (tmp_path / "rig" / SESSION_FILE).read_text()


def test_other_request_models_refuse_non_finite_numbers(tmp_path: Path, client_for):
    lidar_session(tmp_path)
    client = client_for(tmp_path)
    body = '{"source": "front", "target": "top", "init": {"xyz_m": [0, 0, NaN], "ypr_deg": [0, 0, 0]}}'
    response = client.post("/api/sessions/car/lidar-lidar/solve", content=body,
                           headers={"Content-Type": "application/json"})
    assert_error(response, 422, names="init.xyz_m.2")


def test_rig_refuses_non_finite_transforms():
    T = np.eye(4)
    T[1, 3] = np.nan
    with pytest.raises(InputError) as err:
        Frame("cam", "base_link", T)
    assert "T_parent_child[1][3] is nan" in err.value.message and err.value.input == "cam"
    with pytest.raises(InputError):
        Frame("cam", "base_link", covariance=np.diag([np.inf] + [1.0] * 5))
    rig = Rig()
    rig.add(Frame("cam", "base_link", np.eye(4)))
    with pytest.raises(InputError):
        rig.set_relative("cam", "base_link", T)
    np.testing.assert_array_equal(rig.get("cam").T_parent_child, np.eye(4))


def test_exports_refuse_to_write_non_finite_numbers():
    rig = Rig()
    frame = rig.add(Frame("lidar", "base_link", np.eye(4)))
    frame.covariance = np.diag([np.nan] * 6)  # set behind the frame's back
    with pytest.raises(InputError) as err:
        dump_rig_transforms(rig)
    assert "'lidar'" in err.value.message and "sigma" in err.value.message
    frame.covariance, frame.T_parent_child = None, np.diag([1.0, 1.0, 1.0, np.nan])
    with pytest.raises(InputError) as err:
        dump_rig_transforms(rig)
    assert "'lidar'" in err.value.message and "T_parent_child[3][3]" in err.value.message
    T = np.eye(4)
    T[0, 3] = np.inf
    with pytest.raises(InputError):
        static_transform_publisher("base_link", "lidar", T)

    camera = CameraIntrinsics("pinhole-radtan", 640, 480, np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]),
                              np.array([0.1, np.nan, 0, 0, 0]))
    with pytest.raises(InputError) as err:
        dump_camera_info(camera, "cam")
    assert "dist[1] is nan" in err.value.message
    with pytest.raises(InputError) as err:
        dump_opencv_yaml(camera)
    assert "distortion_coefficients[1]" in err.value.message


def test_imports_refuse_non_finite_numbers(tmp_path: Path):
    rig = Rig()
    rig.add(Frame("lidar", "base_link", np.eye(4)))
    text = dump_rig_transforms(rig).replace("z: 0.0", "z: .nan", 1)
    with pytest.raises(InputError) as err:
        load_rig_transforms(text)
    assert "frames[0].translation_m.z" in err.value.message and "finite" in err.value.message

    camera = CameraIntrinsics("pinhole-radtan", 640, 480, np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]),
                              np.zeros(5))
    info = tmp_path / "camera.yaml"
    info.write_text(dump_camera_info(camera, "cam").replace("[500.0,", "[.inf,", 1))
    with pytest.raises(InputError) as err:
        load_camera_info(info)
    assert "camera_matrix.data[0]" in err.value.message
    opencv = tmp_path / "opencv.yaml"
    opencv.write_text(dump_opencv_yaml(camera).replace("[ 500.,", "[ .Nan,", 1))
    with pytest.raises(InputError) as err:
        read_opencv_yaml(opencv)
    assert "camera_matrix" in err.value.message and "non-finite" in err.value.message


# -- temp files of killed writes ------------------------------------------------------------

KILLED_WRITE = """
import os, signal, sys
from pathlib import Path
from backend.store import atomic
atomic.os.fsync = lambda fd: os.kill(os.getpid(), signal.SIGKILL)  # die after writing, before the rename
atomic.write_bytes_atomic(Path(sys.argv[1]), b"half of a capture")
"""


def test_temp_files_of_killed_writes_are_cleaned_at_start(tmp_path: Path):
    session = SessionStore(tmp_path).create("rig")
    session.add_sensor(Frame("cam", "base_link", kind="camera"))
    target = session.path / "captures" / "cam" / "00001.png"
    killed = subprocess.run([sys.executable, "-c", KILLED_WRITE, str(target)], cwd=ROOT, capture_output=True)
    assert killed.returncode == -9, killed.stderr
    [left] = list(target.parent.iterdir())
    assert not target.exists() and TEMP_NAME.fullmatch(left.name), left.name

    old = time.time() - 3600
    stale_session_file = session.path / ".session.json.k2j_x9q0.tmp"
    fresh = session.path / ".session.json.abcdefgh.tmp"  # a write that may still be running
    keep = [session.path / name for name in (".notes.tmp", "draft.tmp", "x.abcdefgh.tmp", ".x.abcdefghi.tmp")]
    for path in (stale_session_file, fresh, *keep):
        path.write_bytes(b"x")
    for path in (left, stale_session_file, *keep):
        os.utime(path, (old, old))

    SessionStore(tmp_path)
    assert not left.exists() and not stale_session_file.exists()
    assert fresh.exists() and all(path.exists() for path in keep)
    assert SessionStore(tmp_path).get("rig").captures("cam") == []


def test_upload_folders_of_killed_requests_are_cleaned_at_start(tmp_path: Path):
    session = SessionStore(tmp_path).create("rig")
    stale, fresh = session.path / f"{UPLOAD_FOLDER_PREFIX}a1b2c3", session.path / f"{UPLOAD_FOLDER_PREFIX}d4e5f6"
    for folder in (stale, fresh):
        folder.mkdir()
        (folder / "scan.pcd").write_bytes(b"x" * 100)
    os.utime(stale, (time.time() - 3600,) * 2)
    SessionStore(tmp_path)
    assert not stale.exists() and (fresh / "scan.pcd").exists()  # a request still being read keeps its folder


# -- the studio's session step --------------------------------------------------------------


@pytest.mark.slow
def test_studio_lists_a_broken_session_with_its_reason(studio, browser):
    sessions = Path(studio.process.args[studio.process.args.index("--sessions") + 1])
    (sessions / "wrecked").mkdir()
    (sessions / "wrecked" / SESSION_FILE).write_text('{"schema_version": 1, "name": "wrecked", "rig": ')
    with studio_page(browser, studio.url, {"width": 1400, "height": 1000}) as page:
        open_button = button(page, "Open session")
        if not open_button.is_visible():
            unfold(page, "1 · Session", open_button)
        open_button.click()  # reopening the demo refreshes the step's list of sessions
        match = wait_body(page, re.compile(r"Broken sessions.*\n+.*wrecked.*not valid JSON"))
        assert "session.json" in match.group(0)
        page.screenshot(path=str(ROOT / "tests" / "artifacts" / "store_isolation_broken_session.png"))
    assert "wrecked" in {e["name"] for e in studio.get("/api/sessions") if e["broken"]}
