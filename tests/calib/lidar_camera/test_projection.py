"""LiDAR points onto a camera image (backend.core.projection): OpenCV agreement, culling, occlusion,
the simulated rig's board, the real OpenCalib frame, drawing and colourising."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from backend.core import projection as projection_module
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.camera_inverse import visible_radius
from backend.core.colour_maps import (
    colormap,
    colour_bar,
    depth_colours,
    height_colours,
    intensity_colours,
    spread_range,
)
from backend.core.overlay import OverlayStyle, render_overlays, with_legend
from backend.core.projection import colourise_cloud, draw_points, project_cloud
from backend.core.transforms import from_xyz_ypr, invert, make_T, to_rvec_tvec, transform_points
from backend.exports.ros_camera_info import load_camera_info
from backend.sim.board_renderer import plate_corners_m, render_board_image
from backend.sim.demo_rig import CAM_WIDE, DEMO_BOARD, demo_rig
from backend.sim.lidar_scene import LABELS, LidarScene
from tests.conftest import SHARED_DATA, opencalib_frame

FISHEYE = CameraIntrinsics("fisheye-equidistant", 1280, 720,
                           np.array([[600.0, 0, 641.2], [0, 599.1, 358.7], [0, 0, 1]]),
                           np.array([0.08, -0.02, 0.004, -0.001]))
T_CAMERA_SENSOR = from_xyz_ypr(np.array([0.1, -0.05, 0.2]), np.radians([3.0, -2.0, 1.5]))


def opencv_pixels(camera: CameraIntrinsics, points_sensor: np.ndarray, T_camera_sensor: np.ndarray) -> np.ndarray:
    rvec, tvec = to_rvec_tvec(T_camera_sensor)
    pts = points_sensor.reshape(-1, 1, 3)
    if camera.is_fisheye:
        uv, _ = cv2.fisheye.projectPoints(pts, rvec, tvec, camera.K, camera.dist)
    else:
        uv, _ = cv2.projectPoints(pts, rvec, tvec, camera.K, camera.dist)
    return uv.reshape(-1, 2)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("camera", [CAM_WIDE, FISHEYE], ids=["pinhole-radtan", "fisheye-equidistant"])
def test_matches_opencv_and_drops_what_the_camera_cannot_see(camera: CameraIntrinsics, dtype: type) -> None:
    rng = np.random.default_rng(3)
    # Directions all round the camera (so behind it and far outside its view too), 0.5-20 m out.
    directions = rng.normal(size=(200_000, 3))
    points_cam = directions / np.linalg.norm(directions, axis=1, keepdims=True) * rng.uniform(0.5, 20, (200_000, 1))
    points = transform_points(invert(T_CAMERA_SENSOR), points_cam)
    projection = project_cloud(points, T_CAMERA_SENSOR, camera, dtype=dtype)

    reference = opencv_pixels(camera, points, T_CAMERA_SENSOR)
    assert len(projection) > 10_000
    assert projection.uv.dtype == dtype and projection.depth_m.dtype == dtype and projection.index.dtype == np.int64
    if dtype == np.float64:
        np.testing.assert_allclose(projection.uv, reference[projection.index], atol=1e-6, rtol=0)
        np.testing.assert_allclose(projection.depth_m, points_cam[projection.index, 2], atol=1e-9)
    else:  # float32 (the default): well under a hundredth of a pixel
        np.testing.assert_allclose(projection.uv, reference[projection.index], atol=1e-3, rtol=0)
        np.testing.assert_allclose(projection.depth_m, points_cam[projection.index, 2], rtol=1e-6)

    in_image = np.all((reference >= -0.5) & (reference < np.array(camera.image_size) - 0.5), axis=1)
    radius = np.linalg.norm(points_cam[:, :2], axis=1) / np.abs(points_cam[:, 2])
    in_view = in_image & (points_cam[:, 2] > 0) & (radius <= visible_radius(camera))
    np.testing.assert_array_equal(np.sort(projection.index), np.flatnonzero(in_view))
    behind_but_inside = in_image & (points_cam[:, 2] <= 0)
    assert behind_but_inside.any()  # OpenCV maps some points behind the camera into the image
    folded = in_image & (points_cam[:, 2] > 0) & (radius > visible_radius(camera))
    if not camera.is_fisheye:  # CAM_WIDE's polynomial folds points from far outside its view back in
        assert folded.sum() > 100
    assert not np.isin(projection.index, np.flatnonzero(behind_but_inside | folded)).any()


def test_drops_non_finite_points_and_applies_the_range_window() -> None:
    camera = demo_rig().get("cam_front").intrinsics
    points_cam = np.array([[0.0, 0.0, 2.0], [0.1, 0.0, 6.0], [np.nan, 0, 3], [0, np.inf, 3], [0.0, 0.0, np.inf],
                           [0.2, 0.1, 0.0]])
    points = transform_points(invert(T_CAMERA_SENSOR), points_cam)
    assert list(project_cloud(points, T_CAMERA_SENSOR, camera).index) == [0, 1]
    ranges = np.linalg.norm(points[:2], axis=1)  # from the sensor's origin, not the camera's
    window = (ranges[0] + 0.01, ranges[1] + 0.01)
    assert list(project_cloud(points, T_CAMERA_SENSOR, camera, range_m=window).index) == [1]
    assert len(project_cloud(np.zeros((0, 3)), T_CAMERA_SENSOR, camera, occlusion_px=4)) == 0


def test_a_2d_scanners_points_project_like_any_other() -> None:
    camera = demo_rig().get("cam_front").intrinsics
    angles = np.radians(np.linspace(-40, 40, 81))
    scan = np.column_stack([3 * np.cos(angles), 3 * np.sin(angles), np.zeros_like(angles)])  # z = 0: its plane
    T_camera_scanner = invert(demo_rig().T_root_frame("cam_front")) @ demo_rig().T_root_frame("scanner_2d")
    reference = opencv_pixels(camera, scan, T_camera_scanner)
    projection = project_cloud(scan, T_camera_scanner, camera, dtype=np.float64)
    assert len(projection) > 40
    np.testing.assert_allclose(projection.uv, reference[projection.index], atol=1e-6)
    default = project_cloud(scan, T_camera_scanner, camera)  # float32
    np.testing.assert_array_equal(default.index, projection.index)
    np.testing.assert_allclose(default.uv, reference[default.index], atol=1e-3)


def test_occlusion_hides_far_points_behind_a_near_plane_only() -> None:
    camera = demo_rig().get("cam_front").intrinsics
    grid = np.stack(np.meshgrid(np.linspace(-1, 1, 201), np.linspace(-0.6, 0.6, 121)), axis=-1).reshape(-1, 2)
    far = np.column_stack([grid * 5.0, np.full(len(grid), 5.0)])  # a wall 5 m ahead
    panel = grid[np.all(np.abs(grid) < 0.25, axis=1)]
    near = np.column_stack([panel * 2.0, np.full(len(panel), 2.0)])  # a 1x1 m panel 2 m ahead
    points = np.vstack([near, far])
    is_far = np.arange(len(points)) >= len(near)
    # Far points whose ray passes through the panel (|x/z|, |y/z| < 0.25) are behind it.
    behind = is_far & np.all(np.abs(points[:, :2] / points[:, 2:]) < 0.25, axis=1)
    beside = is_far & np.all(np.abs(points[:, :2] / points[:, 2:]) > 0.3, axis=1)

    shown = np.zeros(len(points), bool)
    shown[project_cloud(points, np.eye(4), camera, occlusion_px=8).index] = True
    plain = np.zeros(len(points), bool)
    plain[project_cloud(points, np.eye(4), camera).index] = True
    assert plain[behind].all()  # without the filter they show through
    assert not shown[behind].any()
    assert shown[~is_far].all()
    assert shown[beside & plain].all() and (beside & plain).sum() > 1000


@pytest.fixture(scope="module")
def simulated_board() -> dict:
    """The demo rig's lidar_front scan of the static board, and cam_front's image of it."""
    rig = demo_rig()
    scene = LidarScene()
    scan = scene.scan_3d(rig.T_root_frame("lidar_front"), rng=0)
    camera = rig.get("cam_front").intrinsics
    board = BoardSpec.parse(DEMO_BOARD)
    T_camera_board = invert(rig.T_root_frame("cam_front")) @ scene.T_base_board
    image = render_board_image(camera, board, T_camera_board, np.random.default_rng(0))
    return {"scan": scan, "camera": camera, "board": board, "T_camera_board": T_camera_board, "image": image,
            "T_camera_lidar": rig.T_a_b("cam_front", "lidar_front")}


def plate_mask(sim: dict) -> np.ndarray:
    """uint8 mask of the plate's outline as cam_front sees it (edges sampled densely: distortion bends them)."""
    corners = plate_corners_m(sim["board"])
    t = np.linspace(0, 1, 50, endpoint=False)[:, None]
    outline = np.vstack([a + t * (b - a) for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True)])
    uv = sim["camera"].project(transform_points(sim["T_camera_board"], outline))
    mask = np.zeros(sim["image"].shape, np.uint8)
    cv2.fillPoly(mask, [np.rint(uv).astype(np.int32)], 1)
    return mask


def test_simulated_board_points_land_on_the_board_only_with_the_true_transform(simulated_board: dict) -> None:
    sim = simulated_board
    on_board = sim["scan"].labels == LABELS["board"]
    board_points = sim["scan"].points_true[on_board]
    mask = plate_mask(sim)

    def inside_fraction(T_camera_lidar: np.ndarray) -> float:
        projection = project_cloud(board_points, T_camera_lidar, sim["camera"])
        assert len(projection) == len(board_points)
        cols, rows = np.rint(projection.uv).astype(int).T
        return float(mask[rows, cols].mean())

    assert len(board_points) > 50
    assert inside_fraction(sim["T_camera_lidar"]) == 1.0
    for offset_m in ([0.05, 0, 0], [-0.05, 0, 0], [0, 0.05, 0]):  # 5 cm across the line of sight
        assert inside_fraction(make_T(np.eye(3), offset_m) @ sim["T_camera_lidar"]) < 0.95


def test_colourise_takes_the_boards_pattern_and_flags_unseen_points(simulated_board: dict) -> None:
    sim = simulated_board
    scan = sim["scan"]
    colours, seen = colourise_cloud(scan.points, sim["T_camera_lidar"], sim["camera"], sim["image"])
    on_board = scan.labels == LABELS["board"]
    assert seen[on_board].all()
    grey = colours[on_board, 0].astype(float)
    assert np.all(colours[on_board, 0] == colours[on_board, 2])  # a grey image gives grey colours
    assert (grey < 60).sum() > 10 and (grey > 120).sum() > 10  # black and white squares
    # The board's black squares return less light to the LiDAR too: the two agree.
    assert np.corrcoef(grey, scan.intensity[on_board])[0, 1] > 0.8
    behind = scan.points[:, 0] < 0  # behind the LiDAR, so behind the camera
    assert behind.sum() > 1000 and not seen[behind].any() and not colours[~seen].any()


def test_draw_points_paints_squares_on_a_copy() -> None:
    grey = np.full((20, 30), 50, np.uint8)
    uv = np.array([[5.0, 5.0], [6.2, 5.9], [29.4, 19.4], [-3.0, 4.0], [np.nan, 1.0]])
    colours = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [9, 9, 9], [9, 9, 9]], np.uint8)
    out = draw_points(grey, uv, colours, radius_px=1)
    assert out.shape == (20, 30, 3) and out.dtype == np.uint8 and grey.max() == 50
    assert tuple(out[4, 4]) == (0, 0, 255)  # first point's square, red as BGR
    assert tuple(out[5, 6]) == (0, 255, 0) and tuple(out[6, 7]) == (0, 255, 0)  # the later point is on top
    assert tuple(out[19, 29]) == (255, 0, 0) and tuple(out[18, 28]) == (255, 0, 0)  # clipped at the corner
    assert int((out != 50).any(axis=2).sum()) == 9 + 9 - 4 + 4  # nothing else changed
    single = draw_points(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR), uv[:1], colours[:1], radius_px=0)
    assert int((single != 50).any(axis=2).sum()) == 1


def test_colour_modes_use_turbo() -> None:
    assert depth_colours(np.array([0.5, 10.0]), 0.5, 10.0).tolist() != [[0, 0, 0]] * 2
    blue_end, red_end = depth_colours(np.array([0.0, 20.0]), 0.0, 20.0)
    assert blue_end[2] > blue_end[0] and red_end[0] > red_end[2]  # TURBO: near blue, far red
    assert intensity_colours(np.arange(100.0)).shape == (100, 3)
    T_root_sensor = make_T(np.eye(3), [0, 0, 1.0])
    low, high = height_colours(np.array([[0, 0, -1.0], [0, 0, 2.0]]), T_root_sensor, 0.0, 3.0)
    assert low[2] > low[0] and high[0] > high[2]


def test_depth_colours_spread_a_scene_between_its_2nd_and_98th_percentile() -> None:
    """A wall 8-12 m away within the default 0.5-40 m window: the window painted it all one blue; the percentiles
    spread it over the whole map, and the legend beneath says from where to where."""
    camera = demo_rig().get("cam_front").intrinsics
    rng = np.random.default_rng(4)
    depth = rng.uniform(8.0, 12.0, 20_000)
    points_cam = np.column_stack([rng.uniform(-0.5, 0.5, 20_000) * depth, rng.uniform(-0.3, 0.3, 20_000) * depth,
                                  depth])
    points = transform_points(invert(T_CAMERA_SENSOR), points_cam)
    image = np.full((camera.height, camera.width), 90, np.uint8)
    (drawn,), (projection,), scale = render_overlays([(image, points, None)], T_CAMERA_SENSOR, camera,
                                                     OverlayStyle(occlusion_px=0))
    assert len(projection) > 15_000 and scale.label == "depth (m)"
    lo, hi = np.percentile(projection.depth_m, [2, 98])
    assert scale.lo == pytest.approx(lo, abs=0.05) and scale.hi == pytest.approx(hi, abs=0.05)  # a 65k subsample
    old = depth_colours(projection.depth_m, *OverlayStyle.range_m)
    new = colormap(projection.depth_m, scale.lo, scale.hi)
    spread = lambda colours: len(np.unique(colours, axis=0))  # noqa: E731
    assert spread(new) > 200 > 5 * spread(old), (spread(new), spread(old))
    near, far = np.argmin(projection.depth_m), np.argmax(projection.depth_m)
    assert new[near][2] > new[near][0] and new[far][0] > new[far][2]  # blue near, red far

    legend = with_legend(drawn, scale)
    assert legend.shape == (camera.height + 40, camera.width, 3)
    np.testing.assert_array_equal(legend[:camera.height], drawn)
    np.testing.assert_array_equal(legend[camera.height:], colour_bar(scale.lo, scale.hi, "depth (m)", camera.width))


def test_spread_range_ignores_non_finite_values_and_falls_back() -> None:
    assert spread_range(np.r_[np.linspace(0.0, 100.0, 101), np.nan, np.inf]) == pytest.approx((2.0, 98.0))
    assert spread_range(np.array([np.nan]), fallback=(0.5, 40.0)) == (0.5, 40.0)
    lo, hi = spread_range(np.full(10, 3.0))
    assert lo == 3.0 and hi > lo


def opencalib() -> tuple[np.ndarray, np.ndarray, CameraIntrinsics, np.ndarray]:
    frame = opencalib_frame()
    return frame.points, frame.image, frame.camera, frame.T_camera_lidar


def depth_edge_distance(points: np.ndarray, T: np.ndarray, camera: CameraIntrinsics, edge_distance: np.ndarray
                        ) -> float:
    """Mean distance (px) to the nearest image edge of projected points on the near side of a depth jump."""
    projection = project_cloud(points, T, camera, occlusion_px=3)
    cols, rows = np.rint(projection.uv).astype(int).T
    depth = np.zeros((camera.height, camera.width), np.float32)
    depth[rows, cols] = projection.depth_m
    farthest_nearby = cv2.dilate(depth, np.ones((9, 9), np.uint8))[rows, cols]
    edge = farthest_nearby > projection.depth_m * 1.5
    return float(edge_distance[rows[edge], cols[edge]].mean())


def test_real_frame_projects_its_points_and_depth_edges_meet_image_edges() -> None:
    points, image, camera, T_camera_lidar = opencalib()
    count = len(project_cloud(points, T_camera_lidar, camera))
    assert 9_000 <= count <= 11_500, count  # 10,520 here; the data's README says about 10,300

    edges = cv2.Canny(cv2.GaussianBlur(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), (5, 5), 1.5), 50, 150)
    edge_distance = cv2.distanceTransform(np.where(edges > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, 5)
    reference = depth_edge_distance(points, T_camera_lidar, camera, edge_distance)
    for rotvec in np.vstack([np.eye(3), -np.eye(3)]):  # 3 deg either way about each of the camera's axes
        turned = make_T(Rotation.from_rotvec(np.radians(3.0) * rotvec).as_matrix(), np.zeros(3)) @ T_camera_lidar
        # 5.2 px for the reference; 5.6 to 19.7 px turned.
        assert reference < depth_edge_distance(points, turned, camera, edge_distance)


# -- the fast paths: float32 against float64, chunks, the drawing and colour look-ups --------------------------------

def cloud_around(n: int, seed: int) -> np.ndarray:
    """(n, 3) points in T_CAMERA_SENSOR's sensor frame, 0.5-40 m out, mostly ahead of the camera, with a few NaN."""
    rng = np.random.default_rng(seed)
    directions = rng.normal(size=(n, 3)) + [0.0, 0.0, 1.5]
    points_cam = directions / np.linalg.norm(directions, axis=1, keepdims=True) * rng.uniform(0.5, 40, (n, 1))
    points_cam[rng.choice(n, n // 100, replace=False), rng.integers(0, 3)] = np.nan
    return transform_points(invert(T_CAMERA_SENSOR), points_cam)


CAMERAS = [demo_rig().get("cam_front").intrinsics, CAM_WIDE, FISHEYE]
CAMERA_IDS = ["cam_front", "cam_wide", "fisheye"]


@pytest.mark.parametrize("camera", CAMERAS, ids=CAMERA_IDS)
def test_float32_keeps_the_float64_points_within_a_thousandth_of_a_pixel(camera: CameraIntrinsics) -> None:
    points = cloud_around(300_000, seed=5)
    for range_m in (None, (1.0, 30.0)):
        fast = project_cloud(points, T_CAMERA_SENSOR, camera, range_m=range_m)
        exact = project_cloud(points, T_CAMERA_SENSOR, camera, range_m=range_m, dtype=np.float64)
        assert fast.uv.dtype == np.float32 and len(exact) > 50_000
        np.testing.assert_array_equal(fast.index, exact.index)
        np.testing.assert_allclose(fast.uv, exact.uv, atol=1e-3, rtol=0)
        np.testing.assert_allclose(fast.depth_m, exact.depth_m, rtol=1e-6)
    # With the occlusion filter a point within ~1e-4 px of a block edge may fall into the next block.
    fast = project_cloud(points, T_CAMERA_SENSOR, camera, occlusion_px=6)
    exact = project_cloud(points, T_CAMERA_SENSOR, camera, occlusion_px=6, dtype=np.float64)
    assert len(np.setxor1d(fast.index, exact.index)) <= 1e-4 * len(exact)


def test_float32_loses_nothing_on_a_cloud_far_from_its_frames_origin() -> None:
    camera = CAMERAS[0]
    offset_m = np.array([5000.0, -3000.0, 120.0])  # e.g. a map frame 6 km away: the float64 transform takes it out
    T_camera_map = T_CAMERA_SENSOR @ make_T(np.eye(3), -offset_m)
    points = cloud_around(50_000, seed=6) + offset_m
    fast = project_cloud(points, T_camera_map, camera)
    exact = project_cloud(points, T_camera_map, camera, dtype=np.float64)
    np.testing.assert_array_equal(fast.index, exact.index)
    np.testing.assert_allclose(fast.uv, exact.uv, atol=1e-3, rtol=0)


def test_chunks_give_the_one_pass_result(monkeypatch: pytest.MonkeyPatch) -> None:
    camera = CAM_WIDE
    points = cloud_around(20_000, seed=7)
    results = []
    for chunk in (10**9, 997):
        monkeypatch.setattr(projection_module, "CHUNK_POINTS", chunk)
        results.append(project_cloud(points, T_CAMERA_SENSOR, camera, range_m=(1.0, 30.0), occlusion_px=5))
    one_pass, chunked = results
    assert len(one_pass) > 5_000
    for name in ("uv", "depth_m", "index"):
        np.testing.assert_array_equal(getattr(chunked, name), getattr(one_pass, name))


@pytest.mark.parametrize("occlusion_px", [0, 5])
def test_two_threads_give_the_one_thread_result(monkeypatch: pytest.MonkeyPatch, occlusion_px: int) -> None:
    points = cloud_around(40_000, seed=9)
    monkeypatch.setattr(projection_module, "CHUNK_POINTS", 3_001)  # 14 chunks, split over the two threads
    results = []
    for parallel_from in (10**9, 1):
        monkeypatch.setattr(projection_module, "PARALLEL_MIN_POINTS", parallel_from)
        results.append(project_cloud(points, T_CAMERA_SENSOR, CAM_WIDE, range_m=(1.0, 30.0),
                                     occlusion_px=occlusion_px))
    one_thread, two_threads = results
    assert len(one_thread) > 5_000
    for name in ("uv", "depth_m", "index"):
        np.testing.assert_array_equal(getattr(two_threads, name), getattr(one_thread, name))


def test_occlusion_keeps_what_a_block_z_buffer_keeps_in_order() -> None:
    camera = CAMERAS[0]
    points = cloud_around(100_000, seed=8)
    seen = project_cloud(points, T_CAMERA_SENSOR, camera, dtype=np.float64)
    block_px, margin = 7, 0.1
    cols, rows = (np.floor((seen.uv + 0.5) / block_px).astype(int)).T
    block = rows * (-(-camera.width // block_px)) + cols
    nearest = np.full(block.max() + 1, np.inf)
    np.minimum.at(nearest, block, seen.depth_m)
    expected = seen.index[seen.depth_m <= nearest[block] * (1 + margin)]
    shown = project_cloud(points, T_CAMERA_SENSOR, camera, occlusion_px=block_px, occlusion_margin=margin,
                          dtype=np.float64)
    assert 1_000 < len(shown) < len(seen)
    np.testing.assert_array_equal(shown.index, expected)  # the same points, in the cloud's order


def test_project_cloud_takes_float32_or_float64_only() -> None:
    with pytest.raises(ValueError, match="float32 or float64"):
        project_cloud(np.zeros((3, 3)), np.eye(4), CAMERAS[0], dtype=np.float16)


def painted_in_order(image: np.ndarray, uv: np.ndarray, colours: np.ndarray, radius_px: int) -> np.ndarray:
    """What draw_points promises, the slow way: each point's square painted one after another (BGR)."""
    canvas = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR) if image.ndim == 2 else image.copy()
    height, width = canvas.shape[:2]
    for (u, v), rgb in zip(uv, colours, strict=True):
        if -0.5 <= u < width - 0.5 and -0.5 <= v < height - 0.5:
            col, row = int(np.rint(u)), int(np.rint(v))
            canvas[max(row - radius_px, 0):row + radius_px + 1, max(col - radius_px, 0):col + radius_px + 1] = rgb[::-1]
    return canvas


@pytest.mark.parametrize("radius_px", [0, 1, 2])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_draw_points_paints_like_one_point_after_another(radius_px: int, dtype: type,
                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(projection_module, "CHUNK_POINTS", 500)  # several chunks
    rng = np.random.default_rng(radius_px)
    image = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    uv = rng.uniform([-3, -3], [67, 51], (3_000, 2)).astype(dtype)  # dense: most pixels covered several times
    uv[::97] = np.nan
    uv[5] = [-0.5, 47.4999]  # edges: inside
    uv[6] = [63.5, 10.0]  # outside
    colours = rng.integers(0, 256, (len(uv), 3), dtype=np.uint8)
    np.testing.assert_array_equal(draw_points(image, uv, colours, radius_px), painted_in_order(image, uv, colours,
                                                                                                 radius_px))


def test_draw_points_from_several_threads_at_once() -> None:
    rng = np.random.default_rng(9)
    image = np.full((240, 320), 80, np.uint8)
    jobs = [(rng.uniform(0, 320, (20_000, 2)), rng.integers(0, 256, (20_000, 3), dtype=np.uint8)) for _ in range(4)]
    expected = [draw_points(image, uv, colours) for uv, colours in jobs]
    with ThreadPoolExecutor(4) as pool:
        drawn = list(pool.map(lambda job: draw_points(image, *job), jobs * 5))
    for i, result in enumerate(drawn):
        np.testing.assert_array_equal(result, expected[i % 4])
    assert draw_points(image, np.zeros((0, 2)), np.zeros((0, 3), np.uint8)).shape == (240, 320, 3)
    with pytest.raises(ValueError, match="colours"):
        draw_points(image, np.zeros((5, 2)), np.zeros((4, 3), np.uint8))


@pytest.mark.parametrize("cmap", [cv2.COLORMAP_TURBO, cv2.COLORMAP_VIRIDIS])
def test_colormap_is_opencvs_map_of_the_values_scaled_in_float32(cmap: int) -> None:
    values = np.concatenate([np.random.default_rng(10).uniform(-2, 12, 20_000), [0.5, 10.0, np.inf, -np.inf]])
    lo, hi = 0.5, 10.0
    scaled = (np.clip((values.astype(np.float32) - lo) / (hi - lo), 0.0, 1.0) * 255.0).astype(np.uint8)
    expected = cv2.applyColorMap(scaled[:, None], cmap)[:, 0, ::-1]
    np.testing.assert_array_equal(colormap(values, lo, hi, cmap), expected)
    assert colormap(np.zeros(0), lo, hi).shape == (0, 3)


@pytest.mark.parametrize("camera", CAMERAS, ids=CAMERA_IDS)
def test_normalised_to_pixels_computes_in_the_dtype_it_is_given(camera: CameraIntrinsics) -> None:
    rng = np.random.default_rng(11)
    angle, radius = rng.uniform(0, 2 * np.pi, 10_000), rng.uniform(0, visible_radius(camera), 10_000)
    x, y = radius * np.cos(angle), radius * np.sin(angle)
    exact = camera.normalised_to_pixels(x, y)
    fast = camera.normalised_to_pixels(x.astype(np.float32), y.astype(np.float32))
    assert exact[0].dtype == np.float64 and fast[0].dtype == np.float32
    np.testing.assert_allclose(np.column_stack(fast), np.column_stack(exact), atol=1e-3, rtol=0)
    rvec = tvec = np.zeros(3)
    points = np.column_stack([x, y, np.ones_like(x)])[:, None, :]
    project = cv2.fisheye.projectPoints if camera.is_fisheye else cv2.projectPoints
    reference = project(points, rvec, tvec, camera.K, camera.dist)[0].reshape(-1, 2)
    np.testing.assert_allclose(np.column_stack(exact), reference, atol=1e-6, rtol=0)


def test_colourise_gives_each_seen_point_its_nearest_pixels_colour() -> None:
    camera = CAMERAS[0]
    points = cloud_around(50_000, seed=12)
    image = np.random.default_rng(12).integers(0, 256, (camera.height, camera.width, 3), dtype=np.uint8)
    colours, seen = colourise_cloud(points, T_CAMERA_SENSOR, camera, image, occlusion_px=4)
    projection = project_cloud(points, T_CAMERA_SENSOR, camera, occlusion_px=4)
    np.testing.assert_array_equal(np.flatnonzero(seen), np.sort(projection.index))
    cols, rows = np.rint(projection.uv).astype(int).T
    np.testing.assert_array_equal(colours[projection.index], image[rows, cols, ::-1])  # BGR image, RGB colours
    assert not colours[~seen].any()


def test_a_lens_model_that_folds_before_the_image_corners_sees_up_to_its_fold() -> None:
    # The real VLP-16 set's fisheye (kc sigma up to 37): its polynomial theta_d(theta) peaks at about 43 deg, short of
    # the image corners, which then have no inverse. Drawing a cloud on its images raised ValueError (an API 500).
    camera, _ = load_camera_info(SHARED_DATA / "vlp16_camera_checkerboard" / "camera.yaml")
    k1, k2, k3, k4 = camera.dist[:4]
    slope = np.polynomial.Polynomial([1, 0, 3 * k1, 0, 5 * k2, 0, 7 * k3, 0, 9 * k4])  # d theta_d / d theta
    fold_theta = min(r.real for r in slope.roots() if abs(r.imag) < 1e-12 and r.real > 0)
    assert np.degrees(fold_theta) < 50
    assert visible_radius(camera) == pytest.approx(np.tan(fold_theta), rel=1e-3)

    angles = np.radians(np.linspace(0, 80, 400))
    points = np.column_stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)]) * 5.0
    projection = project_cloud(points, np.eye(4), camera)
    assert np.all(angles[projection.index] <= fold_theta) and len(projection) > 0.9 * np.sum(angles <= fold_theta)
    drawn, _, _ = render_overlays([(np.zeros((camera.height, camera.width, 3), np.uint8), points, None)], np.eye(4),
                                  camera, OverlayStyle())
    assert drawn[0].any()


def test_a_photogrammetric_camera_projects_clouds_by_its_own_equations() -> None:
    """The overlay's projection takes the photogrammetric model too: without the affine terms it is OpenCV's
    projection of the converted camera, with them the model's own equations (in float32 within 1e-3 px)."""
    from backend.core.camera_conversion import convert
    from tests.core.test_photogrammetric_model import blackfly

    rng = np.random.default_rng(4)
    points_cam = rng.uniform([-6, -5, 0.5], [6, 5, 12], (50_000, 3))
    points = transform_points(invert(T_CAMERA_SENSOR), points_cam)
    plain = project_cloud(points, T_CAMERA_SENSOR, blackfly(), dtype=np.float64)
    reference = opencv_pixels(convert(blackfly(), "pinhole-radtan").camera, points, T_CAMERA_SENSOR)
    assert len(plain) > 10_000
    np.testing.assert_allclose(plain.uv, reference[plain.index], atol=1e-6, rtol=0)
    camera = blackfly(A1=4e-4, A2=-2.5e-4)
    projection = project_cloud(points, T_CAMERA_SENSOR, camera)
    np.testing.assert_allclose(projection.uv, camera.project(points_cam[projection.index]), atol=1e-3, rtol=0)
    expected = camera.project(points_cam)
    in_image = np.all((expected >= -0.5) & (expected < np.array(camera.image_size) - 0.5), axis=1)
    radius = np.linalg.norm(points_cam[:, :2], axis=1) / points_cam[:, 2]
    folded = in_image & (radius > visible_radius(camera))  # the polynomial folds points from far outside back in
    assert folded.sum() > 100
    np.testing.assert_array_equal(np.sort(projection.index), np.flatnonzero(in_image & ~folded))
