"""What every benchmark script here shares: stderr logging, median timing, peak memory, pose errors."""

import resource
import statistics
import sys
import time

import numpy as np

REPEATS = 3


def log(message):
    print(message, file=sys.stderr, flush=True)


def median_time(function, repeats=REPEATS):
    """Median wall time (s) of ``repeats`` calls of ``function()``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def peak_rss_mb():
    """Peak resident memory of this process so far (MB); ru_maxrss is in KiB on Linux."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def pose_error(T, T_true):
    """(translation error norm in mm, rotation error angle in deg) of the 4x4 ``T`` against ``T_true``."""
    from backend.core.transforms import transform_error

    trans_m, rot_deg = transform_error(T, T_true)
    return float(np.linalg.norm(trans_m) * 1000), float(np.linalg.norm(rot_deg))
