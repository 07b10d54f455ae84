"""The calibration report of a session: one self-contained HTML file (no external request), printable to PDF.

It covers every sensor and every rig edge (method, data counts, sigma, verdict and cross-checks), with
residual plots, coverage maps, the observation graph and the rig drawn. The API route, the studio and
``calib-studio report`` all call :func:`render_report`.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np
from markupsafe import Markup

from backend.core.camera import DIST_NAMES
from backend.core.verdict import Verdict
from backend.plots import intrinsics as intrinsics_plots
from backend.plots import rig as rig_plots
from backend.plots.lidar_camera import pose_evidence_figure
from backend.plots.lidar_lidar import c2c_histogram
from backend.plots.render import to_data_uri
from backend.reports.gather import CameraReport, EdgeReport, ReportData, gather
from backend.reports.template import CSS, SECTIONS, TEMPLATE, environment
from backend.store.session import Session

DATA_UNITS = {"lidar_lidar": "cloud pair(s)", "lidar_camera": "image + cloud pair(s)", "multicam": "image set(s)",
              "sweep": "sweep capture(s)", "depth_node": "observation(s)"}
"""What a transform result's ``inputs`` are, by kind."""


def render_report(session: Session) -> str:
    """The session's calibration report as one HTML document (plots inline, CSS inline)."""
    data = gather(session)
    return environment().from_string(TEMPLATE).render(**page_context(data))


def intrinsics_parameters(camera: CameraReport) -> list[dict[str, Any]]:
    """``{"name", "value", "std"}`` of fx, fy, cx, cy (px) and each distortion coefficient of the model; for the
    photogrammetric model of c, xp, yp and its coefficients in px units, with ``value_mm`` and ``std_mm`` where the
    pixel size is known."""
    record = camera.record
    if "photogrammetric" in record:
        return [{"name": f"{name} ({p['unit_px']})", "value": p["value_px"], "std": p["sigma_px"],
                 **({"value_mm": p["value_mm"], "std_mm": p["sigma_mm"], "unit_mm": p["unit_mm"]}
                    if "value_mm" in p else {})}
                for name, p in record["photogrammetric"]["parameters"].items()]
    K, std = record["camera"]["K"], record["std"]
    rows = [{"name": name, "value": K[i][j], "std": std.get(name)}
            for name, (i, j) in zip(("fx", "fy", "cx", "cy"), ((0, 0), (1, 1), (0, 2), (1, 2)), strict=True)]
    dist_std = std.get("dist") or []
    if "splined" in record:  # fx..cy held; hundreds of control points: the knots are described beside the table
        return [row | {"std": None} for row in rows]
    for k, name in enumerate(DIST_NAMES[record["camera"]["model"]]):
        rows.append({"name": name, "value": record["camera"]["dist"][k],
                     "std": dist_std[k] if k < len(dist_std) else None})
    return rows


def transform_plots(edge: EdgeReport) -> dict[str, str | None]:
    """An accepted transform's plots: ``units`` (residual RMS per pose, scene or set), ``c2c`` (LiDAR-LiDAR) and
    ``poses`` (LiDAR-camera target: each pose's board against the plate's outline)."""
    result = edge.result
    units = rig_plots.unit_residual_bars(result.diagnostics, result.parent, result.child)
    has_c2c = edge.c2c_m is not None and len(edge.c2c_m)
    poses = pose_evidence_figure(edge.poses, f"{result.child} -> {result.parent}: each pose's board, in its plane, "
                                 "at the result") if edge.poses else None
    return {"units": to_data_uri(units) if units else None, "poses": to_data_uri(poses) if poses else None,
            "c2c": to_data_uri(c2c_histogram(edge.c2c_m, float(np.max(edge.c2c_m)),
                                             f"{result.child} -> {result.parent}: cloud-to-cloud distance"))
            if has_c2c else None}


def camera_plots(camera: CameraReport) -> dict[str, str | None]:
    """A camera's intrinsics plots: per-view RMS, residual vectors, corner coverage and projection maps."""
    maps = intrinsics_plots.projection_maps(camera.record)
    return {"rms": to_data_uri(intrinsics_plots.view_rms_bars(camera.sensor, camera.record)),
            "vectors": to_data_uri(intrinsics_plots.residual_vectors(*camera.residual_arrays(), camera.image_size,
                                                                     camera.rejected_corners())),
            "coverage": to_data_uri(intrinsics_plots.coverage_map(camera.used_corners(), camera.image_size)),
            "maps": to_data_uri(maps) if maps else None}


def page_context(data: ReportData) -> dict[str, Any]:
    """What the template reads: the gathered data, the plots and the overview's counts."""
    accepted_edges = [e.residual for e in data.edges]
    verdicts = [Verdict.from_record(c.record).level for c in data.cameras]
    verdicts += [e.result.verdict.level if e.result.verdict else "check" for e in data.edges]
    edge_counts = Counter(name for r in accepted_edges for name in (r.edge.parent, r.edge.child))
    rig_figure, ellipsoid_scale = rig_plots.rig_drawing(data.tree)
    return {
        "css": Markup(CSS), "sections": SECTIONS, "session": data.session, "generated_at": data.generated_at,
        "tree": data.tree, "frames": data.frames, "cameras": data.cameras, "edges": data.edges,
        "cameras_without_intrinsics": data.cameras_without_intrinsics, "acceptance_log": data.acceptance_log,
        "flagged": [r for r in data.tree.edges if r.flagged],
        "worst": max((r for r in accepted_edges if math.isfinite(r.chi2)), key=lambda r: r.chi2, default=None),
        "verdict_counts": {level: n for level in ("trusted", "check", "reject") if (n := verdicts.count(level))},
        "edge_counts": edge_counts,
        "camera_rms": {c.sensor: f"{c.record['camera']['model']}, RMS {c.record['rms_px']:.3f} px ({c.result_id})"
                       for c in data.cameras},
        "params": {c.sensor: intrinsics_parameters(c) for c in data.cameras},
        "camera_plots": {c.sensor: camera_plots(c) for c in data.cameras},
        "edge_plots": [transform_plots(e) for e in data.edges],
        "geometry_plots": [transform_plots(e) for e in data.geometries], "geometries": data.geometries,
        "problems": data.tree.problems(), "units": DATA_UNITS,
        "graph_plot": to_data_uri(rig_plots.observation_graph(data.tree)), "rig_plot": to_data_uri(rig_figure),
        "ellipsoid_scale": ellipsoid_scale,
    }
