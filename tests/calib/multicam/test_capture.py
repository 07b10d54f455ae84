"""Synchronised multi-camera sets: matching frames by time, live capture from the demo rig's simulated cameras
(one board pose seen by both), refusals that store nothing, sets cut short, and a ROS 2 bag of two image topics
with dropped frames and jitter imported as sets."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer

from backend.calib.multicam import capture as multicam
from backend.core.errors import CancelledError, InputError
from backend.core.rig import Frame, Rig
from backend.devices.base import Sample
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.store.session import Session, SessionStore
from tests.devices.test_rosbag_source import T0_NS, TS, camera_info_msg, checkerboard, compressed_msg, header, image_msg

CAMERAS = ["cam_front", "cam_wide"]
HOLD_S = 2.0
"""Seconds the simulated board is held at each pose in the yard."""
N_POSES = 4
SMALL_BOARD = "checkerboard:7x7:0.04"
"""The board of :func:`test_rosbag_source.checkerboard` (8x8 squares: 7x7 inner corners), 360x360 px with border."""


def marked_board(mark: int) -> np.ndarray:
    """The small board with ``mark`` written into a 4x4 block of its white border, to tell frames apart."""
    image = checkerboard()
    image[:4, :4] = mark
    return image


def mark_of(image: np.ndarray) -> int:
    return int(image[1, 1] if image.ndim == 2 else image[1, 1, 0])


def fixed_reads(samples: dict[str, Sample]) -> dict[str, Callable[[], Sample]]:
    return {camera: (lambda s=sample: s) for camera, sample in samples.items()}


@pytest.fixture
def small_session(tmp_path: Path) -> Session:
    """Two cameras without intrinsics, and the small board."""
    rig = Rig()
    for camera in ("cam_a", "cam_b"):
        rig.add(Frame(camera, "base_link", kind="camera"))
    return SessionStore(tmp_path / "sessions").create("small", rig=rig, board=SMALL_BOARD)


@pytest.fixture
def demo_session(tmp_path: Path) -> Session:
    """The demo rig (true intrinsics), both cameras watching the board carried about the yard on one hold clock."""
    rig = demo_rig()
    for camera in CAMERAS:
        rig.get(camera).device = {"driver": "simulated", "camera": camera, "seed": 0, "board_motion": "scene",
                                  "n_poses": N_POSES, "board_hold_s": HOLD_S}
    return SessionStore(tmp_path / "sessions").create("multicam", rig=rig, board=DEMO_BOARD)


# --- matching by time -------------------------------------------------------------------------


def test_jittered_stamps_with_dropped_frames_match_moment_by_moment():
    # Three cameras at 10 Hz, each frame up to 6 ms off its moment; some frames dropped; c's list shuffled.
    rng = np.random.default_rng(3)
    dropped = {"a": {3}, "b": {5, 8}, "c": {5, 10}}
    moments = {cam: [k for k in range(12) if k not in dropped[cam]] for cam in "abc"}
    stamps = {cam: [100.0 + 0.1 * k + rng.uniform(-0.006, 0.006) for k in ks] for cam, ks in moments.items()}
    shuffle = rng.permutation(len(stamps["c"]))
    stamps["c"] = [stamps["c"][i] for i in shuffle]
    moments["c"] = [moments["c"][i] for i in shuffle]

    match = multicam.match_by_timestamp(stamps, 0.02)

    expected = []
    for k in range(12):
        present = {cam: moments[cam].index(k) for cam in "abc" if k in moments[cam]}
        if len(present) >= 2:
            expected.append(present)
    assert match.sets == expected
    assert len(match.sets) == 11  # moment 5 only a saw: no set
    assert match.sets[3] == {"b": 3, "c": moments["c"].index(3)}  # a dropped moment 3: a two-camera set
    assert match.unmatched == {"a": [moments["a"].index(5)], "b": [], "c": []}


def test_tolerance_edges():
    # inclusive at exactly the tolerance (binary-exact numbers), refused just beyond it
    assert multicam.match_by_timestamp({"a": [1.0], "b": [1.25]}, 0.25).sets == [{"a": 0, "b": 0}]
    beyond = multicam.match_by_timestamp({"a": [1.0], "b": [1.25]}, 0.2499)
    assert beyond.sets == [] and beyond.unmatched == {"a": [0], "b": [0]}
    # every frame of a set lies within the tolerance of every other: c is near b but too far from a
    chain = multicam.match_by_timestamp({"a": [0.0], "b": [0.25], "c": [0.5]}, 0.25)
    assert chain.sets == [{"a": 0, "b": 0}] and chain.unmatched == {"a": [], "b": [], "c": [0]}
    # at most one frame per camera: a's second frame inside the window stays out
    double = multicam.match_by_timestamp({"a": [0.0, 0.01], "b": [0.005]}, 0.02)
    assert double.sets == [{"a": 0, "b": 0}] and double.unmatched == {"a": [1], "b": []}
    # zero tolerance matches identical stamps only; a camera with no frames is fine
    exact = multicam.match_by_timestamp({"a": [2.0, 3.0], "b": [2.0, 3.0 + 1e-9], "c": []}, 0.0)
    assert exact.sets == [{"a": 0, "b": 0}] and exact.unmatched == {"a": [1], "b": [1], "c": []}
    for stamps, tolerance, words in [({"a": [0.0]}, 0.02, "at least two cameras"),
                                     ({"a": [0.0], "b": [0.0]}, -0.01, "0 s or more"),
                                     ({"a": [0.0], "b": [float("nan")]}, 0.02, "not finite")]:
        with pytest.raises(InputError, match=words):
            multicam.match_by_timestamp(stamps, tolerance)


# --- live capture -------------------------------------------------------------------------------


@pytest.mark.slow
def test_simulated_cameras_in_the_yard_capture_one_set_of_one_board_pose(demo_session):
    while time.time() % HOLD_S > 0.2:  # start at the beginning of a hold so both reads see one pose
        time.sleep(0.01)
    # Both cameras are read at once (a thread each), but a simulated camera stamps its frame after rendering the
    # yard (1-5 s for a new pose on 2 cores; the stamps were 0.01-0.26 s apart in 5 runs), so the tolerance is the
    # hold: the board is still for that long.
    captured = multicam.capture_set_from_devices(demo_session, CAMERAS, tolerance_s=HOLD_S, require_board=True)

    assert captured.name == "set00001" and captured.cameras == CAMERAS
    assert captured.cameras_with_board == CAMERAS
    front, wide = (captured.captures[c] for c in CAMERAS)
    for capture in (front, wide):
        assert capture.meta["multicam_set"] == "set00001"
        assert capture.meta["multicam_cameras"] == CAMERAS
        assert capture.meta["multicam_stamp_s"] == capture.timestamp_s
        assert len(capture.detection["ids"]) == 54  # every inner corner of the 9x6 board
        assert capture.image_size == (1280, 720) and capture.board == DEMO_BOARD
    assert front.meta["board_pose_index"] == wide.meta["board_pose_index"]
    assert abs(front.timestamp_s - wide.timestamp_s) < HOLD_S
    # the same physical board: its true poses in the two cameras differ exactly by the cameras' mounting
    T_front_wide = np.array(front.meta["T_camera_board"]) @ np.linalg.inv(np.array(wide.meta["T_camera_board"]))
    np.testing.assert_allclose(T_front_wide, demo_session.rig.T_a_b("cam_front", "cam_wide"), atol=1e-9)
    assert "simulated cam_front" in front.device and "simulated cam_wide" in front.device
    assert [s.name for s in multicam.stored_sets(demo_session)] == ["set00001"]
    assert multicam.stored_sets(demo_session)[0].captures == captured.captures


def test_cameras_without_a_working_device_are_named(demo_session):
    demo_session.set_device("cam_wide", {})
    with pytest.raises(InputError, match="no capture device configured") as info:
        multicam.capture_set_from_devices(demo_session, CAMERAS)
    assert info.value.input == "cam_wide"
    demo_session.set_device("cam_wide", {"driver": "simulated", "camera": "cam_nope"})
    with pytest.raises(InputError, match="no simulated camera named 'cam_nope'.*no set was stored") as info:
        multicam.capture_set_from_devices(demo_session, CAMERAS)
    assert info.value.input == "cam_wide"
    with pytest.raises(InputError, match="lidar3d, not a camera"):
        multicam.capture_set_from_devices(demo_session, ["cam_front", "lidar_top"])
    assert demo_session.captures("cam_front") == []


def test_a_late_camera_is_refused_naming_it_and_nothing_is_stored(demo_session):
    blank = np.full((720, 1280), 128, np.uint8)
    late = fixed_reads({"cam_front": Sample(50.0, image=blank), "cam_wide": Sample(50.035, image=blank)})
    with pytest.raises(InputError, match=r"later than cam_front's frame were cam_wide by 35\.0 ms \(tolerance "
                                         r"20\.0 ms\)") as info:
        multicam.capture_set(demo_session, CAMERAS, late, device="test")
    assert info.value.input == "cam_wide"
    assert demo_session.captures("cam_front") == [] and demo_session.captures("cam_wide") == []


def test_an_image_size_that_disagrees_with_the_intrinsics_is_refused_naming_the_camera(demo_session):
    reads = fixed_reads({"cam_front": Sample(1.0, image=np.zeros((720, 1280), np.uint8)),
                         "cam_wide": Sample(1.0, image=np.zeros((360, 640), np.uint8))})
    with pytest.raises(InputError, match="cam_wide: the image is 640x360 px but the camera's intrinsics are for "
                                         "1280x720") as info:
        multicam.capture_set(demo_session, CAMERAS, reads, device="test")
    assert info.value.input == "cam_wide"
    assert demo_session.captures("cam_front") == [] and demo_session.captures("cam_wide") == []


@pytest.mark.slow
def test_sets_are_numbered_in_order_and_a_set_cut_short_is_never_listed(small_session, monkeypatch):
    blank = np.full((360, 360), 255, np.uint8)
    # 19.5 ms apart is within the default 20 ms; a camera that does not see the board is kept without a detection
    one_view = multicam.capture_set(small_session, ["cam_a", "cam_b"], fixed_reads(
        {"cam_a": Sample(1.0, image=marked_board(1)), "cam_b": Sample(1.0195, image=blank)}), device="test")
    assert one_view.cameras_with_board == ["cam_a"] and one_view.captures["cam_b"].detection is None
    assert one_view.captures["cam_b"].meta["multicam_stamp_s"] == 1.0195
    with pytest.raises(InputError, match=r"found by 0 of 2 cameras \(none\); a set needs it in view of at least 2"):
        multicam.capture_set(small_session, ["cam_a", "cam_b"], fixed_reads(
            {"cam_a": Sample(2.0, image=blank), "cam_b": Sample(2.0, image=blank)}), device="test", require_board=True)
    with pytest.raises(InputError, match=r"found by 1 of 2 cameras \(cam_a\)") as info:
        multicam.capture_set(small_session, ["cam_a", "cam_b"], fixed_reads(
            {"cam_a": Sample(2.0, image=marked_board(2)), "cam_b": Sample(2.0, image=blank)}), device="test",
            require_board=True)
    assert info.value.input == "cam_b"
    both = [multicam.capture_set(small_session, ["cam_b", "cam_a"], fixed_reads(
        {"cam_a": Sample(t, image=marked_board(t)), "cam_b": Sample(t, image=marked_board(t))}), device="test",
        require_board=True) for t in (3, 4)]
    assert [s.name for s in both] == ["set00002", "set00003"] and both[0].cameras == ["cam_b", "cam_a"]

    # the disk fails while the second camera of a set is written: its first capture stays, unlisted
    add_capture = small_session.add_capture

    def failing(sensor, image, record):
        if sensor == "cam_a":
            raise OSError("disk full")
        return add_capture(sensor, image, record)

    monkeypatch.setattr(small_session, "add_capture", failing)
    with pytest.raises(OSError):
        multicam.capture_set(small_session, ["cam_b", "cam_a"], fixed_reads(
            {"cam_a": Sample(5.0, image=marked_board(5)), "cam_b": Sample(5.0, image=marked_board(5))}),
            device="test")
    monkeypatch.undo()
    assert small_session.captures("cam_b")[-1].meta["multicam_set"] == "set00004"
    last = multicam.capture_set(small_session, ["cam_a", "cam_b"], fixed_reads(
        {"cam_a": Sample(6.0, image=marked_board(6)), "cam_b": Sample(6.0, image=marked_board(6))}), device="test")
    assert last.name == "set00005"  # the remnant's name is not reused
    listed = multicam.stored_sets(small_session)
    assert [s.name for s in listed] == ["set00001", "set00002", "set00003", "set00005"]
    assert [mark_of(small_session.capture_image("cam_b", s.captures["cam_b"].id)) for s in listed[1:]] == [3, 4, 6]
    assert multicam.stored_sets(small_session, ["cam_a", "cam_b"]) == listed


# --- a ROS 2 bag --------------------------------------------------------------------------------

JITTER_A = np.random.default_rng(11).uniform(-0.006, 0.006, 12)
JITTER_B = np.random.default_rng(12).uniform(-0.006, 0.006, 12)
DROPPED_A, DROPPED_B = {3, 8}, {5}
EXTRA_B = 9.5
"""cam_b has one frame halfway between moments 9 and 10, which no cam_a frame is near."""
ZERO_STAMP_B = 7
"""cam_b's frame of moment 7 has a zero header stamp (the receive time stands in)."""
LATENCY_NS = 2_000_000


def ns(t_s: float) -> int:
    return T0_NS + round(t_s * 1e9)


def write_two_camera_bag(path: Path) -> Path:
    """Moments k = 0..11, 0.1 s apart: cam_a (mono8 Image) and cam_b (PNG CompressedImage) each show the small
    board marked with k (99 on cam_b's extra frame), stamped with jitter and received 2 ms later."""
    frames_a = [(0.1 * k + JITTER_A[k], k) for k in range(12) if k not in DROPPED_A]
    frames_b = sorted([(0.1 * k + JITTER_B[k], k) for k in range(12) if k not in DROPPED_B] + [(0.1 * EXTRA_B, 99)])
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        cam_a = writer.add_connection("/cam_a/image", "sensor_msgs/msg/Image", typestore=TS)
        cam_b = writer.add_connection("/cam_b/compressed", "sensor_msgs/msg/CompressedImage", typestore=TS)
        info = writer.add_connection("/cam_a/info", "sensor_msgs/msg/CameraInfo", typestore=TS)
        for t, k in frames_a:
            msg = image_msg(0, marked_board(k), "mono8")
            msg.header = header(ns(t), "cam_a_optical")
            writer.write(cam_a, ns(t) + LATENCY_NS, TS.serialize_cdr(msg, "sensor_msgs/msg/Image"))
        for t, k in frames_b:
            msg = compressed_msg(0, cv2.imencode(".png", marked_board(k))[1])
            stamp_ns = 0 if k == ZERO_STAMP_B else ns(t)
            msg.header = header(stamp_ns, "cam_b_optical")
            receive_ns = ns(t) if k == ZERO_STAMP_B else ns(t) + LATENCY_NS
            writer.write(cam_b, receive_ns, TS.serialize_cdr(msg, "sensor_msgs/msg/CompressedImage"))
        writer.write(info, ns(0.0), TS.serialize_cdr(camera_info_msg(ns(0.0)), "sensor_msgs/msg/CameraInfo"))
    return path


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_two_camera_bag(tmp_path_factory.mktemp("bags") / "two_cameras")


TOPICS = {"cam_a": "/cam_a/image", "cam_b": "/cam_b/compressed"}


@pytest.mark.slow
def test_a_bag_of_two_image_topics_imports_the_matched_sets(bag, small_session):
    messages: list[str] = []
    report = multicam.import_bag_sets(small_session, bag, TOPICS, progress=lambda f, m: messages.append(m))

    moments = [k for k in range(12) if k not in DROPPED_A | DROPPED_B]  # 0 1 2 4 6 7 9 10 11
    assert report.matched_sets == 9 and report.no_board == 0
    assert report.sets == [f"set{n:05d}" for n in range(1, 10)]
    a, b = report.cameras["cam_a"], report.cameras["cam_b"]
    assert (a.read, a.matched, a.unmatched, a.stored) == (10, 9, [4], 9)  # #4 is moment 5, which cam_b dropped
    assert (b.read, b.matched, b.unmatched, b.stored) == (12, 9, [3, 7, 9], 9)  # moments 3 and 8, the extra frame
    assert report.to_dict()["cameras"]["cam_b"]["unmatched"] == 3 and messages[-1].startswith("9 sets imported")

    sets = multicam.stored_sets(small_session)
    assert [s.name for s in sets] == report.sets
    for k, found in zip(moments, sets, strict=True):
        assert [mark_of(small_session.capture_image(c, found.captures[c].id)) for c in ("cam_a", "cam_b")] == [k, k]
        assert found.cameras_with_board == ["cam_a", "cam_b"]
        assert len(found.captures["cam_a"].detection["ids"]) == 49
        stamp_a = found.captures["cam_a"].meta["multicam_stamp_s"]
        assert stamp_a == pytest.approx(ns(0.1 * k + JITTER_A[k]) * 1e-9, abs=1e-6)  # float64 at 1.7e9 s
        assert abs(found.captures["cam_b"].meta["multicam_stamp_s"] - stamp_a) < 0.012
        assert found.captures["cam_a"].source.startswith("/cam_a/image #")
    zero = sets[moments.index(ZERO_STAMP_B)].captures["cam_b"]
    assert zero.meta["stamp_s"] == 0.0 and zero.meta["multicam_stamp_s"] == zero.meta["bag_time_s"]

    # every 2nd matched set (moments 0 2 6 9 11), at most 3
    again = multicam.import_bag_sets(small_session, bag, TOPICS, every=2, limit=3)
    assert again.sets == ["set00010", "set00011", "set00012"] and "limit of 3 sets" in again.ended
    assert [mark_of(small_session.capture_image("cam_a", s.captures["cam_a"].id))
            for s in multicam.stored_sets(small_session)[9:]] == [0, 2, 6]

    # cancelling lands between sets and keeps the sets stored before it
    before = len(multicam.stored_sets(small_session))
    with pytest.raises(CancelledError, match="cancelled after 2 sets"):
        multicam.import_bag_sets(small_session, bag, TOPICS,
                                 cancelled=lambda: len(multicam.stored_sets(small_session)) >= before + 2)
    assert len(multicam.stored_sets(small_session)) == before + 2


def test_bad_bag_input_names_the_bag_and_topic_and_stores_nothing(bag, small_session, tmp_path):
    with pytest.raises(InputError) as info:
        multicam.import_bag_sets(small_session, bag, {"cam_a": "/cam_a/image", "cam_b": "/cam_b/image_raw"})
    message = info.value.message
    assert message.startswith("cam_b (/cam_b/image_raw): bag ") and str(bag) in message
    assert ("available topics: /cam_a/image (sensor_msgs/msg/Image), /cam_a/info (sensor_msgs/msg/CameraInfo), "
            "/cam_b/compressed (sensor_msgs/msg/CompressedImage)") in message
    with pytest.raises(InputError, match="topic '/cam_a/info' in bag .* holds sensor_msgs/msg/CameraInfo, not images"):
        multicam.import_bag_sets(small_session, bag, {"cam_a": "/cam_a/info", "cam_b": "/cam_b/compressed"})

    cut = write_two_camera_bag(tmp_path / "cut")
    (storage,) = cut.glob("*.mcap")
    storage.write_bytes(storage.read_bytes()[: storage.stat().st_size // 2])
    with pytest.raises(InputError, match="truncated or corrupt") as info:
        multicam.import_bag_sets(small_session, cut, TOPICS)
    assert info.value.input == str(cut) and str(cut) in info.value.message

    small_session.rig.get("cam_b").intrinsics = demo_rig().get("cam_front").intrinsics  # 1280x720, the bag: 360
    with pytest.raises(InputError, match="cam_b: the image is 360x360 px but the camera's intrinsics are for 1280x720"):
        multicam.import_bag_sets(small_session, bag, TOPICS)
    assert small_session.captures("cam_a") == [] and small_session.captures("cam_b") == []
