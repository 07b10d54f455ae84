"""The node frame codec: what survives quantisation and compression, and what a hostile frame is refused with."""

from __future__ import annotations

import json
import zlib

import numpy as np
import pytest

from backend.core.depth import KINECT_V2, pose_from_row
from backend.core.errors import InputError
from backend.core.voxels import voxel_downsample
from backend.devices.base import Sample
from backend.devices.cloud_codec import MAGIC, PREAMBLE, VERSION, decode_frame, encode_frame


@pytest.fixture(scope="module")
def depth_sample() -> Sample:
    """A Kinect v2 frame of a floor 4.9 m below a node tilted as the paper's (RotX -140 deg), 4 mm range noise,
    amplitude falling with range: as a depth driver gives it (points and intensity of the valid pixels)."""
    T_world_node = pose_from_row([0.0, 0.0, 4.9, 0.0, 0.0, -140.0])
    rays_world = KINECT_V2.rays().reshape(-1, 3) @ T_world_node[:3, :3].T
    with np.errstate(divide="ignore"):
        z = -T_world_node[2, 3] / rays_world[:, 2]  # the floor's depth along each ray (Z = 1 rays)
    depth = np.where((z > 0) & (z < 12), z, 0).reshape(KINECT_V2.height, KINECT_V2.width)
    rng = np.random.default_rng(3)
    depth = (depth + (depth > 0) * rng.normal(0, 0.004, depth.shape)).astype(np.float32)
    points, index = KINECT_V2.unproject(depth)
    amplitude = (1.0 / (1.0 + np.linalg.norm(points, axis=1) ** 2) + rng.normal(0, 0.002, len(index)))
    return Sample(1.7e9, points=points, intensity=amplitude.astype(np.float32), depth=depth,
                  meta={"node": "sn1", "pixel_index": index, "intrinsics": KINECT_V2.to_dict()})


def raw_bytes(sample: Sample) -> int:
    """What the frame holds as float32 arrays: depth and amplitude images, points and intensity."""
    return 2 * sample.depth.size * 4 + sample.points.size * 4 + sample.intensity.size * 4


def test_full_depth_frame_keeps_pixels_to_the_millimetre(depth_sample: Sample) -> None:
    data = encode_frame(depth_sample, None)
    back = decode_frame(data)
    assert raw_bytes(depth_sample) / len(data) > 8  # measured 10.9 on this frame
    assert np.abs(back.depth - depth_sample.depth).max() <= 0.0005 + 1e-6  # uint16 mm
    np.testing.assert_array_equal(back.meta["pixel_index"], depth_sample.meta["pixel_index"])
    ray_length = np.linalg.norm(KINECT_V2.rays().reshape(-1, 3)[back.meta["pixel_index"]], axis=1)
    assert (np.linalg.norm(back.points - depth_sample.points, axis=1) <= 0.0005 * ray_length + 1e-6).all()
    np.testing.assert_allclose(back.intensity, depth_sample.intensity, rtol=1e-3)  # float16
    amplitude = back.meta["amplitude"].ravel()
    np.testing.assert_array_equal(amplitude[back.meta["pixel_index"]], back.intensity)
    assert back.meta["node"] == "sn1" and back.timestamp_s == depth_sample.timestamp_s


def test_streamed_depth_frame_is_its_voxelised_cloud(depth_sample: Sample) -> None:
    data = encode_frame(depth_sample, 0.04)
    back = decode_frame(data)
    centroids, mean_amplitude = voxel_downsample(depth_sample.points, depth_sample.intensity, 0.04)
    assert back.depth is None and back.meta["voxel_m"] == 0.04
    assert raw_bytes(depth_sample) / len(data) > 15  # measured 21 here (25 on a simulated cell node)
    assert np.abs(back.points - centroids).max() <= 0.0005 + 1e-9  # 1 mm steps, in the voxels' order
    np.testing.assert_allclose(back.intensity, mean_amplitude, rtol=0.035)  # 4 mantissa bits


def test_lidar_cloud_and_camera_image_round_trip() -> None:
    rng = np.random.default_rng(5)
    points = rng.uniform(-40, 40, (20_000, 3))
    cloud = decode_frame(encode_frame(Sample(2.0, points=points, intensity=rng.uniform(0, 255, 20_000)), None))
    assert np.abs(cloud.points - points).max() <= 0.00005 + 1e-9  # 0.1 mm steps in a full frame
    image = rng.integers(0, 255, (48, 64, 3), dtype=np.uint8)
    np.testing.assert_array_equal(decode_frame(encode_frame(Sample(3.0, image=image), None)).image, image)  # PNG
    preview = decode_frame(encode_frame(Sample(3.0, image=np.full((48, 64), 120, np.uint8)), 0.02)).image  # JPEG
    assert np.abs(preview.astype(int) - 120).max() <= 2


def test_depth_of_unknown_intrinsics_carries_its_points() -> None:
    depth = np.full((30, 40), 2.0, np.float32)
    depth[0, :5] = 0
    index = np.flatnonzero(depth.ravel() > 0)
    points = np.column_stack([index % 40 * 0.01, index // 40 * 0.01, np.full(len(index), 2.0)])
    back = decode_frame(encode_frame(Sample(0.0, points=points, depth=depth, meta={"pixel_index": index}), None))
    assert np.abs(back.points - points).max() <= 0.00005 + 1e-9
    np.testing.assert_array_equal(back.meta["pixel_index"], index)


def _frame(kind: int, header: dict, body: bytes) -> bytes:
    text = json.dumps(header).encode()
    return PREAMBLE.pack(MAGIC, VERSION, kind, len(text)) + text + body


def test_hostile_frames_are_refused_before_inflating() -> None:
    good = encode_frame(Sample(0.0, points=np.zeros((10, 3))), None)
    with pytest.raises(InputError, match="not a node frame"):
        decode_frame(b"GIF89a" + good[6:], source="frame from sn2")
    with pytest.raises(InputError, match="version 9"):
        decode_frame(PREAMBLE.pack(MAGIC, 9, 0, 0) + good[PREAMBLE.size:])
    with pytest.raises(InputError, match="compressed bytes") as truncated:
        decode_frame(good[:-3], source="frame from sn2")
    assert truncated.value.input == "frame from sn2"
    # a zlib bomb: 20 MB of zeros in 20 kB, its header claiming 3 MB of points (within the limits)
    bomb = zlib.compress(bytes(20_000_000), 9)
    header = {"arrays": [{"name": "points", "dtype": "uint16", "shape": [3, 500_000], "raw_bytes": 3_000_000,
                          "zlib_bytes": len(bomb), "step_m": 0.001, "origin_m": [0, 0, 0]}]}
    with pytest.raises(InputError, match="does not inflate to its stated 3,000,000 bytes"):
        decode_frame(_frame(0, header, bomb))
    header["arrays"][0].update(shape=[3, 50_000_000], raw_bytes=300_000_000)
    with pytest.raises(InputError, match="50,000,000 points: more than the 1,000,000-point limit") as big:
        decode_frame(_frame(0, header, bomb), max_points=1_000_000)
    assert big.value.status_code == 413
    header["arrays"][0].update(raw_bytes=12)
    with pytest.raises(InputError, match="stated as 12 bytes"):
        decode_frame(_frame(0, header, bomb))
    with pytest.raises(InputError, match="depth image of 217,088 px: more than the 1,000 px limit"):
        decode_frame(encode_frame(Sample(0.0, depth=np.ones((424, 512), np.float32)), None), max_pixels=1000)
