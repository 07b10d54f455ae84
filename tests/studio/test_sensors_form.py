"""The sensors step's form: every capture driver can be picked, and what the form builds opens the device.

The simulated serial and network sensors are opened and read through the settings the form
produces (a pty for the YDLiDAR and the Dynamixel servo, UDP on 127.0.0.1 for the Velodyne).
"""

from __future__ import annotations

import numpy as np
import pytest
import viser

from backend.core.errors import InputError
from backend.devices.base import create_device, driver_names
from backend.services.jobs import JobRunner
from backend.store.session import SessionStore
from studio.context import StudioContext
from studio.scene import RigScene
from studio.wizard.sensors_step import (
    DRIVERS,
    RANGE_KINDS,
    DeviceForm,
    SensorsStep,
    device_form,
    device_settings,
    drivers_for,
)


def test_every_registered_driver_is_offered_for_the_kinds_it_captures():
    assert sorted(DRIVERS) == driver_names()
    assert drivers_for("camera") == ["uvc", "folder", "simulated", "rosbag", "node"]
    range_drivers = {"simulated_lidar", "velodyne", "velodyne_pcap", "livox", "ydlidar", "hokuyo", "swept_scanner",
                     "cloud_files", "lvx", "rosbag", "node"}
    for kind in RANGE_KINDS:
        depth_drivers = {"kinect2", "realsense", "depth_files", "sim_depth"} if kind == "depth" else set()
        assert set(drivers_for(kind)) == range_drivers | depth_drivers
    assert drivers_for("imu") == ["vn100", "lvx", "rosbag"] and drivers_for("frame") == []


def test_settings_from_the_form(tmp_path):
    bag = tmp_path / "run.mcap"
    bag.write_bytes(b"")
    assert device_settings("uvc", "0", width=1280, height=720) == {
        "driver": "uvc", "device": 0, "width": 1280, "height": 720}
    assert device_settings("uvc", "/dev/video2")["device"] == "/dev/video2"
    assert device_settings("simulated_lidar", "")["sensor"] == "lidar_top"
    assert device_settings("velodyne", "sim") == {"driver": "velodyne", "host": "sim"}
    assert device_settings("velodyne", "2368") == {"driver": "velodyne", "host": "0.0.0.0", "port": 2368}
    assert device_settings("velodyne", "192.168.1.77:2369") == {"driver": "velodyne", "host": "192.168.1.77",
                                                                "port": 2369}
    assert device_settings("ydlidar", "/dev/ttyUSB0") == {"driver": "ydlidar", "port": "/dev/ttyUSB0"}
    assert device_settings("hokuyo", "") == {"driver": "hokuyo", "host": "sim"}
    assert device_settings("hokuyo", "192.168.0.10") == {"driver": "hokuyo", "host": "192.168.0.10"}
    assert device_settings("hokuyo", "10.0.0.7:10941") == {"driver": "hokuyo", "host": "10.0.0.7", "port": 10941}
    assert device_settings("hokuyo", "/dev/ttyACM0") == {"driver": "hokuyo", "serial_port": "/dev/ttyACM0"}
    assert device_settings("kinect2", "") == {"driver": "kinect2", "serial": None}
    assert device_settings("realsense", " 123 ") == {"driver": "realsense", "serial": "123"}
    assert device_settings("sim_depth", "sn4") == {"driver": "sim_depth", "node": "sn4", "seed": 0}
    assert device_settings("node", "sn2") == {"driver": "node", "node": "sn2"}
    assert device_settings("swept_scanner", "sim") == {"driver": "swept_scanner", "servo_port": "sim",
                                                       "scanner": {"driver": "sim"}}
    assert device_settings("swept_scanner", "/dev/ttyUSB1", scanner_port="/dev/ttyUSB0") == {
        "driver": "swept_scanner", "servo_port": "/dev/ttyUSB1",
        "scanner": {"driver": "ydlidar", "port": "/dev/ttyUSB0"}}
    assert device_settings("rosbag", str(bag), topic=" /points ") == {"driver": "rosbag", "path": str(bag),
                                                                      "topic": "/points"}
    assert device_settings("cloud_files", str(tmp_path)) == {"driver": "cloud_files", "path": str(tmp_path)}


def test_a_sensors_device_reads_back_into_the_form(tmp_path):
    """Editing a sensor shows its device in the form's fields, and those fields give the same settings back."""
    bag = tmp_path / "run.mcap"
    bag.write_bytes(b"")
    forms = [DeviceForm("uvc", "/dev/video2", 1280, 720), DeviceForm("simulated", "cam_wide"),
             DeviceForm("simulated_lidar", "scanner_2d"), DeviceForm("velodyne", "sim"),
             DeviceForm("velodyne", "2368"), DeviceForm("velodyne", "192.168.1.77:2369"),
             DeviceForm("ydlidar", "/dev/ttyUSB0"), DeviceForm("vn100", "/dev/ttyUSB3"),
             DeviceForm("hokuyo", "sim"), DeviceForm("hokuyo", "192.168.0.10"),
             DeviceForm("hokuyo", "10.0.0.7:10941"), DeviceForm("hokuyo", "/dev/ttyACM0"),
             DeviceForm("kinect2", "0123"), DeviceForm("realsense", ""),
             DeviceForm("sim_depth", "sn4"), DeviceForm("node", "sn2"), DeviceForm("swept_scanner", "sim"),
             DeviceForm("swept_scanner", "/dev/ttyUSB1", scanner_port="/dev/ttyUSB0"),
             DeviceForm("rosbag", str(bag), topic="/points", time_window_s=(1.0, 2.5)),
             DeviceForm("cloud_files", str(tmp_path)), DeviceForm("lvx", str(bag)), DeviceForm("livox", "sim"),
             DeviceForm("livox", "192.168.1.12"), DeviceForm("livox", "1PQDH5B00100041"), DeviceForm("livox", "")]
    assert {form.driver for form in forms} >= set(DRIVERS) - {"folder", "velodyne_pcap", "depth_files"}
    for form in forms:
        settings = form.settings()
        assert device_form(settings).settings() == settings, form
    assert device_form({"driver": "a_driver_of_a_newer_studio"}) is None


@pytest.mark.parametrize(("driver", "source", "extra", "field", "message"), [
    ("rosbag", "BAG", {}, "topic", "needs its topic"),
    ("cloud_files", "", {}, "source", "needs a path"),
    ("velodyne_pcap", "/no/such/run.pcap", {}, "source", "/no/such/run.pcap does not exist"),
    ("velodyne", "70000", {}, "source", "must be a UDP port"),
    ("velodyne", "lidar:abc", {}, "source", "must be a UDP port"),
    ("hokuyo", "10.0.0.7:port", {}, "source", "must be HOST, HOST:PORT"),
    ("swept_scanner", "/dev/ttyUSB1", {"scanner_port": ""}, "scanner_port", "real 2D scanner's serial port"),
    ("node", " ", {}, "source", "needs the name its agent was started with"),
    ("nonsense", "x", {}, "device", "unknown device"),
])
def test_bad_form_input_names_the_field(tmp_path, driver, source, extra, field, message):
    bag = tmp_path / "run.db3"
    bag.write_bytes(b"")
    with pytest.raises(InputError, match=message) as info:
        device_settings(driver, source.replace("BAG", str(bag)), **extra)
    assert info.value.input == field


@pytest.mark.parametrize("driver", ["simulated_lidar", "velodyne", "ydlidar", "hokuyo"])
def test_the_simulated_range_sensors_open_from_the_form(driver):
    with create_device(device_settings(driver, DRIVERS[driver].default_source)) as device:
        sample = device.read()
    assert sample.points is not None and len(sample.points) > 1000 and np.isfinite(sample.points).all()


def test_the_simulated_imu_opens_from_the_form():
    with create_device(device_settings("vn100", DRIVERS["vn100"].default_source)) as device:
        sample = device.read()
    assert sample.imu is not None and len(sample.imu.t_s) >= 15 and np.isfinite(sample.imu.gyro_rad_s).all()


def test_a_typed_source_outlives_the_device_choice(tmp_path, free_port):
    """Picking a device puts its example source in the box, but never over what the user typed: on a busy server
    the device's update can land after the user has typed the path."""
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    jobs = JobRunner()
    try:
        step = SensorsStep(StudioContext(server, SessionStore(tmp_path), jobs, RigScene(server)))
        step.kind.value = "lidar3d"
        step._on_kind()
        step.driver.value = "velodyne"
        step._on_driver()
        assert step.source.value == DRIVERS["velodyne"].default_source  # the example replaced the last example
        step.source.value = str(tmp_path / "drive")  # typed before the server took the next choice
        step.driver.value = "rosbag"
        step._on_driver()
        assert step.source.value == str(tmp_path / "drive") and step.topics_button.visible
    finally:
        jobs.shutdown()
        server.stop()


def test_editing_a_sensor_in_the_form_changes_only_what_was_changed(tmp_path, free_port):
    """Picking a sensor fills the form with it; a new pose is previewed (nothing written) and applied; a device the
    form cannot show whole (the simulated board's motion settings) is kept when its fields were left alone."""
    from backend.calib.rig import service as rig_service
    from backend.sim.demo_rig import demo_rig

    store = SessionStore(tmp_path)
    session = store.create("s", rig=demo_rig())
    session.set_device("lidar_top", {**session.rig.get("lidar_top").device, "board_poses": 12})
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    jobs = JobRunner()
    try:
        ctx = StudioContext(server, store, jobs, RigScene(server))
        step = SensorsStep(ctx)
        ctx.open_session(session)
        step.sensor.value = "lidar_top"
        assert step.name.value == "lidar_top" and step.name.disabled and step.driver.value == "simulated_lidar"
        assert step.preview_button.visible and not step.add_button.visible
        np.testing.assert_allclose(step.xyz.value, session.rig.get("lidar_top").T_mount[:3, 3], atol=1e-9)

        step.xyz.value = (0.1, 0.0, 0.9)
        before = (tmp_path / "s" / "session.json").read_bytes()
        step._preview_edit()
        assert "would move" in step.change.content and step.apply_button.visible
        assert (tmp_path / "s" / "session.json").read_bytes() == before
        step._apply_edit()
        frame = store.get("s").rig.get("lidar_top")
        np.testing.assert_allclose(frame.T_mount[:3, 3], (0.1, 0.0, 0.9), atol=1e-9)
        assert frame.device["board_poses"] == 12, "the device was replaced though its fields were not touched"
        assert "moved" in step.change.content

        assert "lidar_top" not in step.parent.options  # its own subtree is not offered, and the service refuses it
        with pytest.raises(InputError, match="cycle"):
            rig_service.edit_sensor(session, "lidar_top", rig_service.SensorEdit(parent="lidar_top"))
    finally:
        jobs.shutdown()
        server.stop()
