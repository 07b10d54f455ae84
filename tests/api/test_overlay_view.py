"""The full-size overlay through the API: drawn with a transform given in the query (the studio's sliders), its
colour scale spread over the scene's depths with the legend beneath, two loose captures, the page, and the 4xx JSON
of bad queries."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from fastapi.testclient import TestClient

from backend.api.app import create_app
from backend.core.boards import BoardSpec
from backend.core.transforms import from_xyz_ypr, invert, to_xyz_ypr
from backend.sim.board_renderer import render_board_image
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.sim.lidar_scene import LidarScene, moving_board_poses

RIG = demo_rig()
CAMERA, LIDAR = "cam_front", "lidar_front"
QUERY = {"camera": CAMERA, "lidar": LIDAR}


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """A client over a session holding one pair of cam_front and lidar_front; (client, pair as listed)."""
    app = create_app(tmp_path_factory.mktemp("overlay_view"))
    with TestClient(app) as client:
        app.state.studio.store.create("l2c", rig=demo_rig(), board=DEMO_BOARD)
        rng = np.random.default_rng(1)
        T_base_board = moving_board_poses(1, seed=2)[0]
        camera = RIG.get(CAMERA).intrinsics
        image = render_board_image(camera, BoardSpec.parse(DEMO_BOARD), invert(RIG.T_root_frame(CAMERA)) @ T_base_board,
                                   rng)
        scan = LidarScene(board_pose=T_base_board).scan_3d(RIG.T_root_frame(LIDAR), beams=32, rng=rng)
        cloud = io.BytesIO()
        np.save(cloud, scan.points)
        files = {"image": ("frame.png", cv2.imencode(".png", image)[1].tobytes(), "image/png"),
                 "cloud": ("frame.npy", cloud.getvalue(), "application/octet-stream")}
        response = client.post("/api/sessions/l2c/lidar-camera/pairs", data=QUERY, files=files)
        assert response.status_code == 201, response.text
        yield client, response.json()


def _decoded(response) -> np.ndarray:
    assert response.status_code == 200, response.text
    return cv2.imdecode(np.frombuffer(response.content, np.uint8), cv2.IMREAD_COLOR)


def test_overlay_with_the_sliders_transform_and_its_legend(stored):
    client, pair = stored
    url = f"/api/sessions/l2c/lidar-camera/overlay/{pair['image']}"
    T = RIG.T_a_b(CAMERA, LIDAR)
    xyz, ypr = to_xyz_ypr(T)
    given = {"xyz_m": ",".join(map(str, xyz)), "ypr_deg": ",".join(map(str, np.degrees(ypr)))}
    rig = client.get(url, params=QUERY)
    same = client.get(url, params=QUERY | given)
    assert _decoded(same).shape == (720, 1280, 3)  # full size, no legend unless asked
    assert same.headers["x-points-drawn"] == rig.headers["x-points-drawn"]
    assert int(same.headers["x-points-drawn"]) > 1000
    assert same.headers["x-colour-scale"] == "depth (m)"
    lo, hi = map(float, same.headers["x-colour-range"].split(","))
    assert 0.5 < lo < hi < 40.0 and hi - lo > 1.0, (lo, hi)  # the scene's depths, not the 0.5-40 m window

    turned = from_xyz_ypr(xyz, ypr + np.radians([2.0, 0, 0]))
    moved = client.get(url, params=QUERY | {"xyz_m": given["xyz_m"],
                                            "ypr_deg": ",".join(map(str, np.degrees(to_xyz_ypr(turned)[1])))})
    assert np.abs(_decoded(moved).astype(int) - _decoded(same).astype(int)).max() > 100  # drawn elsewhere

    with_legend = _decoded(client.get(url, params=QUERY | given | {"legend": "true"}))
    assert with_legend.shape == (720 + 40, 1280, 3)
    bar = with_legend[724:738, 400:1200].reshape(-1, 3)  # TURBO's blue to red beneath the image
    assert bar[:, 0].astype(int).max() - bar[:, 0].min() > 150 and bar[:, 2].astype(int).max() - bar[:, 2].min() > 150

    loose = client.get(url, params=QUERY | {"cloud_id": pair["cloud"], "colour_by": "height", "occlusion_px": 0})
    assert _decoded(loose).shape == (720, 1280, 3) and loose.headers["x-colour-scale"] == "height (m)"


@pytest.mark.parametrize(("params", "field"), [
    ({"xyz_m": "1,2", "ypr_deg": "0,0,0"}, "xyz_m"),
    ({"xyz_m": "0,0,0"}, "ypr_deg"),
    ({"xyz_m": "0,0,0", "ypr_deg": "0,nan,0"}, "ypr_deg"),
    ({"range_m": "5"}, "range_m"),
    ({"range_m": "9,2"}, "range_m"),
    ({"colour_by": "rainbow"}, "colour_by"),
    ({"radius_px": 99}, "radius_px"),
])
def test_bad_overlay_queries_are_4xx_json_naming_the_field(stored, params, field):
    client, pair = stored
    response = client.get(f"/api/sessions/l2c/lidar-camera/overlay/{pair['image']}", params=QUERY | params)
    assert response.status_code == 422, response.text
    assert response.json()["error"]["input"].split(".")[-1] == field, response.text  # query fields: "query.<name>"


def test_unknown_captures_are_404_and_the_page_is_served(stored):
    client, pair = stored
    missing = client.get("/api/sessions/l2c/lidar-camera/overlay/nope", params=QUERY | {"cloud_id": pair["cloud"]})
    assert missing.status_code == 404 and "nope" in missing.json()["error"]["message"]
    page = client.get("/api/sessions/l2c/lidar-camera/view", params=QUERY | {"scene": "all"})
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "overlay/${encodeURIComponent(imageId)}" in page.text
