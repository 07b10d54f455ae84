"""Step 10 with a LiDAR: its captures of the rig turned in the simulated yard and an uploaded IMU recording (15 ms
apart) solved as a job, shown (the offset, the card, the IMU's excitation) and accepted, which sets the IMU's clock
offset; without the IMU's file the solve is refused with a toast."""

from __future__ import annotations

import re
from types import SimpleNamespace

import pytest
from scipy.spatial.transform import Rotation

from backend.core.rig import Frame, Rig
from backend.core.transforms import make_T
from backend.devices.imu_csv import format_imu_csv
from backend.plots.camera_imu import excitation_bars
from backend.plots.render import to_rgb
from backend.sim.lidar_imu import R_LIDAR_IMU, simulate_lidar_imu
from backend.store.session import SessionStore
from tests.conftest import poll
from tests.studio.in_process import in_process_studio


def test_the_step_solves_a_lidar_against_an_imu(tmp_path, free_port) -> None:
    recording = simulate_lidar_imu(duration_s=8.0, offset_s=0.015, seed=2)
    rig = Rig()
    rig.add(Frame("cam0", "base_link", kind="camera"))
    rig.add(Frame("lidar", "base_link", kind="lidar3d"))
    rig.add(Frame("imu", "lidar", make_T(R_LIDAR_IMU @ Rotation.from_euler("z", 3, degrees=True).as_matrix(),
                                         [0.05, 0, -0.08]), kind="imu"))
    store = SessionStore(tmp_path / "sessions")
    session = store.create("rig", rig=rig)
    for t_s, points in zip(recording.scan_times_s, recording.scans, strict=True):
        session.add_cloud_capture("lidar", points, None, {"timestamp_s": float(t_s), "device": "sim"})
    with in_process_studio(store, session, free_port) as (app, notes):
        step = app.camera_imu_step
        assert step.camera.options == ("cam0", "lidar") and step.imu.value == "imu"
        step.camera.value = "lidar"
        step._solve()
        assert notes[-1][0] == "Recording missing" and "the LiDAR's scans are its captures" in notes[-1][1], notes

        step._keep("imu", SimpleNamespace(name="imu.csv", content=format_imu_csv(recording.imu)))
        empty = to_rgb(excitation_bars(None))
        step._solve()
        poll(lambda: step.history.selected is not None and (
            step.excitation_image.image.shape != empty.shape or (step.excitation_image.image != empty).mean() > 0.05),
             lambda: f"no result drawn: {step.jobs.text.content}", 120)
        offset = re.search(r"Time offset \*\*(-?\d+\.\d+) ms\*\* ± (\d+\.\d+) \(t_imu = t_lidar",
                           step.offset_text.content)
        assert offset and abs(float(offset.group(1)) - 15.0) < 2.0, step.offset_text.content
        assert "lidar_imu · rates" in step.card.text.content and "**lidar → imu**" in step.card.text.content

        step.card.confirm.checkbox.value = True  # needed if the verdict is check
        step.card.preview()
        step.card.accept()
        assert session.rig.get("imu").clock_offset_s == pytest.approx(float(offset.group(1)) / 1e3, abs=1e-5)
