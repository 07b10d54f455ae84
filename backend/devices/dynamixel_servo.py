"""A Dynamixel servo (ROBOTIS ``dynamixel_sdk``, Protocol 2.0) and the swept 2D scanner it turns.

:class:`DynamixelServo` drives an X-series servo (XM430-like control table: torque enable 64,
goal position 116 and present position 132 as 4-byte ticks, 4096 ticks per revolution, 2048 =
centre = angle 0) over a serial port. Angles are radians from the centre, positive as the servo
counts ticks up.

:class:`SweptScanner` (driver ``"swept_scanner"``) is the "2D scanner on a servo" rig: each
:meth:`~SweptScanner.read` is one full sweep: the servo steps from ``start_deg`` to ``end_deg``,
at each step it settles, one fresh 2D scan is read, and the servo angle is read back; the scans
are assembled with a :class:`~backend.core.sweep_geometry.SweepGeometry` into one cloud in the ``mount``
frame (see :mod:`backend.core.sweep_geometry`).

Simulation: ``servo_port="sim"`` starts the simulated endpoint registered as ``"dynamixel"`` (a simulated
servo speaking byte-level Protocol 2.0 on a pty; :func:`~backend.devices.base.start_simulator`) and
``scanner={"driver": "sim", ...}`` the one registered as ``"swept_head"``: a 2D scanner bolted to that
simulated horn, each scan ray-cast in the simulated yard from the pose the horn's physical angle and a TRUE
geometry give, so tests know the truth (it reports that truth with ``ground_truth()``).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from backend.core.sweep_geometry import SweepGeometry, stack_scans
from backend.core.transforms import transform_points
from backend.devices.base import (
    CaptureDevice,
    DeviceDisconnected,
    DeviceError,
    Sample,
    create_device,
    register_driver,
    start_simulator,
)

TICKS_PER_REV = 4096
CENTER_TICKS = 2048
RAD_PER_TICK = 2.0 * math.pi / TICKS_PER_REV
ADDR_TORQUE_ENABLE = 64
ADDR_GOAL_POSITION = 116
ADDR_MOVING = 122
ADDR_PRESENT_POSITION = 132


def angle_to_ticks(angle_rad: float) -> int:
    """Goal ticks for an angle (rad) from the centre position."""
    return int(round(CENTER_TICKS + angle_rad / RAD_PER_TICK))


def ticks_to_angle(ticks: int) -> float:
    """Angle (rad) from the centre position of a tick count."""
    return (ticks - CENTER_TICKS) * RAD_PER_TICK


USB_LATENCY_MS = 16.0
"""The latency timer of a U2D2 (FTDI) adapter; ``dynamixel_sdk`` waits twice this plus the bytes' time."""
SIM_LATENCY_MS = 250.0
"""The wait for the built-in simulator (``servo_port="sim"``), which answers from a thread of a possibly loaded
host rather than from the servo's own microcontroller."""


def _port_handler(dxl: Any, path: str, latency_ms: float) -> Any:
    """``dynamixel_sdk.PortHandler`` for ``path`` whose packet timeout uses ``latency_ms`` (the SDK's is fixed)."""

    class PortHandler(dxl.PortHandler):
        def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802 - the SDK's name
            self.packet_start_time = self.getCurrentTime()
            self.packet_timeout = self.tx_time_per_byte * packet_length + 2.0 * latency_ms + 2.0

    return PortHandler(path)


class DynamixelServo:
    """One Dynamixel X-series servo in position mode, through ``dynamixel_sdk`` (Protocol 2.0).

    Every transaction is retried ``retries`` times when the status packet is missing or corrupt
    (wrong CRC: the SDK's ``COMM_RX_CORRUPT``); :attr:`retried` counts those. A servo that
    stops answering raises :class:`DeviceDisconnected`; an error in the status packet (data
    limit, access ...) raises :class:`DeviceError` with the SDK's text.
    """

    def __init__(self, port: str, dxl_id: int = 1, baudrate: int = 57600, retries: int = 3,
                 latency_ms: float = USB_LATENCY_MS):
        """Args:
        port: serial device (``/dev/ttyUSB0``, a U2D2) or a simulator's pty path.
        dxl_id: the servo's ID.
        baudrate: 57600 (X-series default) or what the servo is set to.
        retries: attempts after a failed transaction.
        latency_ms: how late an answer may arrive beyond its bytes' time, halved (ms): the USB adapter's latency
            timer (:data:`USB_LATENCY_MS`, the SDK's own figure), or :data:`SIM_LATENCY_MS` for a simulator, a
            thread that a loaded host may not schedule for tens of milliseconds.
        """
        self.port = str(port)
        self.dxl_id = int(dxl_id)
        self.baudrate = int(baudrate)
        self.retries = int(retries)
        self.latency_ms = float(latency_ms)
        self.model_number: int | None = None
        self.retried = 0
        self._port_handler: Any = None
        self._packet: Any = None
        self._dxl: Any = None

    def describe(self) -> str:
        return f"dynamixel id {self.dxl_id} on {self.port} @{self.baudrate}"

    # ------------------------------------------------------------------ lifecycle
    def open(self, torque: bool = True) -> None:
        """Open the port, ping the servo (its model number) and switch torque on."""
        import dynamixel_sdk as dxl

        self._dxl = dxl
        port = _port_handler(dxl, self.port, self.latency_ms)
        try:
            port.baudrate = self.baudrate
            ok = port.openPort()
        except Exception as exc:  # noqa: BLE001 - serial.SerialException, OSError
            raise DeviceError(f"cannot open serial port {self.port}: {exc}", self.describe()) from None
        if not ok:
            raise DeviceError(f"cannot open {self.port} at {self.baudrate} baud (unsupported rate?)",
                              self.describe())
        self._port_handler = port
        self._packet = dxl.PacketHandler(2.0)
        try:
            self.model_number = self._call("ping", lambda: self._packet.ping(self._port_handler, self.dxl_id))
            if torque:
                self.set_torque(True)
        except DeviceError:
            self.close()
            raise

    def close(self) -> None:
        """Release the port (torque stays as it is, so the horn holds its pose). Safe twice."""
        port, self._port_handler = self._port_handler, None
        if port is not None and port.ser is not None:
            try:
                port.closePort()
            except Exception:  # noqa: BLE001 - the port may already be gone
                pass

    def __enter__(self) -> DynamixelServo:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ transactions
    def _call(self, what: str, fn: Any) -> Any:
        """Run an SDK call returning ``(value..., result, error)``; retry, then raise."""
        if self._port_handler is None:
            raise DeviceDisconnected(f"{self.port} is not open", self.describe())
        dxl = self._dxl
        last = ""
        for attempt in range(self.retries + 1):
            try:
                out = fn()
            except Exception as exc:  # noqa: BLE001 - serial errors when the adapter is unplugged
                last = f"serial error: {exc}"
                self._port_handler.is_using = False
            else:
                *values, result, error = out if isinstance(out, tuple) else (None, out, 0)
                if result == dxl.COMM_SUCCESS:
                    if error:
                        raise DeviceError(f"{what}: {self._packet.getRxPacketError(error)} (error {error})",
                                          self.describe())
                    return values[0] if values else None
                last = self._packet.getTxRxResult(result)
            if attempt < self.retries:
                self.retried += 1
                self._resync()
        raise DeviceDisconnected(f"{what}: no valid answer from servo {self.dxl_id} after {self.retries + 1} "
                                 f"attempts ({last}); check power, ID, baud rate and cable", self.describe())

    def _resync(self) -> None:
        """Drop what is left in the receive buffer before a retry: a status packet that came late, or the rest
        of a spoiled one, would otherwise be read as the answer to the next instruction, and every retry after
        it would read a stale packet."""
        try:
            self._port_handler.clearPort()
        except Exception:  # noqa: BLE001 - an unplugged adapter: the retry itself will say so
            pass

    def set_torque(self, on: bool) -> None:
        """Torque enable (address 64)."""
        self._call("torque enable", lambda: self._packet.write1ByteTxRx(
            self._port_handler, self.dxl_id, ADDR_TORQUE_ENABLE, int(bool(on))))

    def read_ticks(self) -> int:
        """Present position (address 132, signed 4 bytes) in ticks."""
        raw = self._call("read present position", lambda: self._packet.read4ByteTxRx(
            self._port_handler, self.dxl_id, ADDR_PRESENT_POSITION))
        return int(raw) - (1 << 32) if raw >= 1 << 31 else int(raw)

    def read_angle(self) -> float:
        """Present angle (rad) from the centre position."""
        return ticks_to_angle(self.read_ticks())

    def write_goal_ticks(self, ticks: int) -> None:
        """Goal position (address 116, 4 bytes) in ticks (0..4095 in position mode)."""
        self._call("write goal position", lambda: self._packet.write4ByteTxRx(
            self._port_handler, self.dxl_id, ADDR_GOAL_POSITION, int(ticks) & 0xFFFFFFFF))

    def move_to(self, angle_rad: float, wait: bool = True, tolerance_rad: float = math.radians(0.2),
                timeout_s: float = 5.0) -> float:
        """Command ``angle_rad`` (rad from centre); with ``wait``, poll until the present position is
        within ``tolerance_rad`` (rad) of the goal and has stopped (two equal readings in a row).
        Returns the last angle read (rad).

        Raises :class:`DeviceError` for an angle outside the servo's range or when it does not get
        there within ``timeout_s`` (s; blocked horn, torque off).
        """
        goal = angle_to_ticks(angle_rad)
        if not 0 <= goal < TICKS_PER_REV:
            raise DeviceError(f"angle {math.degrees(angle_rad):.1f} deg is outside the servo's range "
                              f"(-180..180 deg in position mode)", self.describe())
        self.write_goal_ticks(goal)
        if not wait:
            return self.read_angle()
        tol_ticks = max(tolerance_rad / RAD_PER_TICK, 0.0)
        deadline = time.monotonic() + timeout_s
        previous = None
        while True:
            present = self.read_ticks()
            if abs(present - goal) <= tol_ticks and present == previous:
                return ticks_to_angle(present)
            previous = present
            if time.monotonic() > deadline:
                raise DeviceError(f"servo did not reach {math.degrees(angle_rad):.2f} deg within {timeout_s:g} s "
                                  f"(at {math.degrees(ticks_to_angle(present)):.2f} deg): blocked or torque off?",
                                  self.describe())
            time.sleep(0.001)


# ---------------------------------------------------------------------------------------------- the rig

@register_driver
class SweptScanner(CaptureDevice):
    """A 2D scanner swept into 3D by a Dynamixel servo; one :class:`Sample` per full sweep.

    ``points`` (M, 3) float64 are in the ``mount`` frame (m), assembled with :attr:`geometry`;
    ``intensity`` (M,) float32 (0 where the scanner reports none). ``meta``:

    - ``steps``, ``servo_angles_rad`` (per step, as read back after the scan), ``commanded_angles_rad``;
    - ``points_scanner`` (M, 3) and ``point_step`` (M,) int32: the raw scans, for re-assembly and
      calibration (:meth:`scans_of`); ``scan_angles_rad`` (M,) angle of each point within its scan;
    - ``step_counts`` (per step, points of its scan) and ``geometry`` (the dict used): with
      ``servo_angles_rad`` what a stored capture needs to recover the raw scans
      (:func:`~backend.core.sweep_geometry.scans_from_capture`); ``frame`` ``"mount"``, ``sweep_seconds``,
      ``servo_retries``;
    - in simulation: ``simulated`` True, ``true_geometry``, ``T_base_mount`` (ground truth).
    """

    driver = "swept_scanner"

    def __init__(self, servo_port: str, scanner: dict | None = None, steps: int = 173, start_deg: float = -90.0,
                 end_deg: float = 90.0, geometry: dict | None = None, servo_id: int = 1, baudrate: int = 57600,
                 tolerance_deg: float = 0.2, move_timeout_s: float = 5.0, settle_s: float = 0.0,
                 stale_scans: int = 64, sim_speed_deg_s: float = 240.0):
        """Settings as stored in the rig.

        Args:
            servo_port: the servo's serial port, or ``"sim"`` for the built-in Dynamixel simulator.
            scanner: the 2D scanner's device settings, e.g. ``{"driver": "ydlidar", "port": "sim"}``,
                ``{"driver": "hokuyo", "host": "192.168.0.10"}`` (with ``"host": "sim"`` and the simulated servo: a
                simulated UTM-30LX-EW on the simulated horn, the endpoint registered as ``"hokuyo"``, its optional
                ``"sim"`` dict holding the simulated head's keys, as ``{"driver": "sim", ...}`` takes them),
                or ``{"driver": "sim", ...}`` (only with ``servo_port="sim"``: a ray-cast scanner on
                the simulated horn, the endpoint registered as ``"swept_head"``; keys of the simulation
                package's ``SimSweptScannerHead``). Default ``{"driver": "sim"}`` with the simulated servo.
            steps: servo steps per sweep (>= 2); 173 over 180 deg is the classic half-sphere sweep.
            start_deg, end_deg: first and last servo angle (deg from centre).
            geometry: the :class:`SweepGeometry` dict used to assemble (default: axis x, no offset).
            servo_id, baudrate: the servo's ID and baud rate.
            tolerance_deg: a step is settled when the servo reads within this of the goal (deg).
            move_timeout_s: how long one step may take (s).
            settle_s: extra wait after settling, before the scan (s; lets a real rig stop swinging).
            stale_scans: a streaming scanner's scans started before the servo settled are dropped;
                at most this many per step (a 40 Hz Hokuyo queues about 16 while the servo swings to the start).
            sim_speed_deg_s: the simulated servo's speed (deg/s).
        """
        if int(steps) < 2:
            raise DeviceError(f"steps must be at least 2, not {steps}", f"swept_scanner {servo_port}")
        self.servo_port = str(servo_port)
        self.scanner_settings = dict(scanner) if scanner is not None else (
            {"driver": "sim"} if self.servo_port == "sim" else None)
        if self.scanner_settings is None:
            raise DeviceError("scanner settings are required, e.g. {'driver': 'ydlidar', 'port': '/dev/ydlidar'}",
                              f"swept_scanner {servo_port}")
        if self.scanner_settings.get("driver") == "sim" and self.servo_port != "sim":
            raise DeviceError("the simulated scanner head needs the simulated servo (servo_port='sim')",
                              f"swept_scanner {servo_port}")
        self.steps = int(steps)
        self.start_deg = float(start_deg)
        self.end_deg = float(end_deg)
        try:
            self.geometry = SweepGeometry.from_dict(geometry)
        except (ValueError, TypeError) as exc:
            raise DeviceError(f"bad geometry: {exc}", f"swept_scanner {servo_port}") from None
        self.servo_id = int(servo_id)
        self.baudrate = int(baudrate)
        self.tolerance_deg = float(tolerance_deg)
        self.move_timeout_s = float(move_timeout_s)
        self.settle_s = float(settle_s)
        self.stale_scans = int(stale_scans)
        self.sim_speed_deg_s = float(sim_speed_deg_s)
        self.servo: DynamixelServo | None = None
        self.scanner: CaptureDevice | None = None
        self._sim: Any = None
        """With ``servo_port="sim"``, the simulated servo (``port``, ``stop()``) while open."""
        self._truth: Any = None
        """In simulation, what knows the truth (``ground_truth()``): the simulated head on the simulated horn, or the
        simulated Hokuyo bolted to it (which this device then also stops)."""
        self._scanner_sim: Any = None
        self._sweeps = 0

    def describe(self) -> str:
        return (f"swept_scanner servo {self.servo_port} + {self.scanner_settings.get('driver')} "
                f"({self.steps} steps {self.start_deg:g}..{self.end_deg:g} deg)")

    @property
    def commanded_angles_rad(self) -> np.ndarray:
        """(steps,) servo goals of one sweep (rad)."""
        return np.radians(np.linspace(self.start_deg, self.end_deg, self.steps))

    def open(self) -> None:
        """Start the simulator if asked, open the servo (ping, torque on), then the scanner."""
        try:
            path = self.servo_port
            if self.servo_port == "sim":
                self._sim = start_simulator("dynamixel", self.describe(), dxl_id=self.servo_id,
                                            speed_deg_s=self.sim_speed_deg_s)
                path = self._sim.port
            self.servo = DynamixelServo(path, self.servo_id, self.baudrate,
                                        latency_ms=SIM_LATENCY_MS if self._sim is not None else USB_LATENCY_MS)
            self.servo.open()
            settings = dict(self.scanner_settings)
            if settings.get("driver") == "sim":
                settings.pop("driver")
                try:
                    self.scanner = start_simulator("swept_head", self.describe(), servo=self._sim, **settings)
                except TypeError as exc:
                    raise DeviceError(f"bad simulated scanner settings {settings}: {exc}", self.describe()) from None
                self._truth = self.scanner
            elif settings.get("driver") == "hokuyo" and settings.get("host") == "sim" and self._sim is not None:
                # a simulated UTM-30LX-EW speaking SCIP 2.0 on 127.0.0.1, scanning from the simulated horn
                try:
                    self._scanner_sim = self._truth = start_simulator("hokuyo", self.describe(), servo=self._sim,
                                                                      **settings.pop("sim", {}))
                except TypeError as exc:
                    raise DeviceError(f"bad simulated scanner settings {self.scanner_settings}: {exc}",
                                      self.describe()) from None
                self.scanner = create_device(settings | {"host": self._scanner_sim.host,
                                                         "port": self._scanner_sim.port})
            else:
                self.scanner = create_device(settings)
            self.scanner.open()
        except Exception:
            self.close()
            raise

    def read(self) -> Sample:
        """One full sweep: step, settle, scan, read back the angle; assemble in the mount frame."""
        if self.servo is None or self.scanner is None:
            raise DeviceDisconnected("read() before open()", self.describe())
        t0 = time.time()
        started = time.monotonic()
        tol = math.radians(self.tolerance_deg)
        scans, measured = [], []
        retries_before = self.servo.retried
        for goal in self.commanded_angles_rad:
            self.servo.move_to(float(goal), wait=True, tolerance_rad=tol, timeout_s=self.move_timeout_s)
            if self.settle_s > 0:
                time.sleep(self.settle_s)
            settled = time.time()
            sample = self.scanner.read()
            for _ in range(self.stale_scans):
                if sample.timestamp_s >= settled:
                    break
                sample = self.scanner.read()
            angle = self.servo.read_angle()
            measured.append(angle)
            pts = np.zeros((0, 3)) if sample.points is None else np.asarray(sample.points, dtype=float)
            scans.append((angle, pts, sample.intensity))
        points_scanner, angles, intensity = stack_scans(scans)
        counts = np.array([len(s[1]) for s in scans])
        meta: dict[str, Any] = {
            "steps": self.steps,
            "servo_angles_rad": [float(a) for a in measured],
            "commanded_angles_rad": self.commanded_angles_rad.tolist(),
            "points_scanner": points_scanner,
            "point_step": np.repeat(np.arange(self.steps, dtype=np.int32), counts),
            "step_counts": counts.tolist(),
            "scan_angles_rad": np.arctan2(points_scanner[:, 1], points_scanner[:, 0]),
            "geometry": self.geometry.to_dict(),
            "frame": "mount",
            "sweep_index": self._sweeps,
            "sweep_seconds": time.monotonic() - started,
            "servo_retries": self.servo.retried - retries_before,
        }
        if self._truth is not None:
            meta.update({"simulated": True, **self._truth.ground_truth()})
        self._sweeps += 1
        return Sample(t0, points=self.geometry.transform(points_scanner, angles), intensity=intensity, meta=meta)

    @staticmethod
    def scans_of(sample: Sample) -> list[tuple[float, np.ndarray, np.ndarray]]:
        """The raw sweep of a sample from :meth:`read`: ``(servo angle (rad), points scanner frame (m),
        intensity)`` per step, as :meth:`SweepGeometry.assemble` and the sweep calibration take it."""
        step = np.asarray(sample.meta["point_step"])
        pts = np.asarray(sample.meta["points_scanner"])
        inten = np.zeros(len(pts), np.float32) if sample.intensity is None else np.asarray(sample.intensity)
        return [(float(a), pts[step == k], inten[step == k]) for k, a in enumerate(sample.meta["servo_angles_rad"])]

    def close(self) -> None:
        """Close the scanner, the servo and the simulator. Safe twice."""
        scanner, self.scanner = self.scanner, None
        self._truth = None
        if scanner is not None:
            scanner.close()
        scanner_sim, self._scanner_sim = self._scanner_sim, None
        if scanner_sim is not None:
            scanner_sim.stop()
        servo, self.servo = self.servo, None
        if servo is not None:
            servo.close()
        sim, self._sim = self._sim, None
        if sim is not None:
            sim.stop()


def points_in_base(sample: Sample) -> np.ndarray:
    """A simulated sweep's points (m) mapped into base_link with its ``T_base_mount`` (truth)."""
    return transform_points(np.asarray(sample.meta["T_base_mount"]), np.asarray(sample.points))
