"""Limits on what users send, and a server that keeps answering while it works on an upload.

A decompression-bomb PNG is refused from its header (413 naming the file, its size and the limit); uploads
over the request limit are 413 whether they declare their length or not; clouds over the point limit are
422 before their points are read; a NUL byte in a file name is a 422 naming the field; a batch with one
refused file stores nothing; ``/api/health`` answers while an upload is being processed.
"""

from __future__ import annotations

import io
import struct
import threading
import zlib
from collections.abc import Iterator
from pathlib import Path

import cv2
import laspy
import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.calib.intrinsics import service as intrinsics_service
from backend.calib.lidar_camera import capture as pairs_service
from backend.calib.lidar_lidar import service as lidar_service
from backend.core.errors import InputError
from backend.devices.cloud_files import read_cloud
from backend.devices.image_io import decode_image_bytes, image_size

BOARD = "checkerboard:9x6:0.025"


def bomb_png(width: int, height: int) -> bytes:
    """A valid 1-bit gray PNG of zeros: a few hundred KB that decodes to ``width * height`` bytes."""
    row = b"\x00" * (1 + (width + 7) // 8)  # filter byte 0, then the packed pixels
    packer = zlib.compressobj(9)
    idat = b"".join(packer.compress(row) for _ in range(height)) + packer.flush()

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 1, 0, 0, 0, 0)  # bit depth 1, gray
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")


def npy(points: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, points)
    return buffer.getvalue()


def multipart(parts: list[tuple[str, bytes, bytes]]) -> tuple[bytes, dict[str, str]]:
    """A multipart body of (field, raw file name, data) parts, the name sent as given (httpx would escape it)."""
    body = b"".join(b"--XyZ\r\nContent-Disposition: form-data; name=\"" + field.encode() + b"\"; filename=\""
                    + name + b"\"\r\nContent-Type: application/octet-stream\r\n\r\n" + data + b"\r\n"
                    for field, name, data in parts)
    return body + b"--XyZ--\r\n", {"Content-Type": "multipart/form-data; boundary=XyZ"}


def assert_error(response, status: int, *, input: str, says: list[str]) -> str:
    assert response.status_code == status, response.text
    error = response.json()["error"]
    assert error["input"] == input, error
    for text in says:
        assert text in error["message"], error
    return error["message"]


@pytest.fixture(scope="module")
def board_jpg(left_images: list[Path]) -> bytes:
    return left_images[0].read_bytes()


@pytest.fixture
def client(tmp_path: Path) -> Iterator[TestClient]:
    """Session ``s`` with a board, camera ``cam`` and LiDAR ``lid``."""
    app = create_app(tmp_path)
    with TestClient(app) as client:
        assert client.post("/api/sessions", json={"name": "s", "board": BOARD}).status_code == 201
        assert client.post("/api/sessions/s/sensors", json={"name": "cam"}).status_code == 201
        assert client.post("/api/sessions/s/sensors", json={"name": "lid", "kind": "lidar3d"}).status_code == 201
        client.session_dir = tmp_path / "s"
        yield client
    app.state.studio.jobs.shutdown()


def stored(client: TestClient, sensor: str) -> list[dict]:
    response = client.get(f"/api/sessions/s/sensors/{sensor}/captures")
    assert response.status_code == 200, response.text
    return response.json()


def upload_images(client: TestClient, files: list[tuple[str, bytes]], **params):
    return client.post("/api/sessions/s/sensors/cam/captures", params=params,
                       files=[("files", (name, data, "application/octet-stream")) for name, data in files])


def upload_clouds(client: TestClient, files: list[tuple[str, bytes]]):
    return client.post("/api/sessions/s/sensors/lid/clouds",
                       files=[("files", (name, data, "application/octet-stream")) for name, data in files])


def no_upload_left(client: TestClient) -> bool:
    return not list(client.session_dir.glob(".upload-*"))


# --- images: sizes from headers, the pixel limit -----------------------------------------------------------


def test_image_size_is_read_from_the_header_of_every_format():
    image = np.random.default_rng(0).integers(0, 255, (23, 37, 3), np.uint8)
    gray = image[..., 0].copy()
    cases = {".png": (image, []), ".jpg": (image, []), ".bmp": (image, []), ".tif": (image, []),
             ".pgm": (gray, []), ".ppm": (image, []), ".pbm": (gray, []),
             "progressive.jpg": (image, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1]),
             "ascii.pgm": (gray, [cv2.IMWRITE_PXM_BINARY, 0])}
    for label, (picture, params) in cases.items():
        ok, data = cv2.imencode("." + label.rsplit(".", 1)[-1], picture, params)
        assert ok
        assert image_size(data.tobytes()) == (37, 23), label
    assert image_size(b"\x89PNG\r\n\x1a\n\x00\x00") is None  # cut short
    assert image_size(b"RIFF\x00\x00\x00\x00WEBP") is None  # not a format we read


def test_the_bomb_generator_makes_real_pngs():
    small = cv2.imdecode(np.frombuffer(bomb_png(300, 200), np.uint8), cv2.IMREAD_GRAYSCALE)
    assert small.shape == (200, 300) and not small.any()


@pytest.mark.slow
def test_a_decompression_bomb_is_refused_before_decoding(client: TestClient, board_jpg: bytes):
    bomb = bomb_png(16000, 16000)
    assert len(bomb) < 400_000  # the 331 KB bomb: 256 MP once decoded
    response = upload_images(client, [("bomb.png", bomb)])
    assert_error(response, 413, input="bomb.png",
                 says=["bomb.png", "16000x16000 px", "50,000,000 px limit", "CALIB_MAX_IMAGE_PIXELS"])
    # in a batch, nothing of the batch is stored; the good image alone goes in afterwards
    response = upload_images(client, [("left01.jpg", board_jpg), ("bomb.png", bomb)])
    assert_error(response, 413, input="bomb.png", says=["16000x16000 px"])
    assert stored(client, "cam") == []
    assert upload_images(client, [("left01.jpg", board_jpg)]).status_code == 201
    assert [c["source"] for c in stored(client, "cam")] == ["left01.jpg"]


def test_a_jpeg_claiming_a_huge_size_is_refused_by_its_header():
    ok, data = cv2.imencode(".jpg", np.zeros((16, 16, 3), np.uint8))
    data = bytearray(data.tobytes())
    sof = data.index(b"\xff\xc0")
    data[sof + 5:sof + 9] = struct.pack(">HH", 60000, 60000)
    with pytest.raises(InputError) as info:
        decode_image_bytes(bytes(data), "huge.jpg")
    assert info.value.status_code == 413 and "60000x60000 px" in info.value.message


def test_the_pixel_limit_is_configurable(client: TestClient, board_jpg: bytes, monkeypatch):
    monkeypatch.setenv("CALIB_MAX_IMAGE_PIXELS", "300000")  # the 640x480 board image is 307,200 px
    assert_error(upload_images(client, [("left01.jpg", board_jpg)]), 413, input="left01.jpg",
                 says=["640x480 px", "300,000 px limit on an image (CALIB_MAX_IMAGE_PIXELS)"])
    monkeypatch.setenv("CALIB_MAX_IMAGE_PIXELS", "310000")
    assert upload_images(client, [("left01.jpg", board_jpg)]).status_code == 201


def test_a_cv2_error_in_target_detection_is_a_422(client: TestClient, board_jpg: bytes, monkeypatch):
    def fails(image, board, name):
        raise cv2.error("OpenCV(4.x) error: (-215:Assertion failed) !ssize.empty() in function 'resize'")

    monkeypatch.setattr(intrinsics_service, "detect_target", fails)
    assert_error(upload_images(client, [("odd.jpg", board_jpg)]), 422, input="odd.jpg",
                 says=["odd.jpg", "target search failed", "640x480 px"])
    assert stored(client, "cam") == []


# --- request size limits -----------------------------------------------------------------------------------


def test_an_image_upload_over_the_limit_is_a_413(client: TestClient, board_jpg: bytes, monkeypatch):
    monkeypatch.setenv("CALIB_MAX_IMAGE_UPLOAD_MB", "1")
    count = 1_500_000 // len(board_jpg) + 1  # about 1.5 MB of images
    response = upload_images(client, [(f"left{i}.jpg", board_jpg) for i in range(count)])
    assert_error(response, 413, input="files", says=["MB, more than the 1 MB limit on an image upload",
                                                     "CALIB_MAX_IMAGE_UPLOAD_MB"])
    assert stored(client, "cam") == []
    assert upload_images(client, [("left01.jpg", board_jpg)]).status_code == 201


def test_a_body_without_a_length_is_counted_as_it_arrives(client: TestClient, monkeypatch):
    monkeypatch.setenv("CALIB_MAX_CLOUD_UPLOAD_MB", "1")
    body, headers = multipart([("files", b"big.npy", npy(np.zeros((60_000, 3))))])  # 1.4 MB

    def chunks() -> Iterator[bytes]:  # a generator body is sent chunked, with no Content-Length
        for start in range(0, len(body), 64 * 1024):
            yield body[start:start + 64 * 1024]

    response = client.post("/api/sessions/s/sensors/lid/clouds", content=chunks(), headers=headers)
    assert_error(response, 413, input="files", says=["more than the 1 MB limit on a cloud upload",
                                                     "CALIB_MAX_CLOUD_UPLOAD_MB", "refused after"])
    assert stored(client, "lid") == [] and no_upload_left(client)


def test_a_cloud_upload_over_the_limit_is_a_413(client: TestClient, monkeypatch):
    monkeypatch.setenv("CALIB_MAX_CLOUD_UPLOAD_MB", "1")
    response = upload_clouds(client, [("big.npy", npy(np.zeros((60_000, 3))))])
    assert_error(response, 413, input="files", says=["1.4 MB, more than the 1 MB limit on a cloud upload"])
    monkeypatch.setenv("CALIB_MAX_CLOUD_UPLOAD_MB", "2")
    assert upload_clouds(client, [("big.npy", npy(np.ones((60_000, 3))))]).status_code == 201


def test_an_image_file_over_the_image_limit_in_a_pair_is_a_413(client: TestClient, monkeypatch):
    monkeypatch.setenv("CALIB_MAX_IMAGE_UPLOAD_MB", "1")
    noise = np.random.default_rng(1).integers(0, 255, (800, 800, 3), np.uint8)
    image = cv2.imencode(".png", noise)[1].tobytes()  # 1.9 MB, within the 2000 MB of a pair upload
    files = {"image": ("noise.png", image, "image/png"), "cloud": ("c.npy", npy(np.ones((10, 3))), "x/y")}
    response = client.post("/api/sessions/s/lidar-camera/pairs", data={"camera": "cam", "lidar": "lid"}, files=files)
    assert_error(response, 413, input="noise.png", says=["noise.png", "1 MB limit on an image upload"])
    assert stored(client, "lid") == [] and stored(client, "cam") == []


def test_the_upload_limits_are_in_one_place_and_checked(monkeypatch):
    from backend.core.limits import MAX_CLOUD_UPLOAD_MB

    assert MAX_CLOUD_UPLOAD_MB.value() == 2000
    monkeypatch.setenv("CALIB_MAX_CLOUD_UPLOAD_MB", "lots")
    with pytest.raises(ValueError, match="CALIB_MAX_CLOUD_UPLOAD_MB='lots': expected a positive number of MB"):
        MAX_CLOUD_UPLOAD_MB.value()


# --- the point limit ---------------------------------------------------------------------------------------


def test_a_cloud_over_the_point_limit_is_a_422_naming_the_file(client: TestClient, monkeypatch):
    monkeypatch.setenv("CALIB_MAX_CLOUD_POINTS", "1000")
    response = upload_clouds(client, [("dense.npy", npy(np.ones((2000, 3))))])
    assert_error(response, 422, input="dense.npy",
                 says=["dense.npy", "2,000 points", "1,000 points limit on a point cloud (CALIB_MAX_CLOUD_POINTS)"])
    assert stored(client, "lid") == []


def test_declared_point_counts_are_refused_before_the_points_are_read(tmp_path: Path):
    """Headers declaring 10^11 points over no data: the limit speaks first, not a truncation or memory error."""
    files = {
        "claims.npy": b"\x93NUMPY\x01\x00" + _npy_header("{'descr': '<f8', 'fortran_order': False, "
                                                         "'shape': (100000000000, 3), }"),
        "claims.ply": b"ply\nformat binary_little_endian 1.0\nelement vertex 100000000000\n"
                      b"property float x\nproperty float y\nproperty float z\nend_header\n",
        "claims.pcd": b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 100000000000\n"
                      b"HEIGHT 1\nPOINTS 100000000000\nDATA binary_compressed\n\x00\x00\x00\x00",
    }
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(InputError) as info:
            read_cloud(tmp_path / name)
        assert "100,000,000,000 points, more than the 50,000,000 points limit" in info.value.message, name


def test_a_las_file_over_the_point_limit_is_refused(tmp_path: Path, monkeypatch):
    las = laspy.create(point_format=0, file_version="1.2")
    las.x, las.y, las.z = (np.arange(500, dtype=float) for _ in range(3))
    las.write(tmp_path / "scan.las")
    assert len(read_cloud(tmp_path / "scan.las").points) == 500
    monkeypatch.setenv("CALIB_MAX_CLOUD_POINTS", "499")
    with pytest.raises(InputError, match="scan.las: the cloud holds 500 points, more than the 499 points limit"):
        read_cloud(tmp_path / "scan.las")


def _npy_header(text: str) -> bytes:
    header = text.encode() + b" " * (64 - (len(text) + 11) % 64) + b"\n"
    return struct.pack("<H", len(header)) + header


# --- file names --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("route, field", [("sensors/cam/captures", "files"), ("sensors/lid/clouds", "files")])
def test_a_nul_byte_in_a_file_name_is_a_422_naming_the_field(client: TestClient, board_jpg: bytes, route, field):
    data = board_jpg if "captures" in route else npy(np.ones((10, 3)))
    body, headers = multipart([(field, b"scan\x00.npy", data)])
    response = client.post(f"/api/sessions/s/{route}", content=body, headers=headers)
    assert_error(response, 422, input=field, says=[f"field '{field}'", "NUL byte", "expected a plain file name"])
    assert stored(client, "cam") == [] and stored(client, "lid") == [] and no_upload_left(client)


def test_a_nul_byte_in_a_pair_file_name_is_a_422_naming_the_field(client: TestClient, board_jpg: bytes):
    body, headers = multipart([("image", b"frame.jpg", board_jpg), ("cloud", b"c\x00.npy", npy(np.ones((10, 3))))])
    body = (b"--XyZ\r\nContent-Disposition: form-data; name=\"camera\"\r\n\r\ncam\r\n"
            b"--XyZ\r\nContent-Disposition: form-data; name=\"lidar\"\r\n\r\nlid\r\n" + body)
    response = client.post("/api/sessions/s/lidar-camera/pairs", content=body, headers=headers)
    assert_error(response, 422, input="cloud", says=["field 'cloud'", "NUL byte"])
    assert stored(client, "cam") == [] and stored(client, "lid") == []


# --- all or nothing ----------------------------------------------------------------------------------------


@pytest.mark.slow
def test_an_image_batch_with_one_refused_file_stores_nothing(client: TestClient, board_jpg: bytes):
    blank = cv2.imencode(".png", np.full((480, 640), 200, np.uint8))[1].tobytes()
    for bad, status in [(("cut.jpg", board_jpg[: len(board_jpg) // 2]), 422), (("blank.png", blank), 422)]:
        response = upload_images(client, [("left01.jpg", board_jpg), bad, ("left01b.jpg", board_jpg)])
        assert_error(response, status, input=bad[0], says=[bad[0]])
        assert stored(client, "cam") == []
    # asked for: the usable ones are stored and the others reported
    response = upload_images(client, [("left01.jpg", board_jpg), ("blank.png", blank)], skip_unusable=True)
    assert response.status_code == 201 and [s["input"] for s in response.json()["skipped"]] == ["blank.png"]
    assert [c["source"] for c in stored(client, "cam")] == ["left01.jpg"]


def test_a_cloud_batch_with_one_refused_file_stores_nothing(client: TestClient, monkeypatch):
    good = npy(np.random.default_rng(2).normal(size=(500, 3)))
    for bad in [("cut.npy", good[:300]), ("notes.txt", b"1 2 3"), ("nan.npy", npy(np.full((5, 3), np.nan)))]:
        response = upload_clouds(client, [("a.npy", good), bad, ("b.npy", good)])
        assert_error(response, 422, input=bad[0], says=[bad[0]])
        assert stored(client, "lid") == [] and no_upload_left(client)
    monkeypatch.setenv("CALIB_MAX_CLOUD_POINTS", "1000")
    response = upload_clouds(client, [("a.npy", good), ("dense.npy", npy(np.ones((2000, 3))))])
    assert_error(response, 422, input="dense.npy", says=["1,000 points limit"])
    assert stored(client, "lid") == []
    response = upload_clouds(client, [("a.npy", good), ("a.npy", good)])  # equal names do not collide
    assert response.status_code == 201 and [c["n_points"] for c in stored(client, "lid")] == [500, 500]
    assert no_upload_left(client)


# --- the event loop stays free -----------------------------------------------------------------------------


def _pair_upload(client: TestClient, board_jpg: bytes):
    files = {"image": ("frame.jpg", board_jpg, "image/jpeg"), "cloud": ("c.npy", npy(np.ones((50, 3))), "x/y")}
    return client.post("/api/sessions/s/lidar-camera/pairs", data={"camera": "cam", "lidar": "lid"}, files=files)


@pytest.mark.parametrize("module, function, send", [
    (intrinsics_service, "import_images", lambda c, jpg: upload_images(c, [("left01.jpg", jpg)] * 3)),
    (lidar_service, "import_clouds", lambda c, jpg: upload_clouds(c, [("a.npy", npy(np.ones((50, 3))))])),
    (pairs_service, "import_pair", _pair_upload),
], ids=["images", "clouds", "pair"])
def test_health_answers_while_an_upload_is_processed(client: TestClient, board_jpg: bytes, monkeypatch,
                                                     module, function, send):
    """The upload's service call is held until /api/health has answered. Were it run on the event loop,
    health could not answer while it is held, and the hold would end by its timeout instead."""
    started, release = threading.Event(), threading.Event()
    original = getattr(module, function)
    answers = {}

    def held(*args, **kwargs):
        started.set()
        answers["released"] = release.wait(timeout=60)
        return original(*args, **kwargs)

    monkeypatch.setattr(module, function, held)
    uploader = threading.Thread(target=lambda: answers.setdefault("upload", send(client, board_jpg)))
    uploader.start()
    assert started.wait(timeout=60), "the upload never reached its service"
    health = client.get("/api/health")
    release.set()
    uploader.join(timeout=120)
    assert health.status_code == 200 and health.json() == {"status": "ok"}
    assert answers["released"], "health answered only after the held upload timed out"
    assert answers["upload"].status_code == 201, answers["upload"].text
