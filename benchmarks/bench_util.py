"""What every benchmark script here shares: stderr logging, median timing, peak memory."""

import resource
import statistics
import sys
import time

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
