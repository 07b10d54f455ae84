#!/usr/bin/env python
"""Reading a Livox .lvx recording: ours (``backend.devices.lvx_file.read_lvx_cloud``, the SDK 1 records decoded as
numpy structured arrays) against the livox-lvx package's own reader (one Python object per point), on a written
recording of a Horizon: 2 s (40 frames of 50 ms, 240,000 points/s, extended Cartesian single return).

No real .lvx file is in ``shared/data``, so the recording is written here with the tests' writer. The figures: each
reader's time to read every point, ours as a ratio of the baseline's, and points per second; peak memory.

Prints one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/lvx_read.py
"""

import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_util import log, peak_rss_mb

from backend.devices.livox_packets import DATA_TYPE_EXTEND_CARTESIAN
from backend.devices.lvx_file import read_lvx_cloud

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.devices.test_lvx_file import lvx_file, package, single_records  # noqa: E402

SECONDS = 2.0
FRAME_S = 0.05
POINTS_PER_PACKAGE = 96
PACKAGES_PER_FRAME = int(240_000 * FRAME_S / POINTS_PER_PACKAGE)


def write_recording(path: Path) -> int:
    rng = np.random.default_rng(0)
    frames, stamp_ns = [], 0
    for _ in range(int(SECONDS / FRAME_S)):
        packages = []
        for _ in range(PACKAGES_PER_FRAME):
            xyz_mm = rng.integers(-20_000, 20_000, (POINTS_PER_PACKAGE, 3))
            packages.append(package(0, DATA_TYPE_EXTEND_CARTESIAN, stamp_ns,
                                    single_records(xyz_mm, rng.integers(0, 256, POINTS_PER_PACKAGE))))
            stamp_ns += 400_000
        frames.append(packages)
    lvx_file(path, frames)
    return len(frames) * PACKAGES_PER_FRAME * POINTS_PER_PACKAGE


def read_with_livox_lvx(path: Path) -> int:
    from lvx import LvxFileReader

    with path.open("rb") as fp:
        return sum(len(package.points) for frame in LvxFileReader(fp) for package in frame.packages)


def main():
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "horizon.lvx"
        log("writing the recording")
        written = write_recording(path)
        log("ours")
        started = time.perf_counter()
        ours = len(read_lvx_cloud(path).points)
        ours_s = time.perf_counter() - started
        log("livox-lvx")
        started = time.perf_counter()
        baseline = read_with_livox_lvx(path)
        baseline_s = time.perf_counter() - started
    print(json.dumps({
        "recording": f"written Horizon .lvx, {SECONDS:g} s, {written} points",
        "ours": {"seconds": ours_s, "points": ours, "points_per_s": ours / ours_s},
        "baseline_livox_lvx": {"seconds": baseline_s, "points": baseline, "points_per_s": baseline / baseline_s},
        "ratio_ours_over_baseline_s": ours_s / baseline_s,
        "peak_rss_mb": peak_rss_mb()}, indent=1))


if __name__ == "__main__":
    main()
