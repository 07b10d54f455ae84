"""Live clouds from the simulated LiDARs: frames arrive, accumulation stays bounded, a disconnect is reported;
and the studio's cloud colouring is fast enough for 100k points at 10 Hz."""

from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest

from backend.calib._session import store_cloud
from backend.core.colour_maps import distance_colours
from backend.core.voxels import voxel_downsample
from backend.devices.base import create_device
from backend.plots.lidar_lidar import c2c_histogram
from backend.plots.render import to_rgb
from backend.services.live_clouds import CloudCallbacks, LiveClouds
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.sim.ydlidar_sim import YdlidarSimulator
from backend.store.session import SessionStore
from studio import cloud_colours as cc
from studio.wizard.lidar_step import wire_faults
from tests.conftest import UI_WAIT_S, poll


class Recorder:
    def __init__(self):
        self.sizes: list[int] = []
        self.statuses: list[tuple[str, bool]] = []
        self.failed = threading.Event()
        self.got = threading.Condition()

    def callbacks(self) -> CloudCallbacks:
        return CloudCallbacks(frame=self._frame, status=self._status)

    def _frame(self, sensor, points, intensity) -> None:
        assert points.ndim == 2 and points.shape[1] == 3
        assert intensity is None or len(intensity) == len(points)
        with self.got:
            self.sizes.append(len(points))
            self.got.notify_all()

    def _status(self, message: str, error: bool) -> None:
        self.statuses.append((message, error))
        if error:
            self.failed.set()

    def wait_frames(self, n: int, timeout_s: float = UI_WAIT_S) -> None:
        with self.got:
            assert self.got.wait_for(lambda: len(self.sizes) >= n, timeout_s), f"only {len(self.sizes)} frames"


def make_session(tmp_path, **device):
    rig = demo_rig()
    rig.get("lidar_top").device = {"driver": "simulated_lidar", "sensor": "lidar_top", "seed": 1, **device}
    return SessionStore(tmp_path).create("clouds", rig=rig, board=DEMO_BOARD)


def test_voxel_downsample_keeps_one_centroid_per_voxel():
    rng = np.random.default_rng(0)
    points = rng.uniform(0.0, 1.0, (20_000, 3))
    intensity = rng.uniform(0, 255, 20_000).astype(np.float32)
    merged, merged_intensity = voxel_downsample(points, intensity, 0.25)
    assert len(merged) == 64 and len(merged_intensity) == 64  # 4 x 4 x 4 voxels, all occupied
    cells = np.floor(merged / 0.25)
    assert len(np.unique(cells, axis=0)) == 64  # each centroid lies in its own voxel
    np.testing.assert_allclose(np.sort(merged[:, 0])[::16], [0.125, 0.375, 0.625, 0.875], atol=0.02)
    negative, _ = voxel_downsample(points - 5.0, None, 0.25)  # negative coordinates hash apart too
    assert len(negative) == 64


@pytest.mark.slow
def test_live_thread_streams_and_accumulation_is_bounded(tmp_path):
    session = make_session(tmp_path)
    recorder = Recorder()
    live = LiveClouds(session, "lidar_top", recorder.callbacks(), accumulate=1, voxel_m=0.1, max_hz=50)
    live.start()
    try:
        recorder.wait_frames(3)
        single = recorder.sizes[-1]
        assert single > 10_000  # a 16-beam scan of the yard
        assert live.latest is not None and len(live.latest.points) == single
        live.accumulate = 8
        start = len(recorder.sizes)
        recorder.wait_frames(start + 12)
        accumulated = recorder.sizes[-4:]
        points, _ = live.accumulated()
        # The voxel map of 8 scans is bounded by the occupied voxels, far below 8 raw scans.
        assert max(accumulated) < 8 * single / 2, (single, accumulated)
        assert len(np.unique(np.floor(points / 0.1), axis=0)) == len(points)
        assert not recorder.failed.is_set(), recorder.statuses
        assert live.rate_hz > 0  # it streams (rates are measured in benchmarks/live_clouds.py)
        # What "Capture clouds" stores: the first full scan read after the click, not the voxel map.
        seen = live.latest
        sample = live.scan_after(seen, UI_WAIT_S)
        assert sample is not None and sample is not seen and sample.timestamp_s > seen.timestamp_s
        record = store_cloud(session, "lidar_top", sample, device=live.device_name)
        assert record.n_points == len(sample.points)
    finally:
        live.stop()
    assert not live.running
    assert live.scan_after(live.latest, 0.2) is None  # stopped: no newer scan comes, and the wait ends


def test_disconnect_is_reported_and_captures_kept(tmp_path):
    session = make_session(tmp_path, disconnect_after=4)
    recorder = Recorder()
    live = LiveClouds(session, "lidar_top", recorder.callbacks(), max_hz=50)
    live.start()
    recorder.wait_frames(1)
    store_cloud(session, "lidar_top", live.latest, device=live.device_name)
    assert recorder.failed.wait(30), "the disconnect was never reported"
    live.stop()
    assert not live.running
    message = next(m for m, error in recorder.statuses if error)
    assert message.startswith("lidar_top:") and "after 4" in message
    assert "the 1 cloud(s) captured so far are kept" in message
    assert len(recorder.sizes) == 4
    assert live.latest is not None  # the last scan survives the disconnect


def test_bad_device_settings_are_reported(tmp_path):
    session = make_session(tmp_path, sensor="no_such_lidar")
    recorder = Recorder()
    live = LiveClouds(session, "lidar_top", recorder.callbacks())
    live.start()
    assert recorder.failed.wait(10)
    live.stop()
    assert "no_such_lidar" in recorder.statuses[-1][0] and recorder.sizes == []


def test_a_device_that_breaks_as_it_opens_is_reported(tmp_path, monkeypatch):
    """Not only a DeviceError: any failure to open ends the stream with a message (and the live buttons come back)."""
    session = make_session(tmp_path)
    recorder = Recorder()
    live = LiveClouds(session, "lidar_top", recorder.callbacks())
    monkeypatch.setattr(live, "_open", lambda: {}["no such setting"])
    live.start()
    assert recorder.failed.wait(10)
    live.stop()
    assert not live.running and recorder.sizes == []
    assert recorder.statuses[-1][0] == "lidar_top: the device could not be opened: KeyError('no such setting')"


def test_colour_modes_range_window_and_distance_colours_of_100k_points():
    """Range window, display subset and every colour mode for 100k points (their speed: benchmarks/live_clouds.py)."""
    rng = np.random.default_rng(1)
    points = rng.normal(0.0, 6.0, (100_000, 3))
    intensity = rng.uniform(0, 255, 100_000).astype(np.float32)
    T = np.eye(4)
    T[2, 3] = 0.8
    for mode in cc.COLOUR_MODES:
        colours = cc.colour_points(mode, points, intensity, T, 1)
        assert colours.shape == ((3,) if mode == "sensor" else (100_000, 3)) and colours.dtype == np.uint8
    assert tuple(cc.colour_points("sensor", points, intensity, T, 1)) == cc.sensor_colour(1)
    assert tuple(cc.colour_points("intensity", points, None, T, 2)) == cc.sensor_colour(2)  # no intensity
    assert len(np.unique(cc.colour_points("height", points, intensity, T, 0), axis=0)) > 50
    kept, kept_intensity = cc.range_window(points, intensity, 1.0, 15.0)
    kept, kept_intensity = cc.display_subset(kept, kept_intensity, 100_000)
    assert len(kept) == len(kept_intensity) > 0
    r = np.linalg.norm(kept, axis=1)
    assert r.min() >= 1.0 and r.max() <= 15.0
    d = np.array([0.0, 0.1, 0.2, 0.5, np.inf])
    colours = distance_colours(d, 0.2)
    assert tuple(colours[3]) == tuple(colours[4]) == (230, 40, 40) and tuple(colours[0]) != tuple(colours[2])
    histogram = to_rgb(c2c_histogram(rng.uniform(0, 0.2, 1000), 0.2))
    assert histogram.shape[1] == 480 and histogram.std() > 10


def test_serial_lidar_unplugged_live_shows_reconnecting_and_resumes(tmp_path):
    """A YDLiDAR (its pty simulator) pulled out mid-stream: the stream says it is reconnecting while no scans
    come, scans resume when it is back, and the cloud captured before stays stored."""
    rig = demo_rig()
    rig.get("scanner_2d").device = {"driver": "ydlidar", "port": "sim", "reconnect_timeout_s": 10.0}
    session = SessionStore(tmp_path).create("serial", rig=rig, board=DEMO_BOARD)
    recorder = Recorder()
    live = LiveClouds(session, "scanner_2d", recorder.callbacks(), max_hz=50)
    live.start()
    try:
        recorder.wait_frames(3)
        kept = store_cloud(session, "scanner_2d", live.latest, device=live.device_name)
        assert live.device_status == "streaming" and live.device_name == "ydlidar sim @512000"
        simulator = live.device.simulator
        simulator.unplug()
        poll(lambda: "reconnecting" in (live.device_status or ""), lambda: f"status stayed {live.device_status!r}",
             interval_s=0.05)
        frames_while_out = len(recorder.sizes)
        time.sleep(0.5)  # not a wait: the window in which no frame may arrive (a slower machine only widens it)
        assert len(recorder.sizes) <= frames_while_out + 1  # at most the scan that was already parsed
        simulator.replug()
        recorder.wait_frames(frames_while_out + 3)
        assert live.device_status == "streaming" and live.running and not recorder.failed.is_set()
        assert live.latest.meta["reconnects"] == 1
    finally:
        live.stop()
    points, _ = session.capture_cloud("scanner_2d", kept.id)
    assert len(points) == kept.n_points > 1000


def test_live_clouds_are_padded_to_a_stable_length_with_the_same_points():
    rng = np.random.default_rng(2)
    for n in (1, 4095, 4096, 28_429):
        points, intensity = rng.normal(size=(n, 3)), rng.uniform(0, 1, n).astype(np.float32)
        padded, padded_intensity = cc.padded_to_bucket(points, intensity, 4096)
        assert len(padded) % 4096 == 0 and len(padded) - n < 4096 and len(padded_intensity) == len(padded)
        np.testing.assert_array_equal(padded[:n], points)  # the scan itself, then repeats of it
        assert np.unique(padded, axis=0).shape == np.unique(points, axis=0).shape
    empty = np.zeros((0, 3))
    assert cc.padded_to_bucket(empty, None, 4096)[0] is empty


def test_the_live_line_names_what_the_wire_spoiled():
    """The drivers' fault counters (YDLiDAR checksums and stray bytes, Velodyne malformed datagrams) reach the
    studio's live line under the names the studio reads."""
    with YdlidarSimulator(garbage_every=5, garbage_len=31, corrupt_every=17, seed=1) as sim:
        with create_device({"driver": "ydlidar", "port": sim.port}) as device:
            meta = [device.read() for _ in range(3)][-1].meta
    assert re.fullmatch(r" \(\d+ bad packets and [\d,]+ stray bytes skipped\)", wire_faults(meta))
    with create_device({"driver": "velodyne", "host": "sim"}) as device:
        device.simulator.garbage_every = 10
        meta = [device.read() for _ in range(3)][-1].meta
    assert re.fullmatch(r" \([\d,]+ bad packets skipped\)", wire_faults(meta)), meta["malformed"]
    assert wire_faults({"bad_checksums": 0, "skipped_bytes": 0}) == ""
