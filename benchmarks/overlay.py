#!/usr/bin/env python
"""LiDAR-on-image overlay benchmark: projection, occlusion, colouring and drawing of 1M points.

What it measures, in one run on the same data:

- ``overlays_per_s``: one whole overlay per call: ``project_cloud`` (``occlusion_px`` =
  ``OCCLUSION_PX``, default float32) of ``POINTS`` points, ``depth_colours`` of the kept points
  and ``draw_points`` (``radius_px`` = 1) onto the 1280x720 simulated image of the demo rig's
  ``cam_front`` (target: at least 30 per second); ``overlay_ms_best`` is the fastest call, a
  guide to what the median loses to other processes on a shared machine;
- ``overlays_per_s_float64``: the same with ``project_cloud(..., dtype=np.float64)``;
- ``redraw_100k_ms``: the same for an even stride of 100k of those points: what the server
  spends to redraw after a slider moves (target: within 20 ms); ``redraw_baseline_ms``: the in-run
  baseline for it, the same projection and colours drawn as before ``draw_points`` vectorised the
  drawing, one ``cv2.rectangle`` per point in a Python loop (the same squares, later points on top);
  ``redraw_ratio`` = baseline / redraw_100k_ms;
- ``full_resolution_ms``: what the full-size overlay page's route spends on one image:
  ``render_overlays`` (the same projection, colours over the 2nd-98th percentile of the drawn
  depths, drawing), ``with_legend`` and ``encode_jpeg`` at the image's full size;
  ``full_resolution_ratio`` = baseline / that;
- ``stages_ms``: the 1M overlay's steps timed alone (projection without and with the
  occlusion filter, the percentile colour range, colouring, drawing, legend, JPEG), to see what
  dominates;
- ``float32_vs_float64``: whether the default float32 projection keeps the same points as
  float64, and its largest pixel difference (px);
- ``baseline_projectpoints_per_s``: the in-run baseline, ``cv2.projectPoints`` of the same 1M
  points alone (no culling, colouring or drawing); ``ratio`` = overlays_per_s / baseline.
  From Python it always computes the 2N x 15 Jacobian too, which is most of its time;
- ``kept_points``: how many points the overlay draws (in view and not hidden);
- ``peak_rss_mb``: peak resident memory of the process at the end (ru_maxrss);
- ``load_average``: the 1-minute load average at the start and the end (other processes skew every
  absolute figure on a shared machine; the ratios much less).

Cloud: the simulated yard (``LidarScene``, with the board) ray-cast from the demo rig's
``lidar_front`` with a dense solid-state-like pattern (azimuth -45..45 deg, elevation
-35..15 deg in its frame, no noise) that covers ``cam_front``'s view; the first ``POINTS``
hits are kept. Points are float64 in the LiDAR frame (as ``read_cloud`` gives them), the
transform is the rig's ground truth ``T_cam_front_lidar_front``. Times are medians of
``REPEATS_FAST`` calls (time.perf_counter); the overlays are timed after a warm-up call, since
the first call allocates the work buffers that later calls reuse.

Prints exactly one JSON object on stdout; progress goes to stderr.

Usage:
    .venv/bin/python benchmarks/overlay.py
"""

import json
import os
import statistics
import time

import cv2
import numpy as np
from bench_util import log, median_time, peak_rss_mb

from backend.core.boards import BoardSpec
from backend.core.colour_maps import depth_colours, spread_range
from backend.core.overlay import ColourScale, OverlayStyle, render_overlays, with_legend
from backend.core.projection import draw_points, project_cloud
from backend.core.transforms import invert, to_rvec_tvec
from backend.devices.image_io import encode_jpeg
from backend.sim.board_renderer import render_board_image
from backend.sim.demo_rig import DEMO_BOARD, demo_rig
from backend.sim.lidar_scene import LidarScene

POINTS = 1_000_000
REDRAW_POINTS = 100_000
GRID = (1500, 900)
"""Rays across azimuth and elevation; about 1.2M of the 1.35M rays hit something."""
AZIMUTH_DEG = (-45.0, 45.0)
ELEVATION_DEG = (-35.0, 15.0)
OCCLUSION_PX = 8
DEPTH_RANGE_M = (0.5, 10.0)
REPEATS_FAST = 21


def dense_cloud(scene: LidarScene, T_base_lidar: np.ndarray) -> np.ndarray:
    """The first :data:`POINTS` hits (m, LiDAR frame) of a dense ray grid cast from ``T_base_lidar``."""
    az, el = np.meshgrid(np.radians(np.linspace(*AZIMUTH_DEG, GRID[0])),
                         np.radians(np.linspace(*ELEVATION_DEG, GRID[1])))
    dirs = np.column_stack([(np.cos(el) * np.cos(az)).ravel(), (np.cos(el) * np.sin(az)).ravel(), np.sin(el).ravel()])
    t, _, _ = scene.cast(T_base_lidar[:3, 3], dirs @ T_base_lidar[:3, :3].T)
    hit = np.isfinite(t)
    return (dirs[hit] * t[hit, None])[:POINTS]


def drawn_point_by_point(image, uv, colours, radius_px=1):
    """The overlay's drawing as it was before it was vectorised: one filled square per point, in order."""
    canvas = image.copy()
    for (u, v), (r, g, b) in zip(np.rint(uv).astype(int).tolist(), colours.tolist(), strict=True):
        cv2.rectangle(canvas, (u - radius_px, v - radius_px), (u + radius_px, v + radius_px), (b, g, r), -1)
    return canvas


def call_times(function, repeats):
    """Wall times (s) of ``repeats`` calls of ``function()``."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return times


def main():
    started = time.perf_counter()
    load_start = os.getloadavg()[0]
    log(f"load average at start: {load_start:.2f} on {os.cpu_count()} cores (other processes skew timings)")
    rig = demo_rig()
    camera = rig.get("cam_front").intrinsics
    T_camera_lidar = rig.T_a_b("cam_front", "lidar_front")
    log("ray-casting the simulated yard from lidar_front and rendering cam_front's image ...")
    scene = LidarScene()
    points = dense_cloud(scene, rig.T_root_frame("lidar_front"))
    T_camera_board = invert(rig.T_root_frame("cam_front")) @ scene.T_base_board
    image = cv2.cvtColor(render_board_image(camera, BoardSpec.parse(DEMO_BOARD), T_camera_board,
                                            np.random.default_rng(0)), cv2.COLOR_GRAY2BGR)
    del scene
    subset = points[np.linspace(0, len(points) - 1, REDRAW_POINTS).astype(np.int64)]
    log(f"  {len(points)} points")

    def overlay(cloud, dtype=np.float32):
        projection = project_cloud(cloud, T_camera_lidar, camera, occlusion_px=OCCLUSION_PX, dtype=dtype)
        return draw_points(image, projection.uv, depth_colours(projection.depth_m, *DEPTH_RANGE_M), radius_px=1)

    log(f"timing the 1M overlay and the 100k redraw x{REPEATS_FAST} ...")
    overlay(points), overlay(subset)  # warm-up: first calls allocate buffers that later calls reuse
    overlay_times = call_times(lambda: overlay(points), REPEATS_FAST)
    overlay_s = statistics.median(overlay_times)
    redraw_s = median_time(lambda: overlay(subset), REPEATS_FAST)
    overlay_float64_s = median_time(lambda: overlay(points, np.float64), REPEATS_FAST)

    def redraw_baseline():
        projection = project_cloud(subset, T_camera_lidar, camera, occlusion_px=OCCLUSION_PX)
        colours = depth_colours(projection.depth_m, *DEPTH_RANGE_M)
        return drawn_point_by_point(image, projection.uv, colours)

    log("timing the 100k redraw's baseline (point by point) ...")
    redraw_baseline_s = median_time(redraw_baseline, 5)
    same_redraw = bool(np.array_equal(redraw_baseline(), overlay(subset)))

    def full_resolution():
        (drawn,), _, scale = render_overlays([(image, points, None)], T_camera_lidar, camera, full_style)
        return encode_jpeg(with_legend(drawn, scale))

    log(f"timing the full-resolution page's overlay x{REPEATS_FAST} ...")
    full_style = OverlayStyle(range_m=(0.0, 1e3), occlusion_px=OCCLUSION_PX, radius_px=1)
    full_resolution()
    full_resolution_s = median_time(full_resolution, REPEATS_FAST)

    log("timing the stages ...")
    plain = project_cloud(points, T_camera_lidar, camera)
    occluded = project_cloud(points, T_camera_lidar, camera, occlusion_px=OCCLUSION_PX)
    exact = project_cloud(points, T_camera_lidar, camera, occlusion_px=OCCLUSION_PX, dtype=np.float64)
    same_points = bool(np.array_equal(occluded.index, exact.index))
    max_px = float(np.abs(occluded.uv - exact.uv).max()) if same_points and len(exact) else None
    colours = depth_colours(occluded.depth_m, *DEPTH_RANGE_M)
    project_s = median_time(lambda: project_cloud(points, T_camera_lidar, camera), REPEATS_FAST)
    occluded_s = median_time(lambda: project_cloud(points, T_camera_lidar, camera, occlusion_px=OCCLUSION_PX),
                             REPEATS_FAST)
    colour_s = median_time(lambda: depth_colours(occluded.depth_m, *DEPTH_RANGE_M), REPEATS_FAST)
    draw_s = median_time(lambda: draw_points(image, occluded.uv, colours, radius_px=1), REPEATS_FAST)
    range_s = median_time(lambda: spread_range(occluded.depth_m), REPEATS_FAST)
    drawn = draw_points(image, occluded.uv, colours, radius_px=1)
    scale = ColourScale("depth (m)", *spread_range(occluded.depth_m))
    legend_s = median_time(lambda: with_legend(drawn, scale), REPEATS_FAST)
    jpeg_s = median_time(lambda: encode_jpeg(drawn), REPEATS_FAST)

    log("timing the baseline cv2.projectPoints ...")
    rvec, tvec = to_rvec_tvec(T_camera_lidar)
    baseline_s = median_time(lambda: cv2.projectPoints(points[:, None, :], rvec, tvec, camera.K, camera.dist))
    log(f"  in view {len(plain)}, drawn after occlusion {len(occluded)}")

    peak_memory_mb = peak_rss_mb()
    log(f"done in {time.perf_counter() - started:.1f} s; load average at end: {os.getloadavg()[0]:.2f}")
    result = {
        "benchmark": "overlay",
        "points": len(points),
        "image": [camera.width, camera.height],
        "in_view_points": len(plain),
        "kept_points": len(occluded),
        "overlays_per_s": round(1.0 / overlay_s, 2),
        "overlay_ms": round(overlay_s * 1000, 1),
        "overlay_ms_best": round(min(overlay_times) * 1000, 1),
        "overlays_per_s_float64": round(1.0 / overlay_float64_s, 2),
        "redraw_100k_ms": round(redraw_s * 1000, 1),
        "redraw_baseline_ms": round(redraw_baseline_s * 1000, 1),
        "redraw_ratio": round(redraw_baseline_s / redraw_s, 2),
        "redraw_same_as_baseline": same_redraw,
        "full_resolution_ms": round(full_resolution_s * 1000, 1),
        "stages_ms": {
            "project": round(project_s * 1000, 1),
            "project_with_occlusion": round(occluded_s * 1000, 1),
            "colour_range": round(range_s * 1000, 2),
            "colour": round(colour_s * 1000, 1),
            "draw": round(draw_s * 1000, 1),
            "legend": round(legend_s * 1000, 2),
            "jpeg": round(jpeg_s * 1000, 1),
        },
        "float32_vs_float64": {"same_kept_points": same_points, "max_px": max_px},
        "baseline_projectpoints_per_s": round(1.0 / baseline_s, 2),
        "ratio": round(baseline_s / overlay_s, 2),
        "full_resolution_ratio": round(baseline_s / full_resolution_s, 2),
        "peak_rss_mb": round(peak_memory_mb, 1),
        "load_average": [round(load_start, 2), round(os.getloadavg()[0], 2)],
        "cpu_count": os.cpu_count(),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
