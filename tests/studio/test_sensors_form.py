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
from studio.wizard.sensors_step import DRIVERS, RANGE_KINDS, SensorsStep, device_settings, drivers_for


def test_every_registered_driver_is_offered_for_the_kinds_it_captures():
    assert sorted(DRIVERS) == driver_names()
    assert drivers_for("camera") == ["uvc", "folder", "simulated", "rosbag", "node"]
    range_drivers = {"simulated_lidar", "velodyne", "velodyne_pcap", "ydlidar", "swept_scanner", "cloud_files",
                     "rosbag", "node"}
    for kind in RANGE_KINDS:
        depth_drivers = {"kinect2", "realsense", "depth_files", "sim_depth"} if kind == "depth" else set()
        assert set(drivers_for(kind)) == range_drivers | depth_drivers
    assert drivers_for("imu") == [] and drivers_for("frame") == []


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


@pytest.mark.parametrize(("driver", "source", "extra", "field", "message"), [
    ("rosbag", "BAG", {}, "topic", "needs its topic"),
    ("cloud_files", "", {}, "source", "needs a path"),
    ("velodyne_pcap", "/no/such/run.pcap", {}, "source", "/no/such/run.pcap does not exist"),
    ("velodyne", "70000", {}, "source", "must be a UDP port"),
    ("velodyne", "lidar:abc", {}, "source", "must be a UDP port"),
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


@pytest.mark.parametrize("driver", ["simulated_lidar", "velodyne", "ydlidar"])
def test_the_simulated_range_sensors_open_from_the_form(driver):
    with create_device(device_settings(driver, DRIVERS[driver].default_source)) as device:
        sample = device.read()
    assert sample.points is not None and len(sample.points) > 1000 and np.isfinite(sample.points).all()


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
