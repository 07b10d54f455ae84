"""An IMU's recorded samples from any file the studio reads them from: a CSV (:mod:`backend.devices.imu_csv`), a ROS
bag's ``sensor_msgs/Imu`` topic (:func:`~backend.devices.rosbag_source.read_imu_topic`) or a Livox ``.lvx``
recording's built-in IMU (:func:`~backend.devices.lvx_file.read_lvx_imu`)."""

from __future__ import annotations

from pathlib import Path

from backend.core.errors import InputError
from backend.core.imu import ImuSamples
from backend.devices.imu_csv import read_imu_csv
from backend.devices.lvx_file import read_lvx_imu
from backend.devices.rosbag_source import BAG_FILE_SUFFIXES, IMU, list_topics, read_imu_topic


def read_imu(path: Path, topic: str | None = None) -> tuple[ImuSamples, list[str]]:
    """The samples of ``path`` (a CSV, a ``.lvx`` recording, or a bag whose IMU ``topic`` is named: the commands'
    ``--imu-topic``, which the errors name) and the warnings they earn; :class:`InputError` for a bag without a topic
    (listing its IMU topics), a topic with a file that is no bag, and whatever the file's reader refuses."""
    path = Path(path)
    is_bag = path.is_dir() or path.suffix in BAG_FILE_SUFFIXES
    if topic is None and is_bag:
        topics = [t.name for t in list_topics(path) if t.msgtype == IMU]
        raise InputError(f"{path} is a bag: name its IMU topic with --imu-topic (" + (
            f"its {IMU} topics: {', '.join(topics)}" if topics else f"it holds no {IMU} topic") + ")", "--imu-topic")
    if topic is not None and not is_bag:
        raise InputError(f"--imu-topic reads a ROS bag, but {path} is not one (a ROS 2 bag folder, "
                         f"{', '.join(BAG_FILE_SUFFIXES)}); leave --imu-topic out for an IMU CSV or .lvx file",
                         "--imu-topic")
    if topic is not None:
        return read_imu_topic(path, topic)
    if path.suffix.lower() == ".lvx":
        return read_lvx_imu(path)
    return read_imu_csv(path)
