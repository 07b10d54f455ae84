"""Step 2: add sensors to the rig, with their mounting guess and capture device; edit, remove and restore them.

Every capture driver of :mod:`backend.devices` can be picked here, real or simulated:
the form's *Device* lists the drivers that fit the chosen *Kind*, and its *Source*
field takes what that driver needs (a port, a path, a simulated sensor's name, or
``sim`` for the byte-level simulators of the serial and network sensors).

One form adds and edits: *Sensor* picks a new sensor or one of the rig's, whose parent,
mounting guess, mount sigma and device the form then shows. A change or a removal is
previewed first (what it empties, what moves) and made with a second button; a removed
sensor keeps its captures and results aside and can be restored.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from backend.calib.rig import service as rig_service
from backend.core.errors import InputError
from backend.core.rig import DEFAULT_MOUNT_SIGMA, Frame
from backend.core.transforms import from_xyz_ypr, to_xyz_ypr
from backend.services import recordings
from backend.store.session import Session
from studio.context import StudioContext
from studio.marks import WARNING

CAMERA_KINDS = ("camera",)
RANGE_KINDS = ("lidar3d", "lidar2d", "depth")
DEPTH_KINDS = ("depth",)
IMU_KINDS = ("imu",)
KINDS = ("camera", "lidar3d", "lidar2d", "depth", "imu", "frame")
NEW_SENSOR = "(new sensor)"
"""*Sensor*'s choice for adding one."""


@dataclass(frozen=True)
class DriverChoice:
    """One capture driver as the form offers it."""

    hint: str
    """What goes into *Source*."""
    kinds: tuple[str, ...]
    """Sensor kinds it can capture for."""
    default_source: str


DRIVERS: dict[str, DriverChoice] = {
    "uvc": DriverChoice("USB camera: index or /dev/videoN", CAMERA_KINDS, "0"),
    "folder": DriverChoice("folder of images: its path", CAMERA_KINDS, ""),
    "simulated": DriverChoice("simulated camera: cam_front or cam_wide", CAMERA_KINDS, "cam_front"),
    "simulated_lidar": DriverChoice("simulated LiDAR: lidar_top, lidar_front or scanner_2d", RANGE_KINDS, "lidar_top"),
    "velodyne": DriverChoice("Velodyne VLP-16 over UDP: PORT or HOST:PORT to listen on (2368), or sim",
                             RANGE_KINDS, "sim"),
    "velodyne_pcap": DriverChoice("Velodyne pcap recording: its path", RANGE_KINDS, ""),
    "livox": DriverChoice("Livox SDK 1 LiDAR (Avia, Horizon) over UDP: its IP, its broadcast code, empty for the first "
                          "one broadcasting, or sim", RANGE_KINDS, "sim"),
    "ydlidar": DriverChoice("YDLiDAR TG30 at 512000 baud: serial port (/dev/ttyUSB0), or sim", RANGE_KINDS, "sim"),
    "vn100": DriverChoice("VectorNav VN-100, binary output 1 at 115200 baud: serial port (/dev/ttyUSB0), or sim",
                          IMU_KINDS, "sim"),
    "hokuyo": DriverChoice("Hokuyo over SCIP 2.0: the UTM-30LX-EW's address (192.168.0.10 or HOST:PORT), a USB "
                           "model's serial port (/dev/ttyACM0), or sim", RANGE_KINDS, "sim"),
    "swept_scanner": DriverChoice("2D scanner on a Dynamixel servo: the servo's serial port, or sim",
                                  RANGE_KINDS, "sim"),
    "cloud_files": DriverChoice("point-cloud files (.pcd .ply .las .laz .npy .lvx): a folder or one file",
                                RANGE_KINDS, ""),
    "lvx": DriverChoice("Livox .lvx recording (its frames, or its built-in IMU): its path", RANGE_KINDS + IMU_KINDS,
                        ""),
    "rosbag": DriverChoice("ROS 1 or ROS 2 bag (.bag, a folder, .mcap or .db3): its path; the topic below",
                           CAMERA_KINDS + RANGE_KINDS + IMU_KINDS, ""),
    "kinect2": DriverChoice("Kinect v2 through pylibfreenect2 (pip extra kinect2): its serial, or empty for the "
                            "first found", DEPTH_KINDS, ""),
    "realsense": DriverChoice("RealSense through pyrealsense2 (pip extra realsense): its serial, or empty for the "
                              "first found", DEPTH_KINDS, ""),
    "depth_files": DriverChoice("depth images (16-bit PNG in mm or .npy in m, *_ir beside, intrinsics .json or "
                                "camera_info .yaml): the folder", DEPTH_KINDS, ""),
    "sim_depth": DriverChoice("simulated Kinect v2 node of the depth cell: sn1 to sn6", DEPTH_KINDS, "sn1"),
    "node": DriverChoice("a sensor on another computer, served there by `calib-studio node --name NAME`: its name",
                         CAMERA_KINDS + RANGE_KINDS, ""),
}
PATH_DRIVERS = ("folder", "velodyne_pcap", "cloud_files", "lvx", "rosbag", "depth_files")
VELODYNE_LISTEN_HOST = "0.0.0.0"
"""Where a Velodyne given only a port is listened for: the sensor sends to the broadcast or the host's address."""


def drivers_for(kind: str) -> list[str]:
    """The drivers that can capture for a sensor ``kind`` (none for IMUs and plain frames)."""
    return [name for name, choice in DRIVERS.items() if kind in choice.kinds]


def _existing_path(source: str, driver: str) -> str:
    path = source.strip()
    if not path:
        raise InputError(f"{driver} needs a path in Source", "source")
    if not Path(path).expanduser().exists():
        raise InputError(f"{path} does not exist", "source")
    return str(Path(path).expanduser())


def _velodyne(source: str) -> dict:
    text = source.strip() or "2368"
    if text == "sim":
        return {"driver": "velodyne", "host": "sim"}
    host, _, port = text.rpartition(":")
    if not port.isdigit() or not 0 < int(port) < 65536:
        raise InputError(f"Velodyne source {text!r} must be a UDP port, HOST:PORT or sim", "source")
    return {"driver": "velodyne", "host": host or VELODYNE_LISTEN_HOST, "port": int(port)}


def _livox(source: str) -> dict:
    """A Livox LiDAR's settings from *Source*: ``sim``, its IPv4 address, its broadcast code, or empty (the first
    broadcasting)."""
    text = source.strip()
    if text == "sim":
        return {"driver": "livox", "host": "sim"}
    try:
        return {"driver": "livox", "host": str(ipaddress.IPv4Address(text))}
    except ValueError:
        pass
    if not text or (text.isalnum() and text.isascii() and len(text) <= 15):
        return {"driver": "livox", "broadcast_code": text}
    raise InputError(f"Livox source {text!r} must be the LiDAR's IPv4 address, its broadcast code (15 letters and "
                     "digits), empty for the first one broadcasting, or sim", "source")


def _hokuyo(source: str) -> dict:
    """A Hokuyo's settings from *Source*: ``sim``, a serial device path, or ``HOST[:PORT]``."""
    text = source.strip() or "sim"
    if text == "sim":
        return {"driver": "hokuyo", "host": "sim"}
    if text.startswith("/"):
        return {"driver": "hokuyo", "serial_port": text}
    host, _, port = text.partition(":")
    if not host or (port and not (port.isdigit() and 0 < int(port) < 65536)):
        raise InputError(f"Hokuyo source {text!r} must be HOST, HOST:PORT, a serial port (/dev/...) or sim", "source")
    return {"driver": "hokuyo", "host": host, **({"port": int(port)} if port else {})}


def device_settings(driver: str, source: str, *, width: int = 0, height: int = 0, topic: str = "",
                    time_window_s: tuple[float, float] = (0.0, 0.0), scanner_port: str = "sim") -> dict:
    """Capture settings for the rig from the form fields; :class:`InputError` names the field that is wrong.

    ``time_window_s`` is a bag's replay window (s after its start); ``(0, 0)`` replays it all.
    """
    text = source.strip()
    if driver == "uvc":
        device: int | str = int(text) if text.isdigit() else text
        return {"driver": "uvc", "device": device, "width": width or None, "height": height or None}
    if driver == "simulated":
        return {"driver": "simulated", "camera": text or "cam_front", "seed": 0}
    if driver == "simulated_lidar":
        return {"driver": "simulated_lidar", "sensor": text or "lidar_top", "seed": 0}
    if driver == "velodyne":
        return _velodyne(text)
    if driver in ("ydlidar", "vn100"):
        return {"driver": driver, "port": text or "sim"}
    if driver == "hokuyo":
        return _hokuyo(text)
    if driver == "livox":
        return _livox(text)
    if driver in ("kinect2", "realsense"):
        return {"driver": driver, "serial": text or None}
    if driver == "node":
        if not text:
            raise InputError("a network node needs the name its agent was started with (--name) in Source", "source")
        return {"driver": "node", "node": text}
    if driver == "sim_depth":
        return {"driver": "sim_depth", "node": text or "sn1", "seed": 0}
    if driver == "swept_scanner":
        servo_port = text or "sim"
        scanner = {"driver": "sim"} if servo_port == "sim" else {"driver": "ydlidar", "port": scanner_port.strip()}
        if scanner.get("port") in ("", "sim"):
            raise InputError("a real servo needs the real 2D scanner's serial port in Scanner port", "scanner_port")
        return {"driver": "swept_scanner", "servo_port": servo_port, "scanner": scanner}
    if driver in PATH_DRIVERS:
        settings = {"driver": driver, "path": _existing_path(text, driver)}
        if driver == "rosbag":
            if not topic.strip():
                raise InputError("a ROS bag source needs its topic (e.g. /velodyne_points)", "topic")
            settings["topic"] = topic.strip()
            start_s, end_s = (float(t) for t in time_window_s)
            if (start_s, end_s) != (0.0, 0.0):
                if start_s < 0 or end_s <= start_s:
                    raise InputError(f"time window {start_s:g}..{end_s:g} s: want 0 <= start < end (s after the "
                                     "bag start), or 0, 0 for the whole bag", "time_window")
                settings.update(start_s=start_s, end_s=end_s)
        return settings
    raise InputError(f"unknown device {driver!r}; known: {', '.join(DRIVERS)}", "device")


@dataclass(frozen=True)
class DeviceForm:
    """The form's device fields, as :func:`device_settings` takes them."""

    driver: str
    source: str = ""
    width: int = 0
    height: int = 0
    topic: str = ""
    time_window_s: tuple[float, float] = (0.0, 0.0)
    scanner_port: str = ""

    def settings(self) -> dict:
        return device_settings(self.driver, self.source, width=self.width, height=self.height, topic=self.topic,
                               time_window_s=self.time_window_s, scanner_port=self.scanner_port)


def device_form(device: dict[str, Any]) -> DeviceForm | None:
    """The form fields that give ``device`` (a sensor's settings), or None when the form has no driver for it."""
    driver, text = device.get("driver"), lambda key: "" if device.get(key) is None else str(device[key])
    if driver == "uvc":
        return DeviceForm("uvc", text("device"), device.get("width") or 0, device.get("height") or 0)
    if driver in ("simulated", "simulated_lidar", "ydlidar", "vn100", "node", "sim_depth", "kinect2", "realsense"):
        key = {"simulated": "camera", "simulated_lidar": "sensor", "ydlidar": "port", "vn100": "port", "node": "node",
               "sim_depth": "node"}.get(driver, "serial")
        return DeviceForm(driver, text(key))
    if driver == "hokuyo":
        if device.get("serial_port"):
            return DeviceForm(driver, str(device["serial_port"]))
        port = device.get("port")
        return DeviceForm(driver, text("host") + (f":{port}" if port and device.get("host") != "sim" else ""))
    if driver == "velodyne":
        host, port = device.get("host"), device.get("port")
        return DeviceForm(driver, "sim" if host == "sim" else f"{'' if host == VELODYNE_LISTEN_HOST else host + ':'}"
                          f"{port}")
    if driver == "livox":
        return DeviceForm(driver, text("host") or text("broadcast_code"))
    if driver == "swept_scanner":
        return DeviceForm(driver, text("servo_port"), scanner_port=str(device.get("scanner", {}).get("port", "")))
    if driver in PATH_DRIVERS:
        return DeviceForm(driver, text("path"), topic=text("topic"),
                          time_window_s=(device.get("start_s", 0.0), device.get("end_s", 0.0)))
    return None


def change_text(change: dict[str, Any]) -> str:
    """A previewed or made sensor change (:meth:`SensorChange.to_dict`) as the panel says it."""
    verb = "" if change["applied"] else "would be "
    lines = [f"- `{slot}` {verb}emptied: its result stays in the history" for slot in change["emptied"]]
    lines += [f"- `{slot}` {verb}restored" for slot in change["restored"]]
    lines += [f"- `{slot}` stays empty: {why}" for slot, why in change["not_restored"].items()]
    for move in change["moves"]:
        ratio = "" if move["sigma_ratio"] is None else f" ({move['sigma_ratio']:.1f}σ)"
        lines.append(f"- `{move['frame']}` {'moved' if change['applied'] else 'would move'} "
                     f"{1000 * move['trans_m']:.1f} mm, {move['rot_deg']:.2f}°{ratio}")
    lines += [f"- {WARNING} {problem}" for problem in change["problems"]]
    return "\n".join(lines) or "Nothing else in the rig moves."


class SensorsStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self._loaded: tuple[str, str, np.ndarray, tuple[float, float] | None, DeviceForm | None] | None = None
        """The sensor the form shows: name, parent, mounting guess, mount sigma and device form as loaded."""
        self._pending: rig_service.SensorEdit | None = None
        gui = ctx.server.gui
        with gui.add_folder("2 · Sensors", expand_by_default=False):
            self.listing = gui.add_markdown("Open a session first.")
            self.sensor = gui.add_dropdown("Sensor", options=[NEW_SENSOR], hint="a new sensor, or one of the rig's to "
                                           "edit or remove")
            self.name = gui.add_text("Name", initial_value="cam_new")
            self.kind = gui.add_dropdown("Kind", options=list(KINDS))
            self.parent = gui.add_dropdown("Parent", options=["base_link"])
            self.xyz = gui.add_vector3("xyz (m)", initial_value=(0.0, 0.0, 0.0), step=0.001)
            self.ypr = gui.add_vector3("yaw pitch roll (°)", initial_value=(0.0, 0.0, 0.0), step=0.1)
            self.mount_sigma = gui.add_vector2(
                "Mount 1σ (mm, °)", initial_value=(1000 * DEFAULT_MOUNT_SIGMA[0], DEFAULT_MOUNT_SIGMA[1]), step=1.0,
                min=(0.0, 0.0), hint="how well the mounting above is known (tape, CAD): a weak prior the calibrations "
                "override; 0, 0 means unknown, so only calibrations place the sensor")
            self.driver = gui.add_dropdown("Device", options=drivers_for("camera"), initial_value="uvc")
            self.source = gui.add_text("Source", initial_value=DRIVERS["uvc"].default_source, hint=DRIVERS["uvc"].hint)
            self._example_source = DRIVERS["uvc"].default_source
            self.source_help = gui.add_markdown(DRIVERS["uvc"].hint)
            self.topic = gui.add_text("Topic", initial_value="", visible=False, hint="the bag topic to replay")
            self.time_window = gui.add_vector2("Time window (s)", initial_value=(0.0, 0.0), step=0.1, visible=False,
                                               hint="seconds after the bag start; 0, 0 replays the whole bag")
            self.topics_button = gui.add_button("List the bag's topics", visible=False)
            self.scanner_port = gui.add_text("Scanner port", initial_value="", visible=False,
                                             hint="serial port of the 2D scanner the servo turns")
            self.size = gui.add_vector2("Resolution (px)", initial_value=(1280, 720), step=1)
            self.not_connected = gui.add_checkbox(
                "Add as not connected", initial_value=False, hint="define the rig before the hardware is plugged in: "
                "the device is not opened now, and the sensor is listed as not connected until it answers")
            self.add_button = gui.add_button("Add sensor")
            self.preview_button = gui.add_button("Preview change", visible=False,
                                                 hint="what the change above would empty and move; nothing is written")
            self.remove_button = gui.add_button("Remove sensor…", color="red", visible=False,
                                                hint="what removing it would empty and move; nothing is written yet")
            self.change = gui.add_markdown("", visible=False)
            self.apply_button = gui.add_button("Apply change", visible=False)
            self.confirm_remove_button = gui.add_button("Confirm removal", color="red", visible=False,
                                                        hint="its captures and results are kept aside, restorable")
            with gui.add_folder("Removed sensors", expand_by_default=False):
                self.removed = gui.add_markdown("None.")
                self.removal = gui.add_dropdown("Removal", options=["-"])
                self.restore_button = gui.add_button("Restore sensor", disabled=True)
        self.sensor.on_update(lambda _: self._on_sensor())
        self.kind.on_update(lambda _: self._on_kind())
        self.driver.on_update(lambda _: self._on_driver())
        self.topics_button.on_click(lambda _: self._list_topics())
        self.add_button.on_click(lambda _: self._add())
        self.preview_button.on_click(lambda _: self._preview_edit())
        self.apply_button.on_click(lambda _: self._apply_edit())
        self.remove_button.on_click(lambda _: self._preview_removal())
        self.confirm_remove_button.on_click(lambda _: self._remove())
        self.restore_button.on_click(lambda _: self._restore())
        ctx.on_session_changed(self._show)

    def _on_kind(self) -> None:
        options = drivers_for(self.kind.value)
        self.driver.visible = self.source.visible = self.source_help.visible = bool(options)
        if options:
            self.driver.options = options
            if self.driver.value not in options:
                self.driver.value = options[0]  # fires _on_driver
            self._on_driver()
        else:
            for handle in (self.topic, self.time_window, self.topics_button, self.scanner_port, self.size):
                handle.visible = False

    def _on_driver(self) -> None:
        """Show the chosen device's fields. Its example source replaces the source box's text only while that is
        still the previous device's example: a source typed meanwhile (this runs after the click, later on a busy
        server) is kept."""
        choice = DRIVERS[self.driver.value]
        if self.source.value in ("", self._example_source):
            self.source.value = choice.default_source
        self._example_source = choice.default_source
        self.source_help.content = choice.hint
        self.topic.visible = self.time_window.visible = self.topics_button.visible = self.driver.value == "rosbag"
        self.scanner_port.visible = self.driver.value == "swept_scanner"
        self.size.visible = self.driver.value == "uvc"

    def _list_topics(self) -> None:
        """Show the bag's topics (type, messages, time span) and pick the first one the sensor kind can replay."""
        try:
            topics = recordings.bag_topics(_existing_path(self.source.value, "rosbag"))
        except InputError as exc:
            self.ctx.notify("Cannot read the bag", exc.one_line().removeprefix("error: "), error=True)
            return
        rows = [f"| `{t.name}` | {t.msgtype.rsplit('/', 1)[-1]} | {t.count} | "
                f"{'' if t.start_s is None else f'{t.start_s:.1f}-{t.end_s:.1f}'} |" for t in topics]
        self.source_help.content = "\n".join(["| topic | type | messages | s after start |", "|---|---|---|---|",
                                               *rows]) if rows else "The bag holds no topics."
        fitting = recordings.topics_for_kind(topics, self.kind.value)
        if fitting and not self.topic.value.strip():
            self.topic.value = fitting[0]

    # -- the form's values -------------------------------------------------------------
    def _pose(self) -> np.ndarray:
        return from_xyz_ypr(np.array(self.xyz.value), np.radians(self.ypr.value))

    def _sigma(self) -> tuple[float, float] | None:
        sigma_mm, sigma_deg = self.mount_sigma.value
        return None if sigma_mm == 0 and sigma_deg == 0 else (sigma_mm / 1000, sigma_deg)

    def _device_form(self) -> DeviceForm | None:
        if not drivers_for(self.kind.value):
            return None
        return DeviceForm(self.driver.value, self.source.value, int(self.size.value[0]), int(self.size.value[1]),
                          self.topic.value, tuple(self.time_window.value), self.scanner_port.value)

    def _session(self) -> Session | None:
        if self.ctx.session is None:
            self.ctx.notify("No session", "Open or create a session first.", error=True)
        return self.ctx.session

    # -- adding ------------------------------------------------------------------------
    def _add(self) -> None:
        session = self._session()
        if session is None:
            return
        try:
            form = self._device_form()
            device = {} if form is None else form.settings()
            rig_service.add_sensor(session, Frame(self.name.value.strip(), self.parent.value, self._pose(),
                                                  kind=self.kind.value, device=device, mount_sigma=self._sigma()),
                                   connected=not self.not_connected.value)
        except InputError as exc:
            self.ctx.notify("Cannot add sensor", exc.one_line().removeprefix("error: "), error=True)
            return
        self.ctx.notify("Sensor added", f"{self.name.value.strip()} ({self.kind.value}"
                        f"{', ' + device['driver'] if device else ''})")
        self.ctx.follow()  # every step lists the new sensor

    # -- editing and removing ----------------------------------------------------------
    def _on_sensor(self) -> None:
        """Show the picked sensor's values (editing) or a blank form (adding)."""
        session, name = self.ctx.session, self.sensor.value
        editing = session is not None and name in session.rig.frames
        self._pending = None
        self.change.visible = self.apply_button.visible = self.confirm_remove_button.visible = False
        self.name.disabled = self.kind.disabled = editing
        self.add_button.visible = self.not_connected.visible = not editing
        self.preview_button.visible = self.remove_button.visible = editing
        if not editing:
            self._loaded = None
            if session is not None:
                self.parent.options = list(session.rig.frames)
            return
        frame = session.rig.get(name)
        self.parent.options = [f for f in session.rig.frames if f not in session.rig.subtree(name)]
        self.parent.value = frame.parent
        self.name.value, self.kind.value = frame.name, frame.kind
        xyz, ypr = to_xyz_ypr(frame.T_mount)
        self.xyz.value, self.ypr.value = tuple(float(v) for v in xyz), tuple(float(v) for v in np.degrees(ypr))
        self.mount_sigma.value = (0.0, 0.0) if frame.mount_sigma is None else (1000 * frame.mount_sigma[0],
                                                                                frame.mount_sigma[1])
        form = device_form(frame.device)
        if form is not None:
            self.driver.value = form.driver
            self.source.value, self.topic.value, self.scanner_port.value = form.source, form.topic, form.scanner_port
            self.time_window.value = form.time_window_s
            if form.width and form.height:
                self.size.value = (form.width, form.height)
        self._loaded = (name, frame.parent, self._pose(), self._sigma(), self._device_form())

    def _edit(self) -> rig_service.SensorEdit:
        """The form's changes to the loaded sensor (a field left as loaded is kept: a device the form cannot show
        whole, like the demo's simulated boards, is only replaced when its fields are changed)."""
        name, parent, pose, sigma, device = self._loaded
        form = self._device_form()
        return rig_service.SensorEdit(
            parent=None if self.parent.value == parent else self.parent.value,
            T_mount=None if np.allclose(self._pose(), pose, atol=1e-9) else self._pose(),
            mount_sigma=rig_service.KEEP if self._sigma() == sigma else self._sigma(),
            device=None if form == device or form is None else form.settings())

    def _attempt(self, failure: str, make: Callable[[Session], rig_service.SensorChange]
                 ) -> rig_service.SensorChange | None:
        """``make(session)`` on the open session; None when there is none, or when it raised an :class:`InputError`,
        which is shown under ``failure``."""
        session = self._session()
        if session is None:
            return None
        try:
            return make(session)
        except InputError as exc:
            self.ctx.notify(failure, exc.one_line().removeprefix("error: "), error=True)
            return None

    def _preview_edit(self) -> None:
        if self._loaded is None:
            return
        name = self._loaded[0]

        def preview(session: Session) -> rig_service.SensorChange:
            self._pending = self._edit()
            return rig_service.edit_sensor(session, name, self._pending, preview=True)

        if (change := self._attempt("Cannot change the sensor", preview)) is not None:
            self._say(f"**Changing `{name}`**\n\n{change_text(change.to_dict())}")
            self.apply_button.visible = True

    def _apply_edit(self) -> None:
        if self._loaded is None or (edit := self._pending) is None:
            return
        name = self._loaded[0]
        change = self._attempt("Cannot change the sensor", lambda session: rig_service.edit_sensor(session, name, edit))
        if change is not None:
            self.ctx.notify("Sensor changed", f"{name}: {len(change.moves)} frame(s) moved")
            self._reopen(name, f"**Changed `{name}`**\n\n{change_text(change.to_dict())}")

    def _preview_removal(self) -> None:
        if self._loaded is None:
            return
        name = self._loaded[0]
        change = self._attempt("Cannot remove the sensor",
                               lambda session: rig_service.remove_sensor(session, name, preview=True))
        if change is not None:
            self._say(f"**Removing `{name}`**: its captures and results are kept aside, restorable below.\n\n"
                      f"{change_text(change.to_dict())}")
            self.confirm_remove_button.visible = True

    def _remove(self) -> None:
        if self._loaded is None:
            return
        name = self._loaded[0]
        change = self._attempt("Cannot remove the sensor", lambda session: rig_service.remove_sensor(session, name))
        if change is not None:
            removal = change.removal["id"]
            self.ctx.notify("Sensor removed", f"{name}: kept aside as {removal}")
            self._reopen(NEW_SENSOR, f"**Removed `{name}`**, kept aside as `{removal}`\n\n"
                                     f"{change_text(change.to_dict())}")

    def _restore(self) -> None:
        removal = self.removal.value
        change = self._attempt("Cannot restore the sensor",
                               lambda session: rig_service.restore_sensor(session, removal))
        if change is not None:
            self.ctx.notify("Sensor restored", f"{change.sensor}: {len(change.restored)} accepted result(s) back")
            self._reopen(change.sensor, f"**Restored `{change.sensor}`**\n\n{change_text(change.to_dict())}")

    def _say(self, text: str) -> None:
        self.change.content = text
        self.change.visible = True

    def _reopen(self, pick: str, said: str) -> None:
        """Show the changed rig everywhere (every step follows the session again), with ``pick`` in *Sensor* and
        what the change did under it."""
        self.ctx.follow()
        self._pick(pick)
        self._say(said)

    def _pick(self, name: str) -> None:
        """Show ``name`` (a frame, or :data:`NEW_SENSOR`) in the form."""
        if self.sensor.value == name:
            self._on_sensor()
        else:
            self.sensor.value = name  # fires _on_sensor

    def _show(self, session: Session) -> None:
        self.parent.options = list(session.rig.frames)
        lines = [f"- `{f.name}` ({f.kind}) under `{f.parent}`"
                 f"{' · ' + f.device.get('driver', '') if f.device else ''}"
                 f"{' · **not connected**' if f.not_connected else ''} · {_mount_text(f.mount_sigma)}"
                 for f in session.rig.sensors()]
        self.listing.content = "\n".join(lines) or "No sensors yet."
        names = [f.name for f in session.rig.frames.values() if f.parent is not None]
        kept = self.sensor.value if self.sensor.value in names else NEW_SENSOR
        self.sensor.options = [NEW_SENSOR, *names]
        self._pick(kept)
        removed = session.removed()
        self.removed.content = "\n".join(
            f"- `{r['id']}`: {r['sensor']} ({r['kind']}), {r['captures']} capture(s) and {len(r['results'])} "
            f"result(s) kept" for r in removed) or "None."
        self.removal.options = [r["id"] for r in removed] or ["-"]
        self.restore_button.disabled = not removed


def _mount_text(mount_sigma: tuple[float, float] | None) -> str:
    """How well a sensor's mounting guess is known, as the listing says it."""
    if mount_sigma is None:
        return "mounting unknown"
    return f"mounted ±{1000 * mount_sigma[0]:g} mm, ±{mount_sigma[1]:g}°"
