"""Recordings into captures: a ROS 2 bag topic, a Velodyne pcap or a folder of cloud files, imported whole.

Live capture keeps the scan a user chose; an import keeps every ``every``-th scan of a
recording (within a bag's time window), up to ``limit``, each through the ordinary cloud
path (:func:`backend.calib._session.store_cloud`), so it is a capture like any other.
A recording that cannot be opened (missing file, no such topic, unsupported type) fails
before anything is stored. A message that cannot be converted is skipped and reported; a
file found damaged part-way ends the import, keeping the scans read before (they are
whole and valid) and saying where it stopped.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from backend.calib._session import check_lidar, store_cloud
from backend.core.errors import InputError, shorten
from backend.core.result import ProgressCallback, no_progress
from backend.devices.base import DeviceDisconnected, DeviceError, create_device
from backend.devices.rosbag_source import COMPRESSED_IMAGE, IMAGE, LASERSCAN, POINTCLOUD2, TopicInfo, list_topics
from backend.store.session import Session

RECORDING_DRIVERS = ("rosbag", "velodyne_pcap", "cloud_files")
"""Drivers that replay a finite recording (and so can be imported whole)."""
DEFAULT_LIMIT = 200
"""At most this many scans per import unless asked for more."""


@dataclass
class ImportSummary:
    """What an import did: the captures it added, the messages it skipped and how it ended."""

    added: list[str] = field(default_factory=list)
    """Capture ids, in recording order."""
    skipped: list[dict[str, Any]] = field(default_factory=list)
    """``{"message", "input"}`` of each scan that could not be converted."""
    ended: str = ""
    """Why the import stopped: the recording's end, the limit, or the damage that ended it."""
    complete: bool = True
    """False when damage ended the import before the recording's end."""

    def to_dict(self) -> dict[str, Any]:
        return {"added": self.added, "skipped": self.skipped, "ended": self.ended, "complete": self.complete}


def bag_topics(path: str) -> list[TopicInfo]:
    """The topics of a ROS 2 bag (folder, ``.mcap`` or ``.db3``), with type, count and time span."""
    return list_topics(path)


def topics_for_kind(topics: list[TopicInfo], kind: str) -> list[str]:
    """The names of the topics a sensor of ``kind`` can replay: images for a camera, clouds and scans otherwise."""
    wanted = (IMAGE, COMPRESSED_IMAGE) if kind == "camera" else (POINTCLOUD2, LASERSCAN)
    return [topic.name for topic in topics if topic.msgtype in wanted]


def recording_settings(session: Session, sensor: str, settings: dict[str, Any] | None) -> dict[str, Any]:
    """``settings``, or the sensor's own device when it replays a recording; refused unless importable."""
    chosen = dict(settings if settings is not None else session.rig.get(sensor).device)
    if chosen.get("driver") not in RECORDING_DRIVERS:
        raise InputError(f"{shorten(chosen.get('driver'))} is not a recording; import from one of "
                         f"{', '.join(RECORDING_DRIVERS)}", "driver")
    if not chosen.get("path"):
        raise InputError(f"a {chosen['driver']} import needs the recording's 'path' on the server's disk", "path")
    if not Path(str(chosen["path"])).expanduser().exists():
        raise InputError("does not exist on the server", str(chosen["path"]), status_code=404)
    return chosen


def import_recording(session: Session, sensor: str, settings: dict[str, Any] | None = None, *, every: int = 1,
                     limit: int = DEFAULT_LIMIT, progress: ProgressCallback = no_progress) -> ImportSummary:
    """Store every ``every``-th scan of a recording (at most ``limit``) as captures of the LiDAR ``sensor``.

    ``settings`` are device settings of a :data:`RECORDING_DRIVERS` driver, e.g. ``{"driver": "rosbag",
    "path": "run.mcap", "topic": "/points", "start_s": 5, "end_s": 20}``; default the sensor's own device.
    Cancelling (through ``progress``) keeps the captures stored so far.
    """
    check_lidar(session, sensor)
    if every < 1 or limit < 1:
        raise InputError(f"every and limit must be at least 1, not {every} and {limit}", "every")
    settings = recording_settings(session, sensor, settings)
    summary = ImportSummary()
    device = create_device(settings)
    try:
        device.open()
    except DeviceError as exc:
        raise InputError(exc.message, exc.device) from None
    with device:
        total = getattr(device, "message_count", None)
        index = 0
        while len(summary.added) < limit:
            progress(min(0.99, index / total) if total else len(summary.added) / limit,
                     f"{device.describe()}: {len(summary.added)} scans imported")
            try:
                sample = device.read()
            except DeviceDisconnected as exc:  # the recording's end
                summary.ended = exc.message
                break
            except InputError as exc:
                if isinstance(exc, DeviceError):  # the file is damaged from here on
                    summary.ended, summary.complete = f"stopped early: {exc.message}", False
                    break
                summary.skipped.append(exc.to_dict())  # one bad message or file: read on
                continue
            finally:
                index += 1
            if sample.points is None:
                raise InputError(f"{_where(sample.meta)} holds no point cloud ({sample.meta.get('msgtype', 'an image')}"
                                 "); pick a PointCloud2 or LaserScan topic", "topic")
            if (index - 1) % every:
                continue
            try:
                record = store_cloud(session, sensor, sample, device=device.describe(), source=_where(sample.meta))
            except InputError as exc:  # an empty scan
                summary.skipped.append(exc.to_dict())
                continue
            summary.added.append(record.id)
        else:
            summary.ended = f"stopped at the limit of {limit} scans"
    progress(1.0, f"{len(summary.added)} scans imported; {summary.ended}")
    return summary


def _where(meta: dict[str, Any]) -> str:
    """A scan's place in its recording, for messages and capture records."""
    if "topic" in meta:
        return f"{meta['topic']} #{meta['index']}"
    return str(meta.get("source", meta.get("scan_index", "")))
