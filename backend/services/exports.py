"""Exports of accepted results, shared by the API, the studio and the CLI."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from backend.calib.rig.service import solve_rig
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError, shorten
from backend.core.rig import Frame, Rig
from backend.exports.camera_json import dump_camera_json
from backend.exports.formats import CONVENTION_FORMATS, CONVENTIONS, EXPORT_FORMATS, Convention, ExportFormat
from backend.exports.frame_tree import ancestors
from backend.exports.kalibr_camchain import dump_kalibr_camchain, kalibr_refusal
from backend.exports.mrcal_cameramodel import dump_mrcal_cameramodel, mrcal_refusal
from backend.exports.opencv_yaml import dump_opencv_yaml, opencv_refusal
from backend.exports.pose_table import dump_pose_table
from backend.exports.rig_transforms import dump_rig_transforms
from backend.exports.ros2_launch import dump_ros2_launch
from backend.exports.ros_camera_info import dump_camera_info, ros_refusal
from backend.exports.urdf import dump_urdf
from backend.store.session import Session

MEDIA_TYPES: dict[str, str] = {"camera-json": "application/json", "mrcal": "text/plain", "urdf": "application/xml",
                               "launch": "text/x-python", "pose-table": "text/csv"}
"""The media type of each format that is not YAML (the others are ``application/yaml``)."""


def accepted_camera(session: Session, sensor: str) -> CameraIntrinsics:
    """The intrinsics of camera ``sensor``; :class:`InputError` naming it if it is no camera, or (409) has none."""
    frame = session.rig.get(sensor)
    if frame.kind != "camera":
        raise InputError(f"sensor {sensor!r} is a {frame.kind}, not a camera", "sensor")
    if frame.intrinsics is None:
        raise InputError(f"{sensor} has no intrinsics yet; solve and accept a calibration first", sensor, 409)
    return frame.intrinsics


def camera_exports(name: str, camera: CameraIntrinsics) -> dict[str, str | None]:
    """Each one-camera export and whether it carries ``camera`` as it is: None if it does, else why not (what to
    do instead). ``camera_info`` writes ROS's ``plumb_bob`` or ``equidistant``, ``camera-json`` any model under its
    name, ``opencv`` any but the splined model, ``mrcal`` pinhole-radtan and the splined model, and Kalibr's camchain
    radtan [k1, k2, r1, r2] or equidistant, without a k3 that matters."""
    return {"camera_info": ros_refusal(camera), "opencv": opencv_refusal(camera), "camera-json": None,
            "mrcal": mrcal_refusal(camera), "kalibr": kalibr_refusal(name, camera)}


def export_text(session: Session, fmt: ExportFormat, sensor: str | None = None, *,
                convention: Convention | None = None, cameras: Sequence[str] | None = None) -> tuple[str, str]:
    """Return (file name, text) of one export of the session's rig.

    ``sensor`` is the camera of camera_info, opencv, camera-json and mrcal (the other formats ignore it);
    ``convention`` (default ``optical``) applies to rig, urdf and launch only; ``cameras`` (default: every camera
    Kalibr can describe) to kalibr only. A choice given for a format it does not apply to is refused (422), as is an
    unknown format or convention. Data the rig lacks is refused naming the sensor: a camera without
    intrinsics, a frame that no edge of the rig graph (a mounting guess or an accepted calibration) connects
    to the root (409, with the frames it does connect to).
    """
    if fmt not in EXPORT_FORMATS:
        raise InputError(f"unknown export format {shorten(fmt)}; expected one of {list(EXPORT_FORMATS)}", "format")
    if convention is not None and fmt not in CONVENTION_FORMATS:
        raise InputError(f"the {fmt} export has no convention choice (cameras are optical frames); convention "
                         f"applies to {', '.join(CONVENTION_FORMATS)}", "convention")
    if convention is not None and convention not in CONVENTIONS:
        raise InputError(f"unknown convention {shorten(convention)}; expected one of {list(CONVENTIONS)}",
                         "convention")
    if cameras is not None and fmt != "kalibr":
        raise InputError(f"the {fmt} export takes no camera subset; cameras applies to kalibr", "cameras")
    convention = convention or "optical"
    suffix = "" if convention == "optical" else f"_{convention}"
    if fmt in CONVENTION_FORMATS or fmt == "pose-table":
        _refuse_unconnected(solve_rig(session).unconnected, session.rig)
    if fmt == "pose-table":
        return f"{session.name}_pose_table.csv", dump_pose_table(session.rig)
    if fmt == "rig":
        return f"{session.name}_transforms{suffix}.yaml", dump_rig_transforms(session.rig, convention)
    if fmt == "urdf":
        return f"{session.name}{suffix}.urdf", dump_urdf(session.rig, session.name, convention)
    if fmt == "launch":
        return (f"{session.name}_static_tf{suffix}.launch.py",
                dump_ros2_launch(session.rig, convention, f"for session {session.name}"))
    if fmt == "kalibr":
        return f"{session.name}_camchain.yaml", kalibr_camchain(session, cameras)
    if sensor is None:
        raise InputError(f"the {fmt} export needs a camera sensor", "sensor")
    camera = accepted_camera(session, sensor)
    if fmt == "camera_info":
        return f"{sensor}.yaml", dump_camera_info(camera, sensor)
    result_id = session.accepted(f"{sensor}/intrinsics")
    record = session.result(result_id) if result_id else None
    if fmt == "camera-json":
        kept = ("rms_px", "std", "correlation", "photogrammetric", "splined", "board_flex")
        return f"{sensor}.json", dump_camera_json(camera, sensor, {key: record[key] for key in kept
                                                                   if record and key in record})
    if fmt == "mrcal":
        return f"{sensor}.cameramodel", dump_mrcal_cameramodel(camera, sensor)
    extra = {"avg_reprojection_error": record["rms_px"]} if record else None
    return f"{sensor}_opencv.yaml", dump_opencv_yaml(camera, extra)


def _refuse_unconnected(unconnected: Mapping[str, Sequence[str]], rig: Rig, names: Sequence[str] | None = None
                        ) -> None:
    """:class:`InputError` (409) naming the frames of ``names`` (default: all) that no edge of the rig graph (a
    mounting guess or an accepted calibration) connects to the root, and the frames each connects to."""
    lost = [name for name in (rig.frames if names is None else names) if name in unconnected]
    if not lost:
        return
    links = "; ".join(f"{name} connects to {', '.join(unconnected[name]) or 'no other frame'}" for name in lost)
    raise InputError(
        f"{', '.join(lost)}: not connected to {rig.root} by any edge (no mounting guess, no accepted calibration), "
        f"so the rig has no transform for {'it' if len(lost) == 1 else 'them'} ({links}); give "
        f"{'it' if len(lost) == 1 else 'each'} a mounting guess or accept a calibration linking it to the rig",
        ", ".join(lost), 409)


def kalibr_camchain(session: Session, cameras: Sequence[str] | None = None) -> str:
    """Kalibr camchain YAML of ``cameras`` (in that order), or by default of every camera of the rig with
    intrinsics Kalibr can describe (in the rig's order; those left out are named in a comment at the top).

    cam0 is the first camera; ``T_ref_cam`` is ``rig.T_a_b(cam0, cam)``. A named camera that is not in the
    rig (404), not a camera, has no intrinsics or is not connected to the root (409), or that Kalibr cannot
    describe (e.g. a non-negligible ``k3``) raises :class:`InputError` naming it; by default such cameras are
    left out, and fewer than two left raise one (409) naming those without intrinsics and why the others were
    left out. One named camera
    gives a one-camera camchain (what ``kalibr_calibrate_imu_camera`` takes for a single camera).
    With an IMU connected to the root, it is Kalibr's camchain-imucam: each camera also gets ``T_cam_imu`` to the
    rig's first such IMU and ``timeshift_cam_imu`` from the two sensors' clock offsets (a comment at the top names
    the IMU, and any other IMU not written).
    """
    rig = session.rig
    unconnected = solve_rig(session).unconnected
    skipped: list[str] = []
    if cameras is None:
        chosen, skipped, missing = _describable_cameras(rig, unconnected)
        if len(chosen) < 2:
            found = f"the rig has {len(rig.sensors('camera'))} camera(s)"
            raise InputError(
                f"the kalibr export needs at least two cameras with intrinsics Kalibr can describe; "
                f"{'; '.join(skipped) or found}; add cameras, solve and accept their intrinsics first",
                ", ".join(missing) or "rig", 409)
    elif not cameras:
        raise InputError("the kalibr export needs at least one camera; cameras is empty", "cameras")
    else:
        chosen = [_kalibr_camera(rig, name) for name in cameras]
        _refuse_unconnected(unconnected, rig, cameras)
    reference = chosen[0].name
    imus = [frame for frame in rig.sensors("imu") if frame.name not in unconnected]
    imu, header = None, ""
    if imus:
        T_cam_imu = {frame.name: rig.T_a_b(frame.name, imus[0].name) for frame in chosen}
        timeshift = {frame.name: imus[0].clock_offset_s - frame.clock_offset_s for frame in chosen}
        imu = (T_cam_imu, timeshift)
        others = f" (the rig's first IMU; not written: {', '.join(f.name for f in imus[1:])})" if imus[1:] else ""
        header = (f"# camchain-imucam: T_cam_imu maps points in IMU {imus[0].name}{others} into each camera; "
                  "timeshift_cam_imu (s) is t_imu = t_cam + timeshift\n")
    text = dump_kalibr_camchain(
        [(frame.name, frame.intrinsics) for frame in chosen],
        {frame.name: rig.T_a_b(reference, frame.name) for frame in chosen},
        imu=imu,
    )
    return header + "".join(f"# left out: {reason}\n" for reason in skipped) + text


def _describable_cameras(rig: Rig, unconnected: Mapping[str, Sequence[str]]
                         ) -> tuple[list[Frame], list[str], list[str]]:
    """The rig's cameras Kalibr can describe and the rig places, why each other camera is left out, and those
    without intrinsics."""
    chosen, skipped, missing = [], [], []
    for frame in rig.sensors("camera"):
        if frame.intrinsics is None:
            missing.append(frame.name)
            skipped.append(f"{frame.name} has no intrinsics yet")
            continue
        refusal = kalibr_refusal(frame.name, frame.intrinsics)
        if refusal is None and frame.name in unconnected:
            refusal = f"{frame.name} is not connected to {rig.root} by any edge"
        if refusal is None:
            try:
                ancestors(rig, frame.name)
            except InputError as exc:
                refusal = exc.message
        if refusal is None:
            chosen.append(frame)
        else:
            skipped.append(refusal)
    return chosen, skipped, missing


def _kalibr_camera(rig: Rig, name: str) -> Frame:
    """Camera ``name`` of the rig with its intrinsics and a chain of parents to the root, or :class:`InputError`
    naming it (Kalibr's own refusals follow when the camchain is written)."""
    frame = rig.get(name)
    if frame.kind != "camera":
        raise InputError(f"{name} is a {frame.kind}, not a camera; the kalibr export takes cameras", name)
    if frame.intrinsics is None:
        raise InputError(f"{name} has no intrinsics yet; solve and accept its intrinsics first, or leave it out of "
                         "the cameras", name, 409)
    ancestors(rig, name)
    return frame
