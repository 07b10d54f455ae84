#!/usr/bin/env python
"""Node-network benchmark: how many depth nodes streaming at the Kinect's 30 Hz one studio takes.

What it measures, in one run:

- Per frame, once: a simulated cell node's Kinect v2 frame (``sim_depth``), encoded as an agent streams it
  (voxelised to 2 cm, quantised, zlib: ``frame_bytes``, ``compression_ratio`` against its float32 arrays) and as
  a capture (the full depth image: ``capture_bytes``); ``encode_stream_ms`` (the node computer's work per frame),
  ``decode_stream_ms`` (what the studio spends to look at one, only when a preview is drawn).
- For N = 1, 2, 4, 6, 8, 12 node processes on 127.0.0.1, each publishing its node's encoded frame at 30 Hz
  through the agent's wire (liveliness token, info and clock queryables, the ``frames`` key and its
  sequence/send-time attachment) into one studio :class:`NodeNetwork`, in a window of ``--seconds`` that opens
  once every node streams: received ``frames_per_s`` and ``mb_per_s``, latency ``p50_ms``/``p95_ms`` (studio
  receive time minus the node's send stamp; one host, one clock), ``dropped`` (gaps in each node's sequence
  numbers), ``sent_hz`` (what the publishers managed), the studio's CPU (``studio_cpu``: cores busy receiving)
  and ``scaling`` = frames/s against N times the in-run baseline N = 1; ``clock_rtt_ms`` and
  ``clock_offset_error_ms``, a clock estimate's round trip and error while they stream (one host, one clock: the
  offset should be 0, and its error is at most half the round trip).
- With ``--secure``, every count again with the network's keys (mutual TLS and the studio's access control, as
  the depth-cell demo runs): ``secure_runs``, and per count ``tls_cpu_ratio`` (the studio's CPU per frame secured
  over plain, the in-run baseline) and ``tls_p50_ratio`` (latency).
- ``estimate``: the nodes at 30 Hz one studio core receives (from its CPU per frame), one Gigabit link carries
  (from the frame size), and where it broke here.

The publishers send frames encoded beforehand: on a real network the encoding runs on each node's own
computer (``encode_stream_ms`` of it), and 12 encoders at 30 Hz would need about 20 cores here, not 2.
The machine is shared: ``load_average`` says how busy it was.

Prints exactly one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/node_network.py [--counts 1,2,4,6,8,12] [--seconds 6] [--secure]
"""

import argparse
import json
import os
import resource
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from bench_util import log, median_time

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from backend.devices.cloud_codec import decode_frame, encode_frame  # noqa: E402
from backend.devices.node_agent import CLOCK_REPLY, FRAME_STAMP, node_key, open_session  # noqa: E402
from backend.devices.node_keys import NetworkKeys, read_bundle  # noqa: E402
from backend.devices.node_network import NodeNetwork  # noqa: E402
from backend.services.network_keys import create_network_keys  # noqa: E402

RATE_HZ = 30.0
"""The Kinect v2's frame rate."""
VOXEL_M = 0.02
"""The agent's default voxel (m)."""
GIGABIT_BYTES_S = 125e6
CELL_NODES = [f"sn{i}" for i in range(1, 7)]


def publish(name: str, endpoint: str, frame_file: str, keys_file: str | None) -> None:
    """One node process: present itself as an agent does, then put its frame at RATE_HZ until SIGTERM."""
    payload = Path(frame_file).read_bytes()
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    session = open_session([], [endpoint], "connect", None if keys_file is None else read_bundle(Path(keys_file)))
    info = json.dumps({"name": name, "kind": "depth", "device": "benchmark", "rate_hz": RATE_HZ, "voxel_m": VOXEL_M})
    zid = str(session.zid())
    entities = [session.declare_queryable(node_key(name, zid, "info"), lambda q: q.reply(q.key_expr, info)),
                session.declare_queryable(node_key(name, zid, "clock"),
                                          lambda q: q.reply(q.key_expr, CLOCK_REPLY.pack(time.time())))]
    publisher = session.declare_publisher(node_key(name, zid, "frames"))
    token = session.liveliness().declare_token(node_key(name, zid, "alive"))
    sent, started_s, next_s, cpu_start_s = 0, time.monotonic(), time.monotonic(), time.process_time()
    while not stop.is_set():
        publisher.put(payload, attachment=FRAME_STAMP.pack(sent, time.time()))
        sent += 1
        next_s += 1.0 / RATE_HZ
        stop.wait(max(0.0, next_s - time.monotonic()))
    seconds = time.monotonic() - started_s
    token.undeclare()
    for entity in (*entities, publisher):
        entity.undeclare()
    session.close()
    cpu = (time.process_time() - cpu_start_s) / seconds
    print(json.dumps({"name": name, "sent_hz": sent / seconds, "cpu": cpu}), flush=True)


def render_frames() -> tuple[dict[str, bytes], dict]:
    """Each cell node's stream frame, and the figures of one."""
    from backend.devices.base import create_device

    frames, figures = {}, {}
    for node in CELL_NODES:
        device = create_device({"driver": "sim_depth", "node": node, "rate_hz": 0})
        device.open()
        sample = device.read()
        device.close()
        frames[node] = encode_frame(sample, VOXEL_M)
        if node == "sn1":
            raw = 2 * sample.depth.size * 4 + sample.points.size * 4 + sample.intensity.size * 4
            capture = encode_frame(sample, None)
            figures = {"points": len(sample.points), "raw_bytes": raw, "frame_bytes": len(frames[node]),
                       "frame_points": len(decode_frame(frames[node]).points),
                       "compression_ratio": round(raw / len(frames[node]), 1),
                       "capture_bytes": len(capture), "capture_ratio": round(raw / len(capture), 1),
                       "encode_stream_ms": round(1000 * median_time(lambda s=sample: encode_frame(s, VOXEL_M), 5), 1),
                       "encode_capture_ms": round(1000 * median_time(lambda s=sample: encode_frame(s, None), 5), 1),
                       "decode_stream_ms": round(1000 * median_time(lambda f=frames[node]: decode_frame(f), 5), 1),
                       "decode_capture_ms": round(1000 * median_time(lambda c=capture: decode_frame(c), 5), 1)}
    return frames, figures


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def run_network(count: int, files: dict[str, str], seconds: float, keys: NetworkKeys | None = None) -> dict:
    """N publisher processes into one NodeNetwork (secured with ``keys``): what the studio received in a window of
    ``seconds`` once every node streams (drops from the gaps in each node's sequence numbers)."""
    endpoint = f"{'tcp' if keys is None else 'tls'}/127.0.0.1:{free_port()}"
    received: list[tuple[int, float | None]] = []
    window = {"open": False}

    def on_frame(node: str, n_bytes: int, latency_s: float | None) -> None:
        if window["open"]:
            received.append((n_bytes, latency_s))  # list.append is atomic: no lock on the receive path

    network = NodeNetwork(listen=[endpoint], keys=keys)
    network.open()
    network.on_frame(on_frame)
    names = node_names(count)
    processes = [subprocess.Popen([sys.executable, __file__, "--publish", name, "--endpoint", endpoint,
                                   "--frame", files[CELL_NODES[k % len(CELL_NODES)]]]
                                  + ([] if keys is None else ["--keys", str(keys.bundle_path(name))]),
                                  stdout=subprocess.PIPE, text=True, cwd=ROOT) for k, name in enumerate(names)]
    deadline = time.monotonic() + 60 + 5 * count
    while not all(s.frames >= 15 and s.latency_s is not None for s in network.nodes()) or len(network.nodes()) < count:
        if time.monotonic() > deadline:
            raise RuntimeError(f"only {len(network.nodes())} of {count} nodes streamed within the time allowed")
        time.sleep(0.1)
    before = {s.name: s for s in network.nodes()}
    cpu_start, wall_start = resource.getrusage(resource.RUSAGE_SELF), time.time()
    window["open"] = True
    time.sleep(seconds)
    window["open"] = False
    cpu_end, wall_s = resource.getrusage(resource.RUSAGE_SELF), time.time() - wall_start
    clock = network.estimate_clock(names[0])  # one host, one clock: the whole offset is the estimate's error
    after = {s.name: s for s in network.nodes()}
    for process in processes:
        process.send_signal(signal.SIGTERM)
    reports = [json.loads(p.communicate(timeout=60)[0].strip().splitlines()[-1]) for p in processes]
    network.close()
    frames = len(received)
    dropped = sum(after[n].dropped - before[n].dropped for n in names)
    latencies = np.array([lat for _, lat in received if lat is not None]) * 1000
    studio_cpu_s = (cpu_end.ru_utime + cpu_end.ru_stime) - (cpu_start.ru_utime + cpu_start.ru_stime)
    return {"nodes": count, "frames_per_s": round(frames / wall_s, 1),
            "mb_per_s": round(sum(n for n, _ in received) / wall_s / 1e6, 2),
            "p50_ms": round(float(np.percentile(latencies, 50)), 2) if len(latencies) else None,
            "p95_ms": round(float(np.percentile(latencies, 95)), 2) if len(latencies) else None,
            "dropped": dropped, "dropped_pct": round(100 * dropped / max(frames + dropped, 1), 2),
            "sent_hz": round(float(np.mean([r["sent_hz"] for r in reports])), 1),
            "studio_cpu": round(studio_cpu_s / wall_s, 2),
            "studio_cpu_ms_per_frame": round(1000 * studio_cpu_s / max(frames, 1), 3),
            "publisher_cpu": round(sum(r["cpu"] for r in reports), 2),
            "clock_rtt_ms": round(1000 * clock.rtt_s, 2), "clock_offset_error_ms": round(1000 * abs(clock.offset_s), 3)}


def node_names(count: int) -> list[str]:
    return [f"n{k:02d}" for k in range(count)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--counts", default="1,2,4,6,8,12")
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--publish", help=argparse.SUPPRESS)
    parser.add_argument("--endpoint", help=argparse.SUPPRESS)
    parser.add_argument("--frame", help=argparse.SUPPRESS)
    parser.add_argument("--keys", help=argparse.SUPPRESS)
    parser.add_argument("--secure", action="store_true", help="run every count again with the network's keys")
    args = parser.parse_args()
    if args.publish:
        publish(args.publish, args.endpoint, args.frame, args.keys)
        return
    counts = [int(c) for c in args.counts.split(",")]
    log("rendering and encoding one frame per cell node")
    frames, figures = render_frames()
    runs, secure_runs = [], []
    with tempfile.TemporaryDirectory() as folder:
        files = {}
        for node, payload in frames.items():
            files[node] = os.path.join(folder, f"{node}.frame")
            Path(files[node]).write_bytes(payload)
        keys = create_network_keys(Path(folder) / "keys", node_names(max(counts))) if args.secure else None
        for count in counts:
            log(f"{count} node(s) at {RATE_HZ:g} Hz for {args.seconds:g} s")
            runs.append(run_network(count, files, args.seconds))
            log(json.dumps(runs[-1]))
            if keys is not None:
                log(f"{count} node(s), secured (mutual TLS and access control)")
                secure = run_network(count, files, args.seconds, keys)
                secure["tls_cpu_ratio"] = round(secure["studio_cpu_ms_per_frame"]
                                                / max(runs[-1]["studio_cpu_ms_per_frame"], 1e-9), 2)
                secure["tls_p50_ratio"] = (round(secure["p50_ms"] / runs[-1]["p50_ms"], 2)
                                           if secure["p50_ms"] and runs[-1]["p50_ms"] else None)
                secure_runs.append(secure)
                log(json.dumps(secure))
    base = runs[0]["frames_per_s"] / runs[0]["nodes"]
    for run in runs:
        run["scaling"] = round(run["frames_per_s"] / (base * run["nodes"]), 2) if base else None
    cpu_ms = float(np.median([r["studio_cpu_ms_per_frame"] for r in runs]))
    mean_frame = float(np.mean([len(f) for f in frames.values()]))
    broke = next((r for r in runs if r["scaling"] is not None and (r["scaling"] < 0.9 or r["dropped_pct"] > 5)),
                 None)
    estimate = {
        "nodes_per_studio_core_receiving": int(1000 / (cpu_ms * RATE_HZ)) if cpu_ms else None,
        "nodes_per_studio_core_decoding_every_frame": int(1000 / ((cpu_ms + figures["decode_stream_ms"]) * RATE_HZ)),
        "nodes_per_gigabit_link": int(GIGABIT_BYTES_S / (mean_frame * RATE_HZ)),
        "first_count_not_scaling_here": None if broke is None else broke["nodes"],
    }
    print(json.dumps({"frame": figures, "rate_hz": RATE_HZ, "voxel_m": VOXEL_M, "seconds": args.seconds,
                      "runs": runs, **({"secure_runs": secure_runs} if secure_runs else {}),
                      "estimate": estimate, "load_average": os.getloadavg(),
                      "cores": os.cpu_count()}, indent=1))


if __name__ == "__main__":
    main()
