"""The simulated depth cell (backend/sim/depth_cell.py) and its sim_depth driver, against analytic ground truth."""

from __future__ import annotations

import json

import numpy as np
import pytest
from matplotlib.path import Path

from backend.core.depth import KINECT_V2, pose_from_row
from backend.core.depth_cell import PAPER_NODE_POSES, CellLayout, TablePlacement, default_cell_layout
from backend.core.errors import InputError
from backend.core.transforms import invert, transform_points
from backend.devices.base import DeviceError, create_device
from backend.sim.depth_cell import (
    ALBEDO,
    SURFACES,
    CellScene,
    node_pose,
    node_visibility,
    placement_from_dict,
    range_sigma_m,
    table_corners_m,
    table_placements,
    truth_dict,
)

LAYOUT = default_cell_layout()


@pytest.fixture(scope="module")
def sn1_behind():
    """sn1 with three tables behind each other: the placements, the scene and its noise-free frame."""
    placements = table_placements("sn1", "behind")
    scene = CellScene(LAYOUT, placements)
    return placements, scene, scene.render(node_pose("sn1"), None)


@pytest.fixture(scope="module")
def empty_cell():
    return CellScene(LAYOUT)


def world_points(frame, T_world_node):
    points, index = KINECT_V2.unproject(frame.depth_m)
    return transform_points(T_world_node, points), index


def test_floor_depth_matches_the_ray_plane_intersection(sn1_behind):
    """Every floor pixel's depth equals the analytic intersection of its ray with z = 0, to 0.1 mm (float32)."""
    _, _, frame = sn1_behind
    T = node_pose("sn1")
    on_floor = np.isin(frame.labels, [SURFACES["floor"], SURFACES["tape"], SURFACES["cross"]]).ravel()
    rays = KINECT_V2.rays().reshape(-1, 3)[on_floor]
    expected = -T[2, 3] / (rays @ T[2, :3])  # Z along the optical axis where the ray meets the floor
    assert on_floor.sum() > 50_000
    np.testing.assert_allclose(frame.depth_m.ravel()[on_floor], expected, atol=1e-4)


def test_table_tops_are_level_at_their_known_height(sn1_behind):
    """Noise-free: the pixels inside each top's outline fit a plane at 0.74 m within 1 mm, level within 0.01 deg."""
    placements, _, frame = sn1_behind
    points, index = world_points(frame, node_pose("sn1"))
    on_table = frame.labels.ravel()[index] == SURFACES["table"]
    for placement in placements:
        corners = table_corners_m(LAYOUT, placement)
        inner = placement.centre_xy_m + 0.95 * (corners[:, :2] - placement.centre_xy_m)  # off the side faces
        mine = on_table & Path(inner).contains_points(points[:, :2])
        assert mine.sum() > 1000, placement
        xy1 = np.column_stack([points[mine, :2], np.ones(mine.sum())])
        (a, b, c), *_ = np.linalg.lstsq(xy1, points[mine, 2], rcond=None)
        height = c + a * placement.centre_xy_m[0] + b * placement.centre_xy_m[1]
        assert abs(height - LAYOUT.table(placement.table).height_m) < 1e-3
        assert np.degrees(np.arctan(np.hypot(a, b))) < 0.01


def test_range_noise_at_5_m_on_the_floor(empty_cell):
    """Floor pixels 4.8-5.2 m away: the robust sigma of noisy minus true range is within 10 % of the model's
    7.2 mm (6 mm at 5 m for albedo 0.5, / sqrt(0.35 / 0.5)); the model is 1.5 mm at 1 m and steep beyond 9 m."""
    T = node_pose("sn2")
    clean = empty_cell.render(T, None)
    noisy = empty_cell.render(T, np.random.default_rng(5))
    lengths = np.linalg.norm(KINECT_V2.rays(), axis=2)
    r_true, r_noisy = clean.depth_m * lengths, noisy.depth_m * lengths
    band = (clean.labels == SURFACES["floor"]) & (r_true > 4.8) & (r_true < 5.2)
    error = (r_noisy - r_true)[band]
    sigma = 1.4826 * np.median(np.abs(error - np.median(error)))
    expected = float(range_sigma_m(5.0, ALBEDO["floor"]))
    assert band.sum() > 2000
    assert 0.0065 < expected < 0.0079
    assert abs(sigma / expected - 1) < 0.1, (sigma, expected)
    np.testing.assert_allclose(range_sigma_m([1.0, 5.0], 0.5), [0.0015, 0.006], rtol=1e-6)
    assert range_sigma_m(10.0, 0.5) > 3 * range_sigma_m(9.0, 0.5)
    assert range_sigma_m(5.0, 0.2) > range_sigma_m(5.0, 0.9)  # darker is noisier
    moved = np.abs(noisy.depth_m - clean.depth_m) > 0.05  # flying pixels (and no returns gained or lost)
    assert ((noisy.depth_m > 0) == (clean.depth_m > 0)).all()
    assert 0 < moved.sum() < 0.01 * moved.size


def test_markings_tape_brighter_crosses_far_brighter(sn1_behind):
    """Tape returns about 0.85 / 0.35 of the floor's amplitude at the same place; crosses, range for range, more
    than 10x anything diffuse, and more than any diffuse surface beyond 2 m (the walls beside a node are closer)."""
    _, _, frame = sn1_behind
    labels, amplitude = frame.labels, frame.amplitude
    tape, floor = labels == SURFACES["tape"], labels == SURFACES["floor"]
    # neighbouring pixels see the same range and incidence, so compare tape pixels to the floor pixel beside them
    beside = tape[:, :-1] & floor[:, 1:]
    ratio = np.median(amplitude[:, :-1][beside] / amplitude[:, 1:][beside])
    assert abs(ratio - ALBEDO["tape"] / ALBEDO["floor"]) < 0.1
    crosses = labels == SURFACES["cross"]
    assert crosses.sum() > 100
    diffuse = ~crosses & (labels > 0)
    range_m = frame.depth_m * np.linalg.norm(KINECT_V2.rays(), axis=2)
    reflectance = amplitude * range_m**2  # amplitude falls as 1 / r^2
    assert reflectance[crosses].min() > 10 * reflectance[diffuse].max()
    assert amplitude[crosses].min() > amplitude[diffuse & (range_m > 2.0)].max()


@pytest.mark.slow
def test_every_node_sees_the_floor_two_crossing_lines_and_every_measured_cross(empty_cell):
    """Every paper node sees the floor and an X and a Y line (each over 1.5 m); every cross of a measured distance
    is seen by some node (20 pixels or more)."""
    seen_crosses: dict[str, int] = {}
    for node in PAPER_NODE_POSES:
        visible = node_visibility(empty_cell, node_pose(node))
        assert visible["floor_pixels"] > 100_000, node
        long_lines = {LAYOUT_LINES[name] for name, length in visible["lines"].items() if length > 1.5}
        assert long_lines == {"x", "y"}, (node, visible["lines"])
        for name, pixels in visible["crosses"].items():
            seen_crosses[name] = max(seen_crosses.get(name, 0), pixels)
    for distance in LAYOUT.distances:
        assert seen_crosses.get(distance.a, 0) >= 20 and seen_crosses.get(distance.b, 0) >= 20, distance


LAYOUT_LINES = {line.name: line.axis for line in LAYOUT.lines}


@pytest.mark.parametrize("arrangement", ["behind", "beside"])
@pytest.mark.slow
def test_table_placements_whole_in_view_and_apart(arrangement):
    """For every node: three tables, each top's corners inside the image and within range, every pixel inside
    its outline on it (nothing hides any of it), not touching; behind runs from the image's bottom up (and further
    away), beside from left to right."""
    v, u = np.mgrid[0:KINECT_V2.height, 0:KINECT_V2.width]
    pixels = np.column_stack([u.ravel(), v.ravel()])
    for node in PAPER_NODE_POSES:
        placements = table_placements(node, arrangement)
        assert placements == table_placements(node, arrangement)  # deterministic
        T_node_world = invert(node_pose(node))
        on_a_top = (CellScene(LAYOUT, placements).render(node_pose(node), None).labels == SURFACES["table"]).ravel()
        centres_uv = []
        for placement in placements:
            points = transform_points(T_node_world, table_corners_m(LAYOUT, placement))
            uv, z = KINECT_V2.project(points)
            assert (z > 0).all() and (uv >= 0).all() and (uv[:, 0] < 512).all() and (uv[:, 1] < 424).all()
            assert (np.linalg.norm(points, axis=1) < KINECT_V2.max_range_m).all()
            outline = Path(uv).contains_points(pixels)
            assert outline.sum() > 1000 and on_a_top[outline].all(), (node, placement)
            centres_uv.append(uv.mean(axis=0))
        centres = np.array([p.centre_xy_m for p in placements])
        gaps = np.linalg.norm(np.diff(centres, axis=0), axis=1)
        assert (gaps > 0.8 + 0.2).all(), (node, gaps)
        u, v = np.array(centres_uv).T
        if arrangement == "behind":
            assert (np.diff(v) < -30).all(), (node, v)
        else:
            assert (np.diff(u) > 80).all() and np.ptp(v) < 40, (node, u, v)


def test_truth_dict_is_json_and_reads_back():
    placements = {"c0001": table_placements("sn3", "beside")}
    poses = {node: node_pose(node) for node in PAPER_NODE_POSES}
    truth = json.loads(json.dumps(truth_dict(LAYOUT, poses, placements)))
    assert CellLayout.from_dict(truth["layout"]) == LAYOUT
    for node, row in PAPER_NODE_POSES.items():
        np.testing.assert_allclose(truth["nodes"][node]["pose_row"], row, atol=1e-9)
        np.testing.assert_allclose(truth["nodes"][node]["T_world_node"], pose_from_row(row), atol=1e-12)
    assert [placement_from_dict(p) for p in truth["table_placements"]["c0001"]] == placements["c0001"]
    assert all(c[2] == 0.74 for top in truth["table_tops"]["c0001"] for c in top["corners_m"])
    assert truth["crosses"]["gantry_a1"] == [3.5, 3.0, 0.0]


def test_bad_placements_and_nodes_are_named():
    with pytest.raises(InputError, match="table9"):
        CellScene(LAYOUT, [TablePlacement("table9", (5.0, 5.0))])
    with pytest.raises(InputError, match="outside"):
        CellScene(LAYOUT, [TablePlacement("table1", (9.8, 5.0))])
    with pytest.raises(InputError, match="twice"):
        CellScene(LAYOUT, [TablePlacement("table1", (5.0, 5.0)), TablePlacement("table1", (3.0, 5.0))])
    with pytest.raises(InputError, match="centre_xy_m"):
        placement_from_dict({"table": "table1", "centre_xy_m": "here"})
    with pytest.raises(InputError, match="sn7"):
        table_placements("sn7", "behind")
    with pytest.raises(InputError, match="4x4") as error:
        CellScene(LAYOUT).render(np.eye(3), None)
    assert error.value.input == "T_world_node"


def test_driver_reads_consistent_samples_and_moves_tables():
    """sim_depth: depth (424, 512), points = the unprojected valid pixels (node frame), intensity and pixel_index
    of the same length; set_placements puts a table top in the next frame."""
    device = create_device({"driver": "sim_depth", "node": "sn2", "rate_hz": 0, "seed": 3})
    with device:
        sample = device.read()
        assert sample.depth.shape == (424, 512) and sample.depth.dtype == np.float32
        index = sample.meta["pixel_index"]
        assert sample.points.shape == (len(index), 3) and sample.intensity.shape == (len(index),)
        np.testing.assert_allclose(sample.points, KINECT_V2.unproject(sample.depth)[0])
        T = np.array(sample.meta["T_world_node"])
        np.testing.assert_allclose(T, node_pose("sn2"))
        assert "pixel_index" not in sample.storable_meta() and sample.storable_meta()["node"] == "sn2"
        heights = transform_points(T, sample.points)[:, 2]
        assert np.median(np.abs(heights)) < 0.01  # an empty cell: mostly floor
        device.set_placements(table_placements("sn2", "behind"))
        moved = device.read()
        assert moved.meta["frame_index"] == 1 and len(moved.meta["placements"]) == 3
        on_tops = np.abs(transform_points(T, moved.points)[:, 2] - 0.74) < 0.03
        assert on_tops.sum() > 5000
    with pytest.raises(DeviceError, match="sn9"):
        create_device({"driver": "sim_depth", "node": "sn9"}).open()
