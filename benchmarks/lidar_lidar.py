#!/usr/bin/env python
"""LiDAR-to-LiDAR benchmark: our registration against Open3D's ICP, and the LiDAR parsers' throughput.

What it measures, in one run on the same data:

- ``register_s``: ``register_pair`` with ``LidarLidarSettings(spread=False)`` (input checks,
  coarse-to-fine small_gicp GICP incl. downsampling and covariances, quality numbers and the
  Hessian sigma), from an initial guess 19.7 cm / 5 deg off the truth;
- ``register_with_sigma_s``: the same with the default settings, which adds the spread (the
  leave-one-azimuth-sector-out jackknife, i.e. 8 extra fine GICP solves);
- ``baseline_icp_s``: Open3D point-to-plane ICP (``registration_icp`` with
  ``TransformationEstimationPointToPlane``) at our fine stage's voxel size (0.1 m) and
  correspondence distance (0.2 m), from the same initial guess, ``max_iteration`` as ours (50)
  and Open3D's default relative tolerances. Its time includes building the Open3D clouds,
  voxel downsampling both and estimating the target's normals (20 nearest neighbours, as our
  covariances): point-to-plane needs the target's normals only. One stage suffices for it from
  this guess; ours also runs the two coarse stages;
- ``error_mm`` / ``error_deg`` (ours, the ``spread=False`` result; the default settings give
  the same transform) and ``baseline_error_*``: norm of the translation error (mm) and angle of
  the rotation error (deg) against the simulation's ground truth;
- ``ydlidar_points_per_s``: ``YdlidarParser.feed`` on a synthetic TG30 byte stream (200 clean
  revolutions of the simulator, 2000 samples each) in 4096-byte reads; points are the valid
  samples of the completed scans;
- ``velodyne_udp_points_per_s``: simulated VLP-16 data packets sent from a separate process to
  127.0.0.1 at up to ``UDP_RATE_HZ`` packets/s for ``UDP_SECONDS``, received and decoded by the
  ``VelodyneUdp`` driver (full scans via ``read()``); decoded points over the time from the
  start of sending to the last scan (datagrams the receiver could not keep up with are lost,
  as on a real network, and show up as a lower rate);
- ``velodyne_decoder_points_per_s``: the in-run baseline, velodyne-decoder's ``ScanDecoder``
  alone on the same packets in memory, one rotation per call (no socket, no scan cutting);
- ``peak_rss_mb``: peak resident memory of the process at the end (ru_maxrss).

Clouds: the simulated yard (``LidarScene``, with the board) scanned once from each of two
LiDAR poses by a 64-beam spinning LiDAR (-25..15 deg, 0.2 deg columns), 1 cm range noise,
seeds 1 and 2: about 115k and 108k points (exact counts in ``points``). Times are the median of
``REPEATS`` runs (time.perf_counter). Ratios are ours / baseline: ``register_ratio`` > 1 means
ours is slower, ``udp_ratio`` is the share of the decoder-only rate the UDP driver reaches.

Prints exactly one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/lidar_lidar.py
"""

import json
import multiprocessing
import os
import socket
import time

import numpy as np
from bench_util import REPEATS, log, median_time, peak_rss_mb, pose_error
from scipy.spatial.transform import Rotation

from backend.calib.lidar_lidar.gicp import LidarLidarSettings, register_pair
from backend.core.transforms import from_xyz_ypr, invert, make_T
from backend.devices.base import DeviceDisconnected
from backend.devices.velodyne import VelodyneUdp
from backend.devices.ydlidar import YdlidarParser
from backend.sim.lidar_scene import LidarScene
from backend.sim.velodyne_packets import simulate_vlp16_scan
from backend.sim.ydlidar_sim import YdlidarSimulator

T_BASE_SOURCE = from_xyz_ypr(np.array([0.4, 0.2, 1.1]), np.radians([0.0, 2.0, 0.0]))
T_BASE_TARGET = from_xyz_ypr(np.array([-0.3, -0.35, 0.9]), np.radians([100.0, 12.0, -5.0]))
"""The two LiDARs on the robot (as in tests/calib/lidar_lidar/test_gicp.py): 106 deg apart in yaw, 12 deg in pitch."""
SCAN = {"beams": 64, "vertical_fov_deg": (-25.0, 15.0), "azimuth_step_deg": 0.2, "range_noise_m": 0.01}
INIT_OFFSET_M = np.array([0.12, -0.14, 0.07])
INIT_OFFSET_DEG = 5.0
INIT_AXIS = np.array([0.3, -0.5, 0.8])
"""The initial guess is the truth composed with this offset: 19.7 cm, 5 deg about INIT_AXIS."""
YDLIDAR_SCANS = 200
YDLIDAR_CHUNK_BYTES = 4096
VLP16_ROTATIONS = 10
"""Packets of this many turns (600 rpm, the shared yard from lidar_top) are sent over and over."""
UDP_RATE_HZ = 40_000
UDP_SECONDS = 2.0
UDP_BURST = 40
"""The sender paces itself in bursts of this many packets."""
DECODER_PASSES = 5
"""The decoder-only baseline decodes all the packets this many times per repeat."""


def udp_sender(packets, port, rate_hz, seconds, ready, go, sent):
    """In a separate process: send ``packets`` round and round to 127.0.0.1:``port``, paced at
    ``rate_hz`` for ``seconds``; the count sent goes into ``sent.value``."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    address = ("127.0.0.1", port)
    limit = int(rate_hz * seconds)
    ready.set()
    go.wait()
    start = time.perf_counter()
    count = 0
    while count < limit and time.perf_counter() - start < seconds:
        for _ in range(min(UDP_BURST, limit - count)):
            sock.sendto(packets[count % len(packets)], address)
            count += 1
        ahead = start + count / rate_hz - time.perf_counter()
        if ahead > 0:
            time.sleep(ahead)
    sock.close()
    sent.value = count


def main():
    started = time.perf_counter()
    log(f"load average at start: {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores "
        "(other processes skew the timings, the UDP throughput most)")

    # 1. Two clouds of the simulated yard from two LiDAR poses, and an initial guess.
    log("scanning the simulated yard from two LiDAR poses ...")
    scene = LidarScene()
    source = scene.scan_3d(T_BASE_SOURCE, **SCAN, rng=1).points
    target = scene.scan_3d(T_BASE_TARGET, **SCAN, rng=2).points
    del scene
    T_true = invert(T_BASE_TARGET) @ T_BASE_SOURCE
    axis = INIT_AXIS / np.linalg.norm(INIT_AXIS)
    offset = make_T(Rotation.from_rotvec(np.radians(INIT_OFFSET_DEG) * axis).as_matrix(), INIT_OFFSET_M)
    T_init = T_true @ offset
    init_mm, init_deg = pose_error(T_init, T_true)
    log(f"  {len(source)} source and {len(target)} target points; initial guess {init_mm:.0f} mm / "
        f"{init_deg:.1f} deg off")

    # 2. Registration: ours without and with the spread, and Open3D point-to-plane ICP.
    import open3d as o3d

    no_spread = LidarLidarSettings(spread=False)
    default = LidarLidarSettings()
    reg = o3d.pipelines.registration

    def baseline_icp():
        source_down = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source)).voxel_down_sample(no_spread.voxel_m)
        target_down = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target)).voxel_down_sample(no_spread.voxel_m)
        target_down.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(no_spread.num_neighbors))
        return reg.registration_icp(source_down, target_down, no_spread.max_correspondence_m, T_init,
                                    reg.TransformationEstimationPointToPlane(),
                                    reg.ICPConvergenceCriteria(max_iteration=no_spread.max_iterations))

    log(f"timing register_pair (spread=False) x{REPEATS} ...")
    register_s = median_time(lambda: register_pair(source, target, T_init, no_spread))
    log(f"timing register_pair (default, with the spread) x{REPEATS} ...")
    register_with_sigma_s = median_time(lambda: register_pair(source, target, T_init, default))
    log(f"timing Open3D point-to-plane ICP (with downsampling and normals) x{REPEATS} ...")
    baseline_icp_s = median_time(baseline_icp)

    ours = register_pair(source, target, T_init, no_spread)
    ours_sigma = register_pair(source, target, T_init, default)
    baseline = baseline_icp()
    error_mm, error_deg = pose_error(ours.T_parent_child, T_true)
    sigma_mm, sigma_deg = pose_error(ours_sigma.T_parent_child, T_true)
    baseline_error_mm, baseline_error_deg = pose_error(np.asarray(baseline.transformation), T_true)
    sigma = ours_sigma.std_vector
    log(f"  ours:     {error_mm:.3f} mm {error_deg:.4f} deg, fitness {ours.residuals['fitness']:.3f}, converged "
        f"{ours.converged}, {ours.diagnostics['iterations']} fine iterations; with spread {sigma_mm:.3f} mm "
        f"{sigma_deg:.4f} deg, 1-sigma {np.linalg.norm(sigma[:3]) * 1000:.3f} mm "
        f"{np.degrees(np.linalg.norm(sigma[3:])):.4f} deg")
    log(f"  baseline: {baseline_error_mm:.3f} mm {baseline_error_deg:.4f} deg, fitness {baseline.fitness:.3f}")

    # 3a. YDLiDAR parser on an in-memory byte stream.
    simulator = YdlidarSimulator()
    stream = simulator.scan_bytes(YDLIDAR_SCANS + 1)  # the last ring start closes the last full scan
    simulator.stop()  # never started; removes its temporary folder

    def parse_stream():
        parser = YdlidarParser()
        points = 0
        for i in range(0, len(stream), YDLIDAR_CHUNK_BYTES):
            for scan in parser.feed(stream[i:i + YDLIDAR_CHUNK_BYTES]):
                points += int(np.count_nonzero(scan.valid))
        return points

    ydlidar_points = parse_stream()
    log(f"timing YdlidarParser.feed on {len(stream) / 1e6:.2f} MB ({ydlidar_points} valid points) x{REPEATS} ...")
    ydlidar_points_per_s = ydlidar_points / median_time(parse_stream)

    # 3b. Velodyne: decoder alone on the packets in memory, then the UDP driver.
    import velodyne_decoder as vd

    sim = simulate_vlp16_scan(n_rotations=VLP16_ROTATIONS)
    packets = sim.packets
    per_call = int(np.ceil(sim.packets_per_rotation))
    decoder = vd.ScanDecoder(vd.Config(model=vd.Model.VLP16))

    def decode_all():
        points = 0
        for _ in range(DECODER_PASSES):
            for i in range(0, len(packets), per_call):
                vector = vd.PacketVector()
                for k, data in enumerate(packets[i:i + per_call]):
                    vector.append(vd.VelodynePacket(k * 1e-3, data))
                _, cloud = decoder.decode(vector)
                points += len(cloud)
        return points

    decoder_points = decode_all()
    log(f"timing velodyne_decoder alone on {DECODER_PASSES}x{len(packets)} packets ({decoder_points} points) "
        f"x{REPEATS} ...")
    velodyne_decoder_points_per_s = decoder_points / median_time(decode_all)

    log(f"timing VelodyneUdp: {len(packets)} packets round and round from another process, up to "
        f"{UDP_RATE_HZ} packets/s for {UDP_SECONDS:g} s ...")
    device = VelodyneUdp(host="127.0.0.1", port=0, timeout_s=0.5)
    device.open()
    context = multiprocessing.get_context("spawn")
    ready, go, sent = context.Event(), context.Event(), context.Value("q", 0)
    sender = context.Process(target=udp_sender, args=(packets, device.bound_port, UDP_RATE_HZ, UDP_SECONDS,
                                                      ready, go, sent), daemon=True)
    sender.start()
    try:
        if not ready.wait(30):
            raise SystemExit("the UDP sender process did not start")
        udp_points = scans = received = 0
        start = time.perf_counter()
        go.set()
        end = start
        while time.perf_counter() - start < UDP_SECONDS + 10:  # bounded even if the sender hangs
            try:
                sample = device.read()
            except DeviceDisconnected:
                break  # 0.5 s without packets: the sender is done and the socket is drained
            end = time.perf_counter()
            udp_points += len(sample.points)
            received += sample.meta["packets"]
            scans += 1
        sender.join(5)
    finally:
        device.close()
        if sender.is_alive():
            sender.terminate()
            sender.join()
    if scans == 0:
        raise SystemExit("no Velodyne scan arrived over UDP")
    velodyne_udp_points_per_s = udp_points / (end - start)
    log(f"  sent {sent.value} packets, {received} in {scans} full scans, {udp_points} points in "
        f"{end - start:.2f} s ({received / (end - start):.0f} packets/s decoded)")
    if received >= 0.99 * sent.value:
        log("  the driver kept up with the sender: the UDP rate is the sender's cap, a lower bound of the driver's")

    # 4. Report.
    peak_memory_mb = peak_rss_mb()
    log(f"done in {time.perf_counter() - started:.1f} s; load average at end: {os.getloadavg()[0]:.2f}")
    result = {
        "benchmark": "lidar_lidar",
        "points": [len(source), len(target)],
        "register_s": round(register_s, 4),
        "register_with_sigma_s": round(register_with_sigma_s, 4),
        "baseline_icp_s": round(baseline_icp_s, 4),
        "register_ratio": round(register_s / baseline_icp_s, 2),
        "error_mm": round(error_mm, 3),
        "error_deg": round(error_deg, 4),
        "baseline_error_mm": round(baseline_error_mm, 3),
        "baseline_error_deg": round(baseline_error_deg, 4),
        "ydlidar_points_per_s": round(ydlidar_points_per_s),
        "velodyne_udp_points_per_s": round(velodyne_udp_points_per_s),
        "velodyne_decoder_points_per_s": round(velodyne_decoder_points_per_s),
        "udp_ratio": round(velodyne_udp_points_per_s / velodyne_decoder_points_per_s, 4),
        "peak_rss_mb": round(peak_memory_mb, 1),
        "cpu_count": os.cpu_count(),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
