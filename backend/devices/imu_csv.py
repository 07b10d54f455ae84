"""IMU samples from a CSV file: ``t_ns, wx, wy, wz, ax, ay, az`` (ns; rad/s; m/s²), as EuRoC and Kalibr write them."""

from __future__ import annotations

from pathlib import Path

from backend.core.imu import ImuSamples, checked_imu
from backend.core.tables import parse_table, read_table

IMU_COLUMNS = ("t_ns", "wx", "wy", "wz", "ax", "ay", "az")
"""The columns of an IMU CSV file, in order (``../shared/conventions.md``)."""


def read_imu_csv(path: Path, name: str | None = None) -> tuple[ImuSamples, list[str]]:
    """The samples of an IMU CSV file (times in s from the epoch of its ``t_ns``) and the warnings they earn
    (:func:`~backend.core.imu.checked_imu`); :class:`InputError` naming the file for what cannot be used."""
    shown = name or str(path)
    rows = read_table(path, IMU_COLUMNS, shown)
    return checked_imu(rows[:, 0] * 1e-9, rows[:, 1:4], rows[:, 4:7], shown)


def parse_imu_csv(data: bytes, name: str) -> tuple[ImuSamples, list[str]]:
    """:func:`read_imu_csv` on a file's bytes (an upload named ``name``)."""
    rows = parse_table(data, IMU_COLUMNS, name)
    return checked_imu(rows[:, 0] * 1e-9, rows[:, 1:4], rows[:, 4:7], name)


def format_imu_csv(samples: ImuSamples) -> bytes:
    """``samples`` as an IMU CSV file (:data:`IMU_COLUMNS`, a ``#`` header as EuRoC writes it; times in ns)."""
    lines = ["#" + ",".join(IMU_COLUMNS)] + [
        f"{round(t * 1e9)},{','.join(f'{v:.9f}' for v in (*w, *a))}"
        for t, w, a in zip(samples.t_s, samples.gyro_rad_s, samples.accel_m_s2, strict=True)]
    return "\n".join(lines).encode() + b"\n"
