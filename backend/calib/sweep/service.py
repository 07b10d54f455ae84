"""Swept-scanner workflow shared by the API and the studio.

capture a sweep through the ordinary cloud path (:func:`backend.calib._session.store_cloud`:
points in the mount frame, the sweep meta beside them) -> calibrate the sweep geometry from a
stored capture -> store the result -> accept it (:func:`backend.calib.rig.service.accept`, whose effect
is :func:`apply_sweep_geometry`) as the sensor's ``device["geometry"]`` (the next sweeps are
assembled with it). A result that did not converge, leaves parameters undetermined or made the
planes less flat is stored (so the user can see why) but cannot be accepted. Frames: the sensor's
frame is the sweep's ``mount`` frame (:mod:`backend.core.sweep_geometry`); a stored result's ``transform``
is the scanner's pose in it at servo zero, parent ``<sensor>``, child ``<sensor>_scanner``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np

from backend.calib._session import require_kind, result_of, store_cloud
from backend.calib.sweep.checks import LABELS as LABELS  # re-exported: the parameters' names as shown
from backend.calib.sweep.solver import SweepCalibrationResult, SweepCalibrationSettings, calibrate_sweep
from backend.core.errors import InputError, NotFoundError
from backend.core.result import ProgressCallback, no_progress
from backend.core.rig import Rig
from backend.core.sweep_geometry import (
    SWEEP_META_KEYS,
    ScanAtAngle,
    SweepGeometry,
    intensity_image,
    scans_from_capture,
    stack_scans,
)
from backend.devices.base import create_device
from backend.store.schema import CaptureRecord
from backend.store.session import Session

DRIVER = "swept_scanner"
KIND = SweepCalibrationResult.kind
MAX_IMAGE_COLUMNS = 4096
ImageMode = Literal["intensity", "range"]


def is_swept(session: Session, sensor: str) -> bool:
    """True if the sensor is driven by the ``swept_scanner`` driver (a 2D scanner on a servo)."""
    return session.rig.get(sensor).device.get("driver") == DRIVER


def check_swept(session: Session, sensor: str) -> None:
    """Refuse (naming ``sensor``) a sensor that is not a swept scanner, saying which driver it has."""
    if not is_swept(session, sensor):
        driver = session.rig.get(sensor).device.get("driver")
        raise InputError(f"sensor {sensor!r} is not a swept scanner (its driver is {driver!r}, not {DRIVER!r})",
                         "sensor")


def swept_captures(session: Session, sensor: str) -> list[CaptureRecord]:
    """The captures of ``sensor`` that hold a whole sweep (its cloud and the sweep meta), oldest first."""
    return [r for r in session.captures(sensor) if r.n_points and all(k in r.meta for k in SWEEP_META_KEYS)]


def swept_capture(session: Session, sensor: str, capture_id: str | None = None) -> CaptureRecord:
    """The record of a stored sweep of ``sensor``: ``capture_id``, or the latest capture holding the sweep meta.

    Raises :class:`InputError` (404 for an unknown sensor or capture) naming the sensor or capture.
    """
    check_swept(session, sensor)
    if capture_id is None:
        swept = swept_captures(session, sensor)
        if not swept:
            raise InputError(f"no sweep captured for {sensor} yet; capture a sweep first", sensor)
        return swept[-1]
    record = next((r for r in session.captures(sensor) if r.id == capture_id and r.n_points), None)
    if record is None:
        raise NotFoundError(f"no cloud capture {capture_id!r} for sensor {sensor!r}", "capture")
    missing = [k for k in SWEEP_META_KEYS if k not in record.meta]
    if missing:
        raise InputError(f"capture {capture_id} of {sensor} holds no sweep (its meta lacks {', '.join(missing)}); "
                         f"capture a sweep with the swept scanner", "capture")
    return record


def capture_scans(session: Session, sensor: str, capture: CaptureRecord) -> list[ScanAtAngle]:
    """The raw sweep (per step: servo angle (rad), scanner-frame points (m), intensity) of a stored capture."""
    points, intensity = session.capture_cloud(sensor, capture.id)
    try:
        return scans_from_capture(points, intensity, capture.meta)
    except (ValueError, TypeError) as exc:
        raise InputError(f"capture {capture.id} of {sensor}: {exc}", "capture") from None


def up_in_sensor(rig: Rig, sensor: str) -> tuple[float, float, float]:
    """The root frame's +z (up, with base_link level) expressed in the sensor's (mount) frame."""
    up = rig.T_root_frame(sensor)[:3, :3].T @ np.array([0.0, 0.0, 1.0])
    return float(up[0]), float(up[1]), float(up[2])


def rig_geometry(rig: Rig, sensor: str) -> SweepGeometry:
    """The geometry the sensor's sweeps are assembled with now (its ``device["geometry"]``)."""
    try:
        return SweepGeometry.from_dict(rig.get(sensor).device.get("geometry"))
    except (ValueError, TypeError) as exc:
        raise InputError(f"sensor {sensor!r}: bad device geometry: {exc}", "device.geometry") from None


def solve_session(session: Session, sensor: str, capture_id: str | None = None, *,
              settings: SweepCalibrationSettings | None = None, progress: ProgressCallback = no_progress) -> str:
    """Calibrate the sweep geometry from one stored sweep and store the result (not yet accepted).

    Args:
        capture_id: the sweep to use; default the latest swept capture of ``sensor``.
        settings: solver settings; ``up_mount`` (the floor's up direction in the mount frame) defaults to
            :func:`up_in_sensor`. The solve starts from the rig's current geometry (:func:`rig_geometry`).
        progress: cancelling the job raises at the next report, leaving the session as it was.

    Returns the id of the stored ``sweep`` result; its ``inputs`` and ``capture`` name the capture.
    """
    progress(0.0, f"loading the sweep of {sensor}")
    capture = swept_capture(session, sensor, capture_id)
    scans = capture_scans(session, sensor, capture)
    initial = rig_geometry(session.rig, sensor)
    settings = settings or SweepCalibrationSettings()
    if settings.up_mount is None:
        settings = replace(settings, up_mount=up_in_sensor(session.rig, sensor))
    result = calibrate_sweep(scans, initial, settings, progress)
    record = result.to_record() | {"transform": result.transform.named(sensor, f"{sensor}_scanner").to_record(),
                                   "capture": capture.id}
    return session.add_result(sensor, record, inputs=[capture.id])


def _refusal(record: dict[str, Any]) -> list[str]:
    """Why a stored sweep result must not be accepted (empty if it may)."""
    problems = []
    if not record.get("converged", False):
        problems.append("did not converge")
    covariance = record.get("covariance") or [[None]]  # none stored: nothing is determined
    if any(v is None for row in covariance for v in row):
        problems.append("leaves parameters undetermined")
    if record.get("rms_after_m", math.inf) > record.get("rms_before_m", -math.inf):
        problems.append("made the planes less flat")
    return problems


def apply_sweep_geometry(rig: Rig, record: dict[str, Any]) -> None:
    """Write a stored sweep geometry into the sensor's ``device["geometry"]`` (the mounting stays as it is): the
    effect of accepting it (:func:`backend.calib.rig.service.accept`, slot ``"<sensor>/sweep"``). Not a rig-graph
    edge. Refuses (:class:`InputError` on ``result``) a result that did not converge, leaves parameters
    undetermined or made the planes less flat."""
    require_kind(record, KIND)
    problems = _refusal(record)
    if problems:
        warnings = "; ".join(record.get("warnings", []))
        raise InputError(f"result {record['id']} {' and '.join(problems)} and cannot be accepted"
                         + (f": {warnings}" if warnings else ""), "result")
    frame = rig.get(record["sensor"])
    frame.device = {**frame.device, "geometry": record["geometry"]}


def sweep_result(session: Session, sensor: str, result_id: str) -> dict[str, Any]:
    """The stored sweep geometry result ``result_id`` of the swept scanner ``sensor``; raises
    :class:`InputError` naming the sensor or the result when either is not that."""
    check_swept(session, sensor)
    return result_of(session, KIND, result_id, sensor)


def _beam_columns(scan_angles: np.ndarray, steps: np.ndarray) -> int:
    """Columns giving each beam of a scan its own: the angular span over the median beam spacing."""
    if len(scan_angles) < 2:
        return 1
    order = np.lexsort((scan_angles, steps))
    gaps = np.diff(scan_angles[order])[np.diff(steps[order]) == 0]
    gaps = gaps[gaps > 1e-5]
    if not len(gaps):
        return 1
    span = float(scan_angles.max() - scan_angles.min())
    return int(min(round(span / float(np.median(gaps))) + 1, MAX_IMAGE_COLUMNS))


def capture_sweep(session: Session, sensor: str, progress: ProgressCallback = no_progress) -> CaptureRecord:
    """Run one full sweep of the sensor's device (open, sweep, close) and store it as a capture.

    The device is the rig's (``device`` settings, assembled with the geometry accepted so far). A device
    that cannot be opened or is lost mid-sweep raises :class:`DeviceError`; nothing is stored then.
    """
    check_swept(session, sensor)
    settings = session.rig.get(sensor).device
    progress(0.05, f"opening {settings.get('servo_port')} and the scanner")
    with create_device(settings) as device:
        progress(0.2, f"sweeping {sensor} ({device.describe()})")
        sample = device.read()
    progress(0.95, "storing the sweep")
    return store_cloud(session, sensor, sample, device=device.describe())


def _assembled_sweep(session: Session, sensor: str, capture_id: str | None = None, *, result_id: str | None = None
                     ) -> tuple[CaptureRecord, list[ScanAtAngle], SweepGeometry]:
    """A stored sweep (latest by default), its raw scans and the geometry to assemble them with: ``result_id``'s
    when given, else the one it was captured with."""
    capture = swept_capture(session, sensor, capture_id)
    scans = capture_scans(session, sensor, capture)
    if result_id is None:
        return capture, scans, SweepGeometry.from_dict(capture.meta["geometry"])
    return capture, scans, SweepGeometry.from_dict(sweep_result(session, sensor, result_id)["geometry"])


@dataclass
class SweepView:
    """A stored sweep as the studio shows it, assembled with one geometry."""

    capture: CaptureRecord
    points_mount: np.ndarray
    """(M, 3) the sweep's points in the mount frame (m)."""
    image: np.ndarray
    """uint8 H x W LiDAR image (see :func:`sweep_view`)."""


def sweep_view(session: Session, sensor: str, capture_id: str | None = None, *, result_id: str | None = None,
               mode: ImageMode = "intensity") -> SweepView:
    """A stored sweep (latest by default) re-assembled with ``result_id``'s geometry when given, else with the
    geometry it was captured with: its cloud and its LiDAR image.

    The image has one row per servo step (first step on top) and one column per beam (scan angle rising to
    the right); ``mode`` ``"intensity"`` (mean return intensity, stretched) or ``"range"`` (near = bright,
    range from the mount origin); 0 = no return.
    """
    if mode not in ("intensity", "range"):
        raise InputError(f"image mode must be 'intensity' or 'range', not {mode!r}", "mode")
    capture, scans, geometry = _assembled_sweep(session, sensor, capture_id, result_id=result_id)
    points_scanner, servo, intensity = stack_scans(scans)
    steps = np.repeat(np.arange(len(scans)), [len(s[1]) for s in scans])
    scan_angles = np.arctan2(points_scanner[:, 1], points_scanner[:, 0])
    points_mount = geometry.transform(points_scanner, servo)
    shape = (len(scans), _beam_columns(scan_angles, steps))
    image = intensity_image(points_mount, intensity, servo, scan_angles, shape)
    return SweepView(capture, points_mount, image.intensity if mode == "intensity" else image.range)


def sweep_image(session: Session, sensor: str, capture_id: str, *, result_id: str | None = None,
                mode: ImageMode = "intensity") -> np.ndarray:
    """The LiDAR image of :func:`sweep_view` (for the API's PNG)."""
    return sweep_view(session, sensor, capture_id, result_id=result_id, mode=mode).image
