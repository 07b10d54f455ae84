"""Exports of accepted results, shared by the API, the studio and the CLI."""

from __future__ import annotations

from typing import Literal

from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.exports.kalibr_camchain import dump_kalibr_camchain
from backend.exports.opencv_yaml import dump_opencv_yaml
from backend.exports.rig_transforms import dump_rig_transforms
from backend.exports.ros_camera_info import dump_camera_info
from backend.store.session import Session

ExportFormat = Literal["camera_info", "opencv", "rig", "kalibr"]
EXPORT_FORMATS: dict[str, str] = {
    "camera_info": "ROS camera_info YAML (camera_calibration_parsers)",
    "opencv": "OpenCV FileStorage YAML",
    "rig": "the rig's transforms with sigmas and static_transform_publisher lines",
    "kalibr": "Kalibr camchain YAML (T_cn_cnm1 chain)",
}


def accepted_camera(session: Session, sensor: str) -> CameraIntrinsics:
    frame = session.rig.get(sensor)
    if frame.kind != "camera":
        raise InputError(f"sensor {sensor!r} is a {frame.kind}, not a camera", "sensor")
    if frame.intrinsics is None:
        raise InputError(f"{sensor} has no intrinsics yet; solve and accept a calibration first", sensor, 409)
    return frame.intrinsics


def export_text(session: Session, fmt: ExportFormat, sensor: str | None = None) -> tuple[str, str]:
    """Return (file name, YAML text) of one export; ``sensor`` is used by camera_info and opencv only."""
    if fmt == "rig":
        return f"{session.name}_transforms.yaml", dump_rig_transforms(session.rig)
    if fmt == "kalibr":
        return f"{session.name}_camchain.yaml", kalibr_camchain(session)
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


def kalibr_camchain(session: Session) -> str:
    """Kalibr camchain YAML of every camera of the rig that has intrinsics, in the rig's order.

    cam0 is the first such camera; ``T_ref_cam`` is ``rig.T_a_b(cam0, cam)``. Raises
    :class:`InputError` (409) naming the cameras without intrinsics if fewer than two
    have them, and the camchain writer's :class:`InputError` for a camera Kalibr cannot
    describe (e.g. a non-negligible ``k3``).
    """
    rig = session.rig
    cameras = rig.sensors("camera")
    ready = [frame for frame in cameras if frame.intrinsics is not None]
    if len(ready) < 2:
        missing = [frame.name for frame in cameras if frame.intrinsics is None]
        if len(cameras) < 2:
            problem = f"the rig has {len(cameras)} camera(s) ({', '.join(f.name for f in cameras) or 'none'})"
        else:
            problem = f"{', '.join(missing)} {'has' if len(missing) == 1 else 'have'} no intrinsics yet"
        raise InputError(
            f"the kalibr export needs at least two cameras with intrinsics; {problem}; "
            "add cameras, solve and accept their intrinsics first",
            ", ".join(missing) or "rig",
            409,
        )
    reference = ready[0].name
    return dump_kalibr_camchain(
        [(frame.name, frame.intrinsics) for frame in ready],
        {frame.name: rig.T_a_b(reference, frame.name) for frame in ready},
    )
