"""Recording an IMU live in step 10, through the VN-100's byte-level simulator on a pty: the excitation bars are
drawn from the growing run, the samples are stored as 2 s captures as they come, and on *Stop* the run becomes the
step's IMU file, equal to what the captures hold."""

from __future__ import annotations

import numpy as np

from backend.core.rig import Frame, Rig
from backend.devices.imu_csv import parse_imu_csv
from backend.devices.rosbag_source import read_imu_topic, typestore
from backend.plots.camera_imu import excitation_bars
from backend.plots.render import to_rgb
from backend.store.session import SessionStore
from tests.conftest import poll
from tests.devices.test_rosbag_imu_livox import imu_msgs, imu_stamps, write_bag
from tests.studio.in_process import in_process_studio


def test_a_live_run_is_shown_stored_and_becomes_the_imu_file(tmp_path, free_port) -> None:
    rig = Rig()
    rig.add(Frame("cam0", "base_link", kind="camera"))
    rig.add(Frame("imu0", "base_link", kind="imu", device={"driver": "vn100", "port": "sim"}))
    store = SessionStore(tmp_path / "sessions")
    session = store.create("rig", rig=rig)
    with in_process_studio(store, session, free_port) as (app, notes):
        step = app.camera_imu_step
        empty = to_rgb(excitation_bars(None))
        step._record()
        assert step.stop_button.visible and not step.record_button.visible
        recorder = step.recorder
        poll(lambda: len(session.captures("imu0")) >= 1, lambda: f"no IMU capture stored: {step.live_text.content}",
             60)
        poll(lambda: step.excitation_image.image.shape != empty.shape or (step.excitation_image.image != empty)
             .mean() > 0.05, lambda: f"no excitation drawn: {step.live_text.content}", 60)
        assert step.live_text.content.startswith("Recording "), step.live_text.content
        motion = recorder.excitation()
        assert (motion.rate_rms_rad_s > 0.3).all() and (motion.accel_std_m_s2 > 0.5).all(), motion  # the sim's sines

        step._stop_recording()
        assert step.record_button.visible and step.recorder is None and not recorder.running
        name, data = step._files["imu"]
        assert name == f"imu0 {recorder.run}.csv" and "Recorded " in step.live_text.content, step.live_text.content
        recorded, _ = parse_imu_csv(data, name)
        captures = session.captures("imu0")
        assert all(c.meta["imu_run"] == recorder.run for c in captures) and captures[0].n_imu_samples > 300
        stored = [session.imu_capture("imu0", c.id) for c in captures]
        stored_t = np.concatenate([s.t_s for s in stored])
        assert len(stored_t) == len(recorded.t_s) and np.allclose(stored_t, recorded.t_s, atol=1e-9)
        assert np.allclose(np.vstack([s.gyro_rad_s for s in stored]), recorded.gyro_rad_s, atol=1e-6)


def test_an_imu_bag_replays_into_the_step(tmp_path, free_port) -> None:
    """An IMU whose device replays a bag's sensor_msgs/Imu topic: the run ends with the bag, by itself, and becomes
    the step's IMU file, holding every message of the topic."""
    ts = typestore(True)
    bag = write_bag(tmp_path / "imu.bag", {"/imu0": ("sensor_msgs/msg/Imu", imu_msgs(ts, imu_stamps()))}, True,
                    {"/imu0": imu_stamps()})
    rig = Rig()
    rig.add(Frame("imu0", "base_link", kind="imu", device={"driver": "rosbag", "path": str(bag), "topic": "/imu0"}))
    store = SessionStore(tmp_path / "sessions")
    session = store.create("rig", rig=rig)
    with in_process_studio(store, session, free_port) as (app, _):
        step = app.camera_imu_step
        step._record()
        poll(lambda: step.recorder is None and step.record_button.visible,
             lambda: f"the run did not end with the bag: {step.live_text.content}", 60)
        recorded, _ = parse_imu_csv(*reversed(step._files["imu"]))
        expected, _ = read_imu_topic(bag, "/imu0")
        assert np.allclose(recorded.t_s, expected.t_s, atol=1e-9) and np.allclose(recorded.gyro_rad_s,
                                                                                   expected.gyro_rad_s, atol=1e-6)
        assert sum(c.n_imu_samples for c in session.captures("imu0")) == len(expected.t_s)
