"""LiDAR-to-LiDAR workflow shared by the API, the studio and the CLI.

capture or import clouds -> store them -> solve ``T_target_source`` from pairs of
captures (one per scene, or several) -> store the result with its verdict -> accept it into
the rig as the source LiDAR's ``T_parent_child`` with its covariance. A result that did not
converge is stored (so the user can see why) but cannot be accepted; a ``check`` verdict needs
the user's confirmation.
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from backend.core.errors import InputError
from backend.core.rig import Rig
from backend.devices.base import Sample
from backend.devices.cloud_files import CLOUD_EXTENSIONS, read_cloud
from backend.solvers.lidar_lidar import LidarLidarResult, LidarLidarSettings
from backend.solvers.lidar_lidar_scenes import register_pairs
from backend.solvers.result import ProgressCallback, no_progress
from backend.store.schema import CaptureRecord
from backend.store.session import Session

LIDAR_KINDS = ("lidar3d", "lidar2d", "depth")


def lidar_names(rig: Rig) -> list[str]:
    """The rig's LiDAR and depth sensors, in rig order."""
    return [f.name for f in rig.frames.values() if f.kind in LIDAR_KINDS]


def check_lidar(session: Session, sensor: str) -> None:
    """Refuse (naming the sensor) anything but a LiDAR or depth sensor of the rig."""
    kind = session.rig.get(sensor).kind
    if kind not in LIDAR_KINDS:
        raise InputError(f"sensor {sensor!r} is a {kind}, not a LiDAR or depth sensor", "sensor")


def slot(source: str, target: str) -> str:
    """The acceptance slot of a source-to-target transform."""
    return f"{source}/T_{target}_{source}"


def store_cloud(session: Session, sensor: str, sample: Sample, *, device: str, source: str | None = None
                ) -> CaptureRecord:
    """Keep one cloud (live or imported) in the sensor's frame."""
    check_lidar(session, sensor)
    if sample.points is None or len(sample.points) == 0:
        raise InputError(f"{source or device}: the cloud holds no points", source or device)
    return session.add_cloud_capture(sensor, sample.points, sample.intensity, {
        "timestamp_s": sample.timestamp_s, "device": device, "source": source, "meta": sample.storable_meta()})


def import_clouds(session: Session, sensor: str, files: list[tuple[str, bytes | Path]],
                  progress: ProgressCallback = no_progress) -> list[CaptureRecord]:
    """Add uploaded cloud files (their bytes, or where they were saved) as captures; any unreadable file rejects
    the whole batch, naming it, and nothing of the batch is stored."""
    check_lidar(session, sensor)
    clouds = []
    for i, (name, data) in enumerate(files):
        progress(i / max(len(files), 1), f"reading {name}")
        clouds.append(read_uploaded_cloud(name, data))
    return [store_cloud(session, sensor, sample, device="upload", source=sample.meta["source"]) for sample in clouds]


def read_uploaded_cloud(name: str, data: bytes | Path) -> Sample:
    """An uploaded cloud file's points as a sample (``meta``: the base ``source`` name kept and the points
    dropped as non-finite); ``data`` is the file's bytes or the path it was saved to (an upload streamed to
    disk). Raises :class:`InputError` naming the file when it cannot be read."""
    safe_name = Path(name).name
    if Path(safe_name).suffix.lower() not in CLOUD_EXTENSIONS:
        raise InputError(f"{safe_name}: not a point-cloud file (expected {', '.join(CLOUD_EXTENSIONS)})", safe_name)
    try:
        if isinstance(data, Path):
            cloud = read_cloud(data)
        else:
            with tempfile.TemporaryDirectory() as folder:
                path = Path(folder) / safe_name
                path.write_bytes(data)
                cloud = read_cloud(path)
    except InputError as exc:  # name the upload, not the server's temporary path
        exc.input = safe_name
        raise
    return Sample(0.0, points=cloud.points, intensity=cloud.intensity,
                  meta={"source": safe_name, "dropped_non_finite": cloud.dropped_non_finite})


def pair_ids(session: Session, source: str, target: str) -> list[tuple[str, str]]:
    """The default frame pairs, (source capture id, target capture id): the i-th cloud of each sensor."""
    check_lidar(session, source)
    check_lidar(session, target)
    source_ids = [c.id for c in session.captures(source) if c.n_points]
    target_ids = [c.id for c in session.captures(target) if c.n_points]
    if not source_ids or not target_ids:
        empty = source if not source_ids else target
        raise InputError(f"no clouds captured for {empty} yet; capture or import clouds of both LiDARs", empty)
    return list(zip(source_ids, target_ids, strict=False))


def capture_pairs(session: Session, source: str, target: str,
                  pairs: list[tuple[str, str]] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Clouds to register: the given (source id, target id) pairs, or :func:`pair_ids`."""
    check_lidar(session, source)
    check_lidar(session, target)
    if pairs is None:
        pairs = pair_ids(session, source, target)
    return [(session.capture_cloud(source, s)[0], session.capture_cloud(target, t)[0]) for s, t in pairs]


def solve_session(session: Session, source: str, target: str, *, T_init: np.ndarray | None = None,
                  use_rig_guess: bool = True, settings: LidarLidarSettings | None = None,
                  pairs: list[tuple[str, str]] | None = None,
                  progress: ProgressCallback = no_progress) -> tuple[str, LidarLidarResult]:
    """Register ``source`` into ``target`` over the frame ``pairs`` (default :func:`pair_ids`) and store the
    result (not yet accepted). Pairs from different places are scenes that cross-check each other (see
    :mod:`backend.solvers.lidar_lidar_scenes`).

    The initial guess is ``T_init`` if given, else the rig's current transform
    (manual nudges included) when ``use_rig_guess``, else global registration.
    """
    pairs = pair_ids(session, source, target) if pairs is None else [tuple(p) for p in pairs]
    clouds = capture_pairs(session, source, target, pairs)
    if T_init is None and use_rig_guess:
        T_init = session.rig.T_a_b(target, source)
    result = register_pairs(clouds, T_init, settings, progress,
                            names=[(f"{source} {s}", f"{target} {t}") for s, t in pairs])
    record = result.to_record() | {"target": target}
    result_id = session.add_result(source, record, inputs=[f"{s}:{t}" for s, t in pairs])
    return result_id, result


def apply_lidar_lidar(rig: Rig, record: dict[str, Any]) -> None:
    """Write a stored ``T_target_source`` into the rig as the source frame's mounting, with its covariance
    (translation in target axes, rotation about source axes; see :meth:`Rig.set_relative`)."""
    if record.get("kind") != "lidar_lidar":
        raise InputError(f"result {record['id']} is a {record.get('kind')} result, not lidar_lidar", "result")
    if not record.get("converged", False):
        raise InputError(f"result {record['id']} did not converge to a good fit and cannot be accepted: "
                         + "; ".join(record.get("warnings", [])), "result")
    covariance = np.array([[np.nan if v is None else v for v in row] for row in record["covariance"]], float)
    rig.set_relative(record["sensor"], record["target"], np.array(record["T_target_source"]), covariance)


def accept(session: Session, source: str, result_id: str, confirm: bool = False) -> None:
    """Make a stored LiDAR-to-LiDAR result the source LiDAR's mounting (also how a user reverts)."""
    record = session.result(result_id)
    if record.get("kind") != "lidar_lidar":  # before its 'target' is read: another kind has none
        raise InputError(f"result {result_id} is a {record.get('kind')} result, not lidar_lidar", "result")
    if record["sensor"] != source:
        raise InputError(f"result {result_id} belongs to {record['sensor']}, not {source}", "result")
    session.accept(slot(source, record["target"]), result_id, apply_lidar_lidar, confirm)
