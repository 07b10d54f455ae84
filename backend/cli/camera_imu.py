"""``calib-studio camera-imu``: the rotation, translation and time offset between a camera and an IMU, from a board
waved in front of the camera (Kalibr's ``kalibr_calibrate_imu_camera``); ``calib-studio lidar-imu``: the rotation and
time offset between a LiDAR and an IMU, from the rig turned in a static scene.

Both read the IMU from a CSV file (``--imu imu.csv``), from a ROS bag's sensor_msgs/Imu topic (``--imu BAG
--imu-topic /imu0``: a ROS 2 bag folder, ``.mcap``, ``.db3`` or ROS 1 ``.bag``, read by
:func:`~backend.devices.rosbag_source.read_imu_topic`) or from a Livox recording's built-in IMU (``--imu
recording.lvx``, :func:`~backend.devices.lvx_file.read_lvx_imu`), through :func:`~backend.devices.imu_files.read_imu`;
the JSON is the same either way."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from backend.cli._common import add_camera_corners_arguments, prints_summary, progress_to_stderr, warn
from backend.core.errors import InputError

if TYPE_CHECKING:
    from backend.core.result import TransformResult

IMU_HELP = ("IMU samples: a CSV t_ns,wx,wy,wz,ax,ay,az (rad/s, m/s²), a ROS bag (ROS 2 folder, .mcap, .db3 or ROS 1 "
            ".bag) with --imu-topic, or a Livox .lvx recording (its built-in IMU)")
IMU_TOPIC_HELP = "the bag's sensor_msgs/Imu topic, e.g. /imu0 (with --imu BAG)"


def add_parser(sub: argparse._SubParsersAction) -> None:
    ci = sub.add_parser("camera-imu", help="camera-IMU extrinsics and time offset (t_imu = t_cam + offset) from a "
                                           "board waved in front of the camera")
    add_camera_corners_arguments(ci)
    ci.add_argument("--imu", type=Path, required=True, help=IMU_HELP)
    ci.add_argument("--imu-topic", metavar="TOPIC", help=IMU_TOPIC_HELP)
    ci.add_argument("--board", required=True, help="the board, e.g. aprilgrid:6x6:0.088:0.3")
    ci.add_argument("--knots-per-second", type=float, default=50.0, metavar="HZ",
                    help="knots of the trajectory spline per second (default 50)")
    ci.add_argument("--gravity", type=float, default=9.80665, metavar="M_S2", help="gravity's magnitude (m/s²)")
    ci.add_argument("--imu-model", choices=("calibrated", "scale-misalignment"), default="calibrated",
                    help="the IMU's model, as Kalibr's --imu-models: calibrated (ideal axes; default) or "
                         "scale-misalignment (also fits the axes' scale, misalignment and the gyro's g-sensitivity); "
                         "the other model is fitted as a cross-check either way")
    ci.add_argument("--json", action="store_true", help="print the result as one JSON object")
    ci.set_defaults(handler=prints_summary(run_camera_imu))

    li = sub.add_parser("lidar-imu", help="LiDAR-IMU rotation, time offset (t_imu = t_lidar + offset) and, where the "
                                          "motion determines it, translation, from the rig turned in a static scene")
    li.add_argument("--scans", type=Path, required=True,
                    help="a folder of clouds (.pcd .ply .las .laz .npy .lvx) named by their time stamp in ns")
    li.add_argument("--imu", type=Path, required=True, help=IMU_HELP)
    li.add_argument("--imu-topic", metavar="TOPIC", help=IMU_TOPIC_HELP)
    li.add_argument("--json", action="store_true", help="print the result as one JSON object")
    li.set_defaults(handler=prints_summary(run_lidar_imu))


def run_lidar_imu(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.lidar_imu.service import solve_files, summary

    result = solve_files(args.scans, args.imu, progress_to_stderr(False), imu_topic=args.imu_topic)
    _report(result)
    out = summary(result)
    if not args.json:
        determined = out["std"]["trans_m"][0] is not None
        translation = (f"translation sigma (mm) {[round(1e3 * s, 2) for s in out['std']['trans_m']]}" if determined
                       else "translation not determined by this motion")
        print(f"T_lidar_imu:\n{result.T_parent_child.round(6)}\ntime offset {1e3 * out['time_offset_s']:.3f} "
              f"ms (t_imu = t_lidar + offset), sigma {1e3 * out['std']['time_s']:.3f} ms; rotation sigma (deg) "
              f"{[round(s, 4) for s in out['std']['rot_deg']]}; {translation}")
    return out


def run_camera_imu(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.camera_imu.service import solve_files, summary
    from backend.calib.camera_imu.solver import CameraImuSettings

    if not 5 <= args.knots_per_second <= 400:
        raise InputError(f"expected 5 to 400 knots per second, got {args.knots_per_second}", "--knots-per-second")
    if not 9.7 <= args.gravity <= 9.9:
        raise InputError(f"expected gravity's magnitude on Earth, 9.7 to 9.9 m/s², got {args.gravity}", "--gravity")
    settings = CameraImuSettings(knots_per_s=args.knots_per_second, gravity_m_s2=args.gravity,
                                 imu_model=args.imu_model)
    result = solve_files(args.camera, args.images or args.detections, args.imu, args.board, settings,
                         progress_to_stderr(False), imu_topic=args.imu_topic)
    _report(result)
    out = summary(result)
    if not args.json:
        std = out["std"]
        print(f"T_cam_imu:\n{result.T_parent_child.round(6)}\ntime offset {1e3 * out['time_offset_s']:.3f} ms "
              f"(t_imu = t_cam + offset), sigma {1e3 * std['time_s']:.3f} ms\nsigma translation (mm) "
              f"{[round(1e3 * s, 2) for s in std['trans_m']]}, rotation (deg) {[round(s, 4) for s in std['rot_deg']]}")
    return out


def _report(result: TransformResult) -> None:
    """The result's warnings and verdict on stderr."""
    for warning in result.warnings:
        warn(warning)
    print(f"verdict: {result.verdict.level}: {'; '.join(result.verdict.reasons)}", file=sys.stderr)
