"""The REST API end to end on real chessboard images: sessions, uploads, solves, jobs, exports, auth."""

from __future__ import annotations

import itertools
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from fastapi.testclient import TestClient

from backend.api.app import create_app
from tests.conftest import wait_job

BOARD = "checkerboard:9x6:0.025"
_names = itertools.count(1)


def upload(client: TestClient, session: str, sensor: str, files: list[tuple[str, bytes]], **params):
    parts = [("files", (name, data, "application/octet-stream")) for name, data in files]
    return client.post(f"/api/sessions/{session}/sensors/{sensor}/captures", files=parts, params=params)


def captures(client: TestClient, session: str, sensor: str) -> list[dict]:
    response = client.get(f"/api/sessions/{session}/sensors/{sensor}/captures")
    assert response.status_code == 200, response.text
    return response.json()


def assert_error(response, status: int, *, names: str) -> dict:
    """A 4xx with the documented body ``{"error": {"message", "input"}}`` naming ``names``."""
    assert response.status_code == status, response.text
    body = response.json()
    assert set(body) == {"error"} and set(body["error"]) == {"message", "input"}
    assert names in body["error"]["message"] or names == body["error"]["input"], body
    return body["error"]


def png(image: np.ndarray) -> bytes:
    ok, buffer = cv2.imencode(".png", image)
    assert ok
    return buffer.tobytes()


@pytest.fixture(scope="module")
def images(left_images) -> dict[str, bytes]:
    assert len(left_images) == 13
    return {p.name: p.read_bytes() for p in left_images}


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("api_sessions")


@pytest.fixture(scope="module")
def client(root: Path):
    app = create_app(root)
    with TestClient(app) as c:
        yield c
    app.state.studio.jobs.shutdown()


@pytest.fixture
def fresh(client: TestClient) -> str:
    """A new session with a board and one camera ``cam``."""
    name = f"s{next(_names):03d}"
    assert client.post("/api/sessions", json={"name": name, "board": BOARD}).status_code == 201
    response = client.post(f"/api/sessions/{name}/sensors", json={"name": "cam"})
    assert response.status_code == 201, response.text
    return name


@pytest.fixture(scope="module")
def solved(client: TestClient, images: dict[str, bytes]) -> dict:
    """Session ``bench``: camera ``cam`` with all 13 left images, solved (not accepted)."""
    response = client.post("/api/sessions", json={"name": "bench", "board": BOARD, "title": "stereo left"})
    assert response.status_code == 201, response.text
    response = client.post("/api/sessions/bench/sensors", json={"name": "cam", "pose": {"xyz_m": [0.1, 0, 0.2]}})
    assert response.status_code == 201, response.text
    assert "cam" in response.json()["sensors"]
    response = upload(client, "bench", "cam", list(images.items()))
    assert response.status_code == 201, response.text
    added = response.json()["added"]
    assert len(added) == 13 and response.json()["skipped"] == []
    assert sorted(c["source"] for c in added) == sorted(images)
    response = client.post("/api/sessions/bench/sensors/cam/intrinsics/solve", json={})
    assert response.status_code == 202, response.text
    job = response.json()
    assert job["state"] in ("running", "done") and job["result_id"] is None
    status = wait_job(client, job["id"])
    assert status["state"] == "done", status
    assert status["result_id"]
    return {"session": "bench", "result_id": status["result_id"]}


# -- meta -----------------------------------------------------------------------------------


def test_health_and_docs(client: TestClient):
    response = client.get("/api/health")
    assert response.status_code == 200 and response.json() == {"status": "ok"}
    docs = client.get("/docs")
    assert docs.status_code == 200 and "swagger" in docs.text.lower()
    assert "/api/sessions" in client.get("/openapi.json").json()["paths"]


# -- sessions -------------------------------------------------------------------------------


def test_create_session_and_duplicate(client: TestClient, root: Path):
    response = client.post("/api/sessions", json={"name": "dup-1", "board": BOARD})
    assert response.status_code == 201
    assert response.json()["name"] == "dup-1" and response.json()["board"] == BOARD
    assert (root / "dup-1" / "session.json").is_file()
    error = assert_error(client.post("/api/sessions", json={"name": "dup-1"}), 409, names="dup-1")
    assert error["input"] == "name"
    assert client.get("/api/sessions/dup-1").json()["board"] == BOARD


def test_bad_board_spec(client: TestClient, root: Path):
    error = assert_error(client.post("/api/sessions", json={"name": "badboard", "board": "checkerboard:9by6"}),
                         422, names="board")
    assert error["input"] == "board" and "checkerboard:9by6" in error["message"]
    assert not (root / "badboard").exists()


def test_bad_session_name(client: TestClient, root: Path):
    error = assert_error(client.post("/api/sessions", json={"name": "../escape"}), 422, names="name")
    assert error["input"] == "name"
    assert not (root.parent / "escape").exists()


def test_unknown_session_and_sensor(client: TestClient, fresh: str):
    error = assert_error(client.get("/api/sessions/no-such-session"), 404, names="no-such-session")
    assert "no-such-session" in error["message"]
    assert_error(client.get("/api/sessions/no-such-session/sensors/cam/captures"), 404, names="no-such-session")
    error = assert_error(client.get(f"/api/sessions/{fresh}/sensors/ghost/captures"), 404, names="ghost")
    assert "ghost" in error["message"]


def test_add_sensor(client: TestClient, fresh: str):
    response = client.post(f"/api/sessions/{fresh}/sensors", json={"name": "cam_side", "pose": {
        "xyz_m": [0, 0.5, 1.0], "ypr_deg": [90, 0, 0]}})
    assert response.status_code == 201 and "cam_side" in response.json()["sensors"]
    rig = client.get(f"/api/sessions/{fresh}/rig").json()
    frame = next(f for f in rig["frames"] if f["name"] == "cam_side")
    T = np.array(frame["T_parent_child"])
    np.testing.assert_allclose(T[:3, 3], [0, 0.5, 1.0])
    np.testing.assert_allclose(T[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)  # yaw 90 deg
    assert_error(client.post(f"/api/sessions/{fresh}/sensors", json={"name": "cam_side"}), 409, names="cam_side")


# -- uploads --------------------------------------------------------------------------------


def test_truncated_jpeg_rejects_whole_batch(client: TestClient, fresh: str, root: Path, images):
    assert upload(client, fresh, "cam", [("left01.jpg", images["left01.jpg"])]).status_code == 201
    whole = images["left05.jpg"]
    batch = [("left02.jpg", images["left02.jpg"]), ("cut.jpg", whole[: int(len(whole) * 0.6)]),
             ("left03.jpg", images["left03.jpg"])]
    error = assert_error(upload(client, fresh, "cam", batch), 422, names="cut.jpg")
    assert "cut.jpg" in error["message"]
    assert len(captures(client, fresh, "cam")) == 1
    assert len(list((root / fresh / "captures" / "cam").glob("*.png"))) == 1


def test_text_file_named_png(client: TestClient, fresh: str, images):
    batch = [("left01.jpg", images["left01.jpg"]), ("notes.png", b"just some notes, not an image\n")]
    error = assert_error(upload(client, fresh, "cam", batch), 422, names="notes.png")
    assert "notes.png" in error["message"]
    assert captures(client, fresh, "cam") == []


@pytest.mark.slow
def test_image_without_board(client: TestClient, fresh: str, images):
    blank = png(np.zeros((480, 640, 3), np.uint8))
    batch = [("left01.jpg", images["left01.jpg"]), ("blank.png", blank)]
    error = assert_error(upload(client, fresh, "cam", batch), 422, names="blank.png")
    assert "blank.png" in error["message"] and "board" in error["message"]
    assert captures(client, fresh, "cam") == []

    response = upload(client, fresh, "cam", batch, skip_unusable="true")
    assert response.status_code == 201, response.text
    body = response.json()
    assert [c["source"] for c in body["added"]] == ["left01.jpg"]
    assert [s["input"] for s in body["skipped"]] == ["blank.png"]
    assert "board" in body["skipped"][0]["message"]
    stored = captures(client, fresh, "cam")
    assert [c["source"] for c in stored] == ["left01.jpg"] and stored[0]["board_found"] is True


def test_upload_path_traversal_stays_in_session(client: TestClient, fresh: str, root: Path, images):
    outside_before = {p for p in root.parent.rglob("*") if root / fresh not in p.parents}
    response = upload(client, fresh, "cam", [("../../evil.png", images["left01.jpg"])])
    assert response.status_code == 201, response.text
    added = response.json()["added"]
    assert len(added) == 1 and added[0]["source"] == "evil.png"
    assert [c["source"] for c in captures(client, fresh, "cam")] == ["evil.png"]
    outside_after = {p for p in root.parent.rglob("*") if root / fresh not in p.parents}
    assert outside_after == outside_before
    assert not list(root.parent.rglob("evil*"))
    assert not (root.parent.parent / "evil.png").exists() and not Path("evil.png").exists()
    stored = list((root / fresh / "captures" / "cam").glob("*.png"))
    assert [p.name for p in stored] == [f"{added[0]['id']}.png"]
    # the stored image is the uploaded one, served back as JPEG
    image = client.get(f"/api/sessions/{fresh}/sensors/cam/captures/{added[0]['id']}/image")
    assert image.status_code == 200 and image.headers["content-type"] == "image/jpeg"
    assert cv2.imdecode(np.frombuffer(image.content, np.uint8), cv2.IMREAD_COLOR).shape == (480, 640, 3)


def test_image_of_another_size(client: TestClient, fresh: str, images):
    assert upload(client, fresh, "cam", [("left01.jpg", images["left01.jpg"])]).status_code == 201
    full = cv2.imdecode(np.frombuffer(images["left02.jpg"], np.uint8), cv2.IMREAD_COLOR)
    small = png(cv2.resize(full, (320, 240), interpolation=cv2.INTER_AREA))
    error = assert_error(upload(client, fresh, "cam", [("small.png", small)]), 422, names="small.png")
    assert "small.png" in error["message"] and "320x240" in error["message"] and "640x480" in error["message"]
    assert len(captures(client, fresh, "cam")) == 1


def test_mixed_sizes_in_first_upload_store_nothing(client: TestClient, fresh: str, root: Path, images):
    """The size check also holds within one batch, so a camera's first upload is all-or-nothing."""
    full = cv2.imdecode(np.frombuffer(images["left02.jpg"], np.uint8), cv2.IMREAD_COLOR)
    small = png(cv2.resize(full, (320, 240), interpolation=cv2.INTER_AREA))
    batch = [("left01.jpg", images["left01.jpg"]), ("small.png", small)]
    error = assert_error(upload(client, fresh, "cam", batch), 422, names="small.png")
    assert "small.png" in error["message"] and "320x240" in error["message"]
    assert captures(client, fresh, "cam") == []
    assert not list((root / fresh).glob("captures/cam/*.png"))


# -- solve, accept, export ------------------------------------------------------------------


@pytest.mark.slow
def test_solve_result(client: TestClient, solved: dict, root: Path):
    session, rid = solved["session"], solved["result_id"]
    result = client.get(f"/api/sessions/{session}/results/{rid}")
    assert result.status_code == 200
    record = result.json()
    assert record["id"] == rid and record["sensor"] == "cam" and record["kind"] == "intrinsics"
    assert record["rms_px"] < 0.5
    assert len(record["views"]) == 13 and all(v["used"] for v in record["views"])
    assert record["camera"]["width"] == 640 and record["camera"]["height"] == 480
    assert 500 < record["camera"]["K"][0][0] < 570
    assert (root / session / "results" / f"{rid}.json").is_file()
    listed = client.get(f"/api/sessions/{session}/results", params={"sensor": "cam"}).json()
    assert rid in [r["id"] for r in listed]
    assert_error(client.get(f"/api/sessions/{session}/results/r9999"), 404, names="r9999")


@pytest.mark.slow
def test_accept_and_export(client: TestClient, solved: dict, tmp_path: Path):
    session, rid = solved["session"], solved["result_id"]
    record = client.get(f"/api/sessions/{session}/results/{rid}").json()
    K = record["camera"]["K"]

    verdict = record["verdict"]
    assert verdict["level"] in ("trusted", "check") and verdict["reasons"], verdict
    if verdict["level"] == "check":  # a 'check' wants the confirmation, and the log keeps it
        response = client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/accept", json={"result_id": rid})
        assert response.status_code == 409 and response.json()["error"]["input"] == "confirm", response.text
    response = client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/accept",
                           json={"result_id": rid, "confirm": True})
    assert response.status_code == 200, response.text
    assert response.json()["accepted"] == {"cam/intrinsics": rid}
    (entry,) = response.json()["acceptance_log"]
    assert (entry["result_id"], entry["verdict"], entry["confirmed"]) == (rid, verdict["level"],
                                                                          verdict["level"] == "check")
    assert client.get(f"/api/sessions/{session}").json()["accepted"] == {"cam/intrinsics": rid}

    info = client.get(f"/api/sessions/{session}/export/camera_info", params={"sensor": "cam"})
    assert info.status_code == 200, info.text
    assert 'filename="cam.yaml"' in info.headers["content-disposition"]
    doc = yaml.safe_load(info.text)
    assert doc["image_width"] == 640 and doc["image_height"] == 480
    assert doc["distortion_model"] == "plumb_bob"
    assert doc["camera_matrix"]["rows"] == 3 and doc["camera_matrix"]["cols"] == 3
    np.testing.assert_allclose(doc["camera_matrix"]["data"], np.ravel(K), rtol=1e-12)
    np.testing.assert_allclose(doc["distortion_coefficients"]["data"], record["camera"]["dist"], rtol=1e-12)

    opencv = client.get(f"/api/sessions/{session}/export/opencv", params={"sensor": "cam"})
    assert opencv.status_code == 200, opencv.text
    path = tmp_path / "cam_opencv.yaml"
    path.write_text(opencv.text)
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    assert storage.isOpened()
    np.testing.assert_allclose(storage.getNode("camera_matrix").mat(), K, rtol=1e-12)
    assert storage.getNode("image_width").real() == 640
    assert storage.getNode("avg_reprojection_error").real() == pytest.approx(record["rms_px"])
    storage.release()

    rig = client.get(f"/api/sessions/{session}/export/rig")
    assert rig.status_code == 200, rig.text
    frames = {f["child"]: f for f in yaml.safe_load(rig.text)["frames"]}
    assert frames["cam"]["parent"] == "base_link"
    assert frames["cam"]["translation_m"] == pytest.approx({"x": 0.1, "y": 0.0, "z": 0.2})

    bad = client.get(f"/api/sessions/{session}/export/nonsense", params={"sensor": "cam"})
    assert_error(bad, 422, names="fmt")


@pytest.mark.slow
def test_export_before_accept_is_409(client: TestClient, solved: dict):
    session = solved["session"]
    assert client.post(f"/api/sessions/{session}/sensors", json={"name": "cam_unsolved"}).status_code == 201
    error = assert_error(client.get(f"/api/sessions/{session}/export/camera_info", params={"sensor": "cam_unsolved"}),
                         409, names="cam_unsolved")
    assert "accept" in error["message"]
    assert_error(client.get(f"/api/sessions/{session}/export/opencv", params={"sensor": "cam_unsolved"}),
                 409, names="cam_unsolved")


def test_solve_with_too_few_captures_fails(client: TestClient, fresh: str, root: Path, images):
    batch = [("left01.jpg", images["left01.jpg"]), ("left02.jpg", images["left02.jpg"])]
    assert upload(client, fresh, "cam", batch).status_code == 201
    response = client.post(f"/api/sessions/{fresh}/sensors/cam/intrinsics/solve", json={})
    assert response.status_code == 202, response.text
    status = wait_job(client, response.json()["id"])
    assert status["state"] == "failed", status
    assert "at least 3" in status["error"]["message"] and "at least 3" in status["message"]
    assert status["result_id"] is None
    assert not list((root / fresh).glob("results/*.json"))


def test_solve_unknown_sensor_is_404(client: TestClient, fresh: str):
    assert_error(client.post(f"/api/sessions/{fresh}/sensors/ghost/intrinsics/solve", json={}), 404, names="ghost")


def test_unknown_job_is_404(client: TestClient):
    assert_error(client.get("/api/jobs/j99999"), 404, names="j99999")


@pytest.mark.slow
def test_cancel_solve(client: TestClient, solved: dict, root: Path):
    session = solved["session"]
    results = root / session / "results"
    before = sorted(p.name for p in results.glob("*.json"))
    response = client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/solve", json={"estimate_k3": True})
    assert response.status_code == 202
    job_id = response.json()["id"]
    cancel = client.post(f"/api/jobs/{job_id}/cancel")
    assert cancel.status_code == 200 and cancel.json()["id"] == job_id
    status = wait_job(client, job_id)
    assert status["state"] in ("cancelled", "done"), status
    after = sorted(p.name for p in results.glob("*.json"))
    if status["state"] == "cancelled":
        assert after == before and status["result_id"] is None
        assert "cancel" in status["message"]
    else:
        assert len(after) == len(before) + 1 and f"{status['result_id']}.json" in after
    assert not list(results.glob(".*.tmp"))


# -- token ----------------------------------------------------------------------------------


def test_token(tmp_path: Path):
    app = create_app(tmp_path, token="s3cret")
    with TestClient(app) as c:
        error = assert_error(c.get("/api/health"), 401, names="token")
        assert error["input"] == "token"
        assert_error(c.get("/api/health", headers={"Authorization": "Bearer wrong"}), 401, names="token")
        assert_error(c.get("/api/sessions"), 401, names="token")
        assert "calib_token" not in c.cookies

        ok = c.get("/api/health", headers={"Authorization": "Bearer s3cret"})
        assert ok.status_code == 200 and ok.json() == {"status": "ok"}
        assert "calib_token" not in ok.headers.get("set-cookie", "")

        first = c.get("/api/health", params={"token": "s3cret"})
        assert first.status_code == 200 and first.json() == {"status": "ok"}
        cookie = first.headers["set-cookie"]
        assert cookie.startswith("calib_token=s3cret") and "httponly" in cookie.lower()
        # the cookie alone now authenticates
        assert c.get("/api/sessions").status_code == 200
    with TestClient(app) as other:
        assert other.get("/api/health", params={"token": "nope"}).status_code == 401
        other.cookies.set("calib_token", "nope")
        assert other.get("/api/health").status_code == 401
    app.state.studio.jobs.shutdown()


def solve_as_job(client: TestClient, session: str, body: dict) -> tuple[str, dict]:
    """Solve camera ``cam``'s intrinsics with ``body`` as a job, waited for until done: the result's id and record."""
    response = client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/solve", json=body)
    assert response.status_code == 202, response.text
    status = wait_job(client, response.json()["id"])
    assert status["state"] == "done", status
    return status["result_id"], client.get(f"/api/sessions/{session}/results/{status['result_id']}").json()


@pytest.mark.slow
def test_a_photogrammetric_solve_through_the_api_and_the_camera_json_export(client: TestClient, solved: dict):
    session = solved["session"]
    rid, record = solve_as_job(client, session, {"model": "photogrammetric", "pixel_size_um": 6.0})
    assert record["camera"]["model"] == "photogrammetric" and len(record["camera"]["dist"]) == 7
    assert record["photogrammetric"]["parameters"]["c"]["unit_mm"] == "mm"
    # judged where the 13 VGA views' boards reach, the lens is pinned (the halves agree); the image's corners, which
    # no board reached and where K3 is loose, are named with their extrapolated sigma, not judged
    assert record["verdict"]["level"] == "trusted", record["verdict"]
    assert any("beyond them the sigma is up to" in r for r in record["verdict"]["reasons"])
    assert record["projection_uncertainty"]["max_uncovered_px"] > 1.0 > 0.3 > record["projection_uncertainty"][
        "max_covered_px"]
    assert record["board_flex"]["status"] == "not solved" and "photogrammetric" in record["board_flex"]["detail"]
    response = client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/accept", json={"result_id": rid})
    assert response.status_code == 200, response.text
    # the camera JSON carries the accepted camera with its sigmas and correlations
    accepted = client.get(f"/api/sessions/{session}").json()["accepted"]["cam/intrinsics"]
    assert accepted == rid
    exported = client.get(f"/api/sessions/{session}/export/camera-json", params={"sensor": "cam"})
    assert exported.status_code == 200 and exported.headers["content-type"].startswith("application/json")
    assert 'filename="cam.json"' in exported.headers["content-disposition"]
    document, kept = exported.json(), client.get(f"/api/sessions/{session}/results/{accepted}").json()
    assert document["model"] == kept["camera"]["model"] and document["dist"] == kept["camera"]["dist"]
    assert document["std"] == kept["std"] and document["correlation"] == kept["correlation"]
    assert document["model"] == "photogrammetric" and document["photogrammetric"] == kept["photogrammetric"]
    assert document["board_flex"] == kept["board_flex"] and document["board_flex"]["status"] == "not solved"
    response = client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/solve",
                           json={"model": "photogrammetric", "pixel_size_um": -1})
    assert response.status_code == 422 and "pixel_size_um" in response.text


@pytest.mark.slow
def test_the_board_can_be_held_flat_through_the_api(client: TestClient, solved: dict):
    """``board_flex: false`` holds the board flat (OpenCV's own problem): the record says so, and the default
    solve's flex, solved from the same views, fits them better."""
    session = solved["session"]
    response = client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/solve",
                           json={"board_flex": False, "reject_corners": False})
    assert response.status_code == 202, response.text
    status = wait_job(client, response.json()["id"])
    assert status["state"] == "done", status
    flat = client.get(f"/api/sessions/{session}/results/{status['result_id']}").json()
    bowed = client.get(f"/api/sessions/{session}/results/{solved['result_id']}").json()
    assert flat["board_flex"]["status"] == "not solved" and flat["board_flex"]["detail"] == "switched off"
    assert flat["settings"]["board_flex"] is False and flat["settings"]["reject_corners"] is False
    assert bowed["board_flex"]["status"] == "solved" and flat["rms_px"] > bowed["rms_px"]
    assert_error(client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/solve", json={"board_flex": "bowed"}),
                 422, names="board_flex")


@pytest.mark.slow
def test_a_splined_solve_through_the_api_and_what_each_export_does_with_it(client: TestClient, solved: dict):
    """The splined model through the API with the knots chosen from the views: the record names mrcal's model; once
    accepted, camera_info refuses it naming the model and the camera JSON carries it, its knots and the fitted
    OpenCV model. Knots out of range are a 422 naming the field."""
    session = solved["session"]
    rid, record = solve_as_job(client, session, {"model": "splined-stereographic", "spline_fov_x_deg": 80})
    assert record["camera"]["model"] == "splined-stereographic"
    nx, ny = record["settings"]["spline_knots"]
    assert record["splined"]["knots"] == [nx, ny] and record["splined"]["measurements_per_value"] >= 5
    assert record["splined"]["lensmodel"].endswith(f"Nx={nx}_Ny={ny}_fov_x_deg=80")
    assert client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/accept",
                       json={"result_id": rid, "confirm": True}).status_code == 200
    refused = assert_error(client.get(f"/api/sessions/{session}/export/camera_info", params={"sensor": "cam"}), 422,
                           names="splined-stereographic")
    assert "OpenCV model fitted to the spline" in refused["message"]
    document = client.get(f"/api/sessions/{session}/export/camera-json", params={"sensor": "cam"}).json()
    assert document["spline"] == record["camera"]["spline"] and document["splined"] == record["splined"]
    assert client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/accept",
                       json={"result_id": solved["result_id"], "confirm": True}).status_code == 200
    response = client.post(f"/api/sessions/{session}/sensors/cam/intrinsics/solve",
                           json={"model": "splined-stereographic", "spline_knots": [3, 10]})
    assert response.status_code == 422 and "spline_knots" in response.text
