"""Registers the simulated sensors with the device layer; import it once, for its effect.

Drivers never import simulators (the dependency runs sim -> devices -> core). Importing this module:

- registers the simulated drivers with :func:`~backend.devices.base.create_device`: ``simulated``
  (:class:`~backend.sim.camera_device.SimulatedCamera`), ``simulated_lidar``
  (:class:`~backend.sim.lidar_device.SimulatedLidar`) and ``sim_depth``
  (:class:`~backend.sim.depth_device.SimulatedDepthCamera`);
- registers the simulated endpoints real drivers talk to with :func:`~backend.devices.base.start_simulator`:
  ``"ydlidar"`` (``ydlidar`` with ``port="sim"``: a :class:`~backend.sim.ydlidar_sim.YdlidarSimulator` on a pty),
  ``"velodyne"`` (``velodyne`` with ``host="sim"``: a :class:`~backend.sim.velodyne_udp.Vlp16UdpSimulator`
  sending to the driver's port), ``"livox"`` (``livox`` with ``host="sim"``: a
  :class:`~backend.sim.livox_sim.LivoxSimulator` broadcasting to the driver's discovery port), ``"dynamixel"``
  (``swept_scanner`` with ``servo_port="sim"``: a
  :class:`~backend.sim.dynamixel_sim.DynamixelSimulator` on a pty) and ``"swept_head"`` (its
  ``scanner={"driver": "sim"}``: a :class:`~backend.sim.swept_head.SimSweptScannerHead` on that servo's horn) and
  ``"hokuyo"`` (``hokuyo`` with ``host="sim"``: a :class:`~backend.sim.hokuyo_sim.HokuyoSimulator` on 127.0.0.1,
  scanning the yard from the demo rig's ``scanner_2d`` mounting, or, for ``swept_scanner`` with
  ``scanner={"driver": "hokuyo", "host": "sim"}``, from the simulated servo's horn: :class:`HokuyoOnServo`).

:mod:`backend.services` imports it, so every front-end (API, studio, CLI) has the simulators; a process that
reaches devices without services (the node agent of ``calib-studio node``) imports it itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from backend.devices.base import register_driver, register_simulator
from backend.sim.camera_device import SimulatedCamera
from backend.sim.demo_rig import demo_rig
from backend.sim.depth_device import SimulatedDepthCamera
from backend.sim.dynamixel_sim import DynamixelSimulator
from backend.sim.hokuyo_sim import HokuyoSimulator
from backend.sim.lidar_device import SimulatedLidar
from backend.sim.livox_sim import LivoxSimulator
from backend.sim.swept_head import SimSweptScannerHead
from backend.sim.vectornav_sim import VN100Simulator
from backend.sim.velodyne_udp import Vlp16UdpSimulator
from backend.sim.ydlidar_sim import YdlidarSimulator

SIMULATED_DRIVERS = (SimulatedCamera, SimulatedLidar, SimulatedDepthCamera)
"""The simulated capture drivers, selectable by their ``driver`` name like any other."""


def demo_lidar3d_pose(sensor: str) -> np.ndarray:
    """Ground-truth ``T_base_lidar`` (4x4, m) of the demo rig's ``lidar3d`` sensor ``sensor``; :class:`ValueError`
    naming the ones there are otherwise."""
    rig = demo_rig()
    frame = rig.frames.get(sensor)
    if frame is None or frame.kind != "lidar3d":
        lidars = [f.name for f in rig.sensors() if f.kind == "lidar3d"]
        raise ValueError(f"no simulated 3D LiDAR named {sensor!r} in the demo rig; available: {lidars}")
    return rig.T_root_frame(sensor)


def start_ydlidar(**settings: Any) -> YdlidarSimulator:
    """A TG30 scanning the yard from the demo rig's ``scanner_2d`` mounting, on a pty (its ``port``)."""
    return YdlidarSimulator(**settings).start()


def start_vn100(**settings: Any) -> VN100Simulator:
    """A VN-100 streaming binary output 1 at 200 Hz on a pty (its ``port``)."""
    return VN100Simulator(**settings).start()


def start_velodyne(port: int, sensor: str = "lidar_top", **settings: Any) -> Vlp16UdpSimulator:
    """A VLP-16 at the demo rig's ground-truth pose of ``sensor`` sending to 127.0.0.1:``port``."""
    return Vlp16UdpSimulator(port, T_base_lidar=demo_lidar3d_pose(sensor), **settings).start()


def start_livox(discovery_port: int, sensor: str = "lidar_front", **settings: Any) -> LivoxSimulator:
    """A Livox SDK 1 LiDAR (an Avia unless ``model`` says otherwise) at the demo rig's ground-truth pose of ``sensor``,
    broadcasting to 127.0.0.1:``discovery_port``."""
    return LivoxSimulator(discovery_port, T_base_lidar=demo_lidar3d_pose(sensor), **settings).start()


def start_dynamixel(**settings: Any) -> DynamixelSimulator:
    """A Dynamixel XM430 on a pty (its ``port``)."""
    return DynamixelSimulator(**settings).start()


def start_swept_head(servo: DynamixelSimulator, **settings: Any) -> SimSweptScannerHead:
    """The ray-cast 2D scanner (not yet opened) on ``servo``'s horn; a bad setting is a :class:`TypeError`."""
    return SimSweptScannerHead(servo, **settings)


@dataclass
class HokuyoOnServo:
    """A simulated UTM-30LX-EW bolted to a simulated servo's horn: the endpoint a ``hokuyo`` driver connects to
    (``host``, ``port``) and the truth its scans are ray-cast from (:meth:`ground_truth`, as the swept head's)."""

    simulator: HokuyoSimulator
    head: SimSweptScannerHead

    @property
    def host(self) -> str:
        return self.simulator.host

    @property
    def port(self) -> int:
        return self.simulator.port

    def ground_truth(self) -> dict[str, Any]:
        return self.head.ground_truth()

    def stop(self) -> None:
        self.simulator.stop()
        self.head.close()


def start_hokuyo(servo: DynamixelSimulator | None = None, **settings: Any) -> HokuyoSimulator | HokuyoOnServo:
    """A UTM-30LX-EW speaking SCIP 2.0 on 127.0.0.1 (its ``host`` and ``port``): scanning the yard from the demo
    rig's ``scanner_2d`` mounting, or, on ``servo``'s horn, from the pose the horn's physical angle and the true
    sweep geometry give (:class:`HokuyoOnServo`; ``settings`` then go to the head, as ``scanner={"driver": "sim"}``
    takes them)."""
    if servo is None:
        return HokuyoSimulator(**settings).start()
    head = SimSweptScannerHead(servo, **settings)
    head.open()
    return HokuyoOnServo(HokuyoSimulator(pose=head.T_yard_scanner, scene=head.scene, range_noise_m=head.range_noise_m,
                                         seed=head.seed).start(), head)


for _driver in SIMULATED_DRIVERS:
    register_driver(_driver)
register_simulator("ydlidar", start_ydlidar)
register_simulator("vn100", start_vn100)
register_simulator("velodyne", start_velodyne)
register_simulator("livox", start_livox)
register_simulator("dynamixel", start_dynamixel)
register_simulator("swept_head", start_swept_head)
register_simulator("hokuyo", start_hokuyo)
