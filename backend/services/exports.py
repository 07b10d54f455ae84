"""Exports of accepted results, shared by the API, the studio and the CLI."""

from __future__ import annotations

from typing import Literal

from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.exports.opencv_yaml import dump_opencv_yaml
from backend.exports.rig_transforms import dump_rig_transforms
from backend.exports.ros_camera_info import dump_camera_info
from backend.store.session import Session

ExportFormat = Literal["camera_info", "opencv", "rig"]
EXPORT_FORMATS: dict[str, str] = {
    "camera_info": "ROS camera_info YAML (camera_calibration_parsers)",
    "opencv": "OpenCV FileStorage YAML",
    "rig": "the rig's transforms with sigmas and static_transform_publisher lines",
}


def accepted_camera(session: Session, sensor: str) -> CameraIntrinsics:
    frame = session.rig.get(sensor)
    if frame.kind != "camera":
        raise InputError(f"sensor {sensor!r} is a {frame.kind}, not a camera", "sensor")
    if frame.intrinsics is None:
        raise InputError(f"{sensor} has no intrinsics yet; solve and accept a calibration first", sensor, 409)
    return frame.intrinsics


def export_text(session: Session, fmt: ExportFormat, sensor: str | None = None) -> tuple[str, str]:
    """Return (file name, YAML text) of one export."""
    if fmt == "rig":
        return f"{session.name}_transforms.yaml", dump_rig_transforms(session.rig)
    if fmt not in EXPORT_FORMATS:
        raise InputError(f"unknown export format {fmt!r}; expected one of {sorted(EXPORT_FORMATS)}", "format")
    if sensor is None:
        raise InputError(f"the {fmt} export needs a camera sensor", "sensor")
    camera = accepted_camera(session, sensor)
    if fmt == "camera_info":
        return f"{sensor}.yaml", dump_camera_info(camera, sensor)
    result_id = session.accepted(f"{sensor}/intrinsics")
    extra = {"avg_reprojection_error": session.result(result_id)["rms_px"]} if result_id else None
    return f"{sensor}_opencv.yaml", dump_opencv_yaml(camera, extra)
