"""The report's page: one Jinja2 template (autoescaped) with its CSS inline, and the filters it formats with.

Print CSS puts each section on its own page and keeps figures and tables whole, so a browser's
*Print to PDF* gives a clean document.
"""

from __future__ import annotations

import math
import time
from typing import Any

import jinja2
import numpy as np

from backend.core.transforms import to_xyz_ypr


def number(value: Any, digits: int = 4) -> str:
    """A number with ``digits`` significant digits; '—' for None or a value that is not finite."""
    if value is None or isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        return "—" if value is None else str(value)
    if not math.isfinite(value):
        return "—"
    return str(int(value)) if isinstance(value, int | np.integer) else f"{value:.{digits}g}"


def fixed(value: Any, decimals: int = 2, factor: float = 1.0) -> str:
    """``value * factor`` with ``decimals`` decimals (e.g. m shown as mm with ``factor=1000``); '—' when unknown."""
    if value is None or not math.isfinite(value):
        return "—"
    return f"{value * factor:.{decimals}f}"


def utc(seconds: float | None) -> str:
    """s since the epoch as ``YYYY-MM-DD HH:MM:SS UTC``."""
    return "—" if not seconds else time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(seconds))


def pose(T: np.ndarray) -> dict[str, list[float]]:
    """``{"xyz_m": [3], "ypr_deg": [3]}`` of a 4x4 (ROS yaw, pitch, roll)."""
    xyz, ypr = to_xyz_ypr(np.asarray(T, dtype=float))
    return {"xyz_m": xyz.tolist(), "ypr_deg": np.degrees(ypr).tolist()}


def _scalar(value: Any) -> bool:
    return value is None or isinstance(value, str | bool | int | float)


def _shown(value: Any) -> str:
    """A scalar, a short list of numbers or a matrix as report text."""
    if _scalar(value):
        return number(value)
    if isinstance(value, list) and value and all(isinstance(row, list) for row in value):
        return f"{len(value)}×{len(value[0])} matrix"
    if isinstance(value, list) and all(_scalar(v) for v in value):
        return "[" + ", ".join(number(v) for v in value[:8]) + (", …" if len(value) > 8 else "") + "]"
    return f"{type(value).__name__} of {len(value)}"


def _flat(mapping: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dicts as ``a.b`` keys (one row each)."""
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        if isinstance(value, dict):
            out |= _flat(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = value
    return out


def details(mapping: dict[str, Any], max_rows: int = 40) -> dict[str, Any]:
    """A record's ``residuals`` or ``diagnostics`` laid out for the page: ``rows`` (name, shown value) of its
    scalars, short lists and nested dicts, and ``tables`` (name, columns, rows) of its lists of records (a
    scene table, per-pair residuals), at most ``max_rows`` rows each."""
    rows, tables = [], []
    for key, value in _flat(mapping).items():
        if isinstance(value, list) and value and all(isinstance(item, dict) for item in value):
            items = [_flat(item) for item in value[:max_rows]]
            columns = [c for c in dict.fromkeys(c for item in items for c in item)
                       if any(_scalar(item.get(c)) or isinstance(item.get(c), list) for item in items)]
            tables.append({"name": key, "columns": columns, "more": max(len(value) - max_rows, 0),
                           "rows": [[_shown(item.get(c)) for c in columns] for item in items]})
        else:
            rows.append((key, _shown(value)))
    return {"rows": rows, "tables": tables}


def environment() -> jinja2.Environment:
    """The Jinja2 environment of the report (autoescape on, undefined names an error)."""
    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined, trim_blocks=True,
                             lstrip_blocks=True)
    env.filters.update(number=number, fixed=fixed, utc=utc)
    env.globals.update(pose=pose, details=details)
    return env


CSS = """
:root { --ink: #1d2430; --muted: #5b6675; --line: #d5dbe3; --band: #f3f5f8;
        --trusted: #1e7b3c; --check: #a86a00; --reject: #b3261e; }
* { box-sizing: border-box; }
body { font: 13px/1.45 -apple-system, "Segoe UI", "Liberation Sans", "DejaVu Sans", Arial, sans-serif;
       color: var(--ink); margin: 0 auto; max-width: 1100px; padding: 24px 32px 64px; }
header h1 { margin: 0 0 4px; font-size: 24px; }
header p { margin: 2px 0; color: var(--muted); }
nav { margin: 14px 0 8px; padding: 8px 12px; background: var(--band); border-radius: 6px; }
nav a { margin-right: 14px; color: var(--ink); }
section { margin-top: 28px; border-top: 2px solid var(--ink); padding-top: 8px; }
h2 { font-size: 19px; margin: 4px 0 10px; }
h3 { font-size: 15px; margin: 20px 0 6px; padding-bottom: 2px; border-bottom: 1px solid var(--line); }
h4 { font-size: 13px; margin: 12px 0 4px; color: var(--muted); }
table { border-collapse: collapse; margin: 6px 0 10px; font-variant-numeric: tabular-nums; }
th, td { border: 1px solid var(--line); padding: 3px 7px; text-align: left; vertical-align: top; }
th { background: var(--band); font-weight: 600; }
td.n { text-align: right; white-space: nowrap; }
table.facts th { width: 220px; }
.badge { display: inline-block; padding: 1px 8px; border-radius: 10px; color: white; font-weight: 600;
         font-size: 12px; }
.badge.trusted { background: var(--trusted); } .badge.check { background: var(--check); }
.badge.reject { background: var(--reject); } .badge.none { background: var(--muted); }
.flag { color: var(--reject); font-weight: 700; }
.note { color: var(--muted); font-size: 12px; }
.warn { color: var(--check); }
ul.reasons { margin: 4px 0 8px 18px; padding: 0; }
figure { margin: 10px 0; }
figure img { max-width: 100%; height: auto; display: block; }
figcaption { color: var(--muted); font-size: 12px; margin-top: 2px; }
figure img.half { max-width: 60%; }
ul.problems { margin: 4px 0 10px 18px; padding: 0; color: var(--reject); }
@page { size: A4; margin: 12mm; }
@media print {
  body { max-width: none; padding: 0; font-size: 11px; }
  nav { display: none; }
  section { break-before: page; border-top: none; margin-top: 0; }
  section#overview { break-before: auto; }
  figure, table { break-inside: avoid; }
  h3, h4 { break-after: avoid; }
}
"""

TEMPLATE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta http-equiv="Content-Security-Policy" content="default-src 'none'; img-src data:; style-src 'unsafe-inline'">
<title>Calibration report: {{ session.name }}</title>
<style>{{ css }}</style>
</head>
<body>
{% macro badge(verdict) %}
{% if verdict %}<span class="badge {{ verdict.level }}">{{ verdict.level }}</span>
{% else %}<span class="badge none">no verdict</span>{% endif %}
{% endmacro %}
{% macro reasons(verdict) %}
{% if verdict and verdict.reasons %}<ul class="reasons">{% for r in verdict.reasons %}<li>{{ r }}</li>{% endfor %}</ul>
{% endif %}
{% endmacro %}
{% macro sigma(std) %}
{% for v in std.trans_m %}{{ v | fixed(2, 1000) }}{% if not loop.last %}, {% endif %}{% endfor %} mm;
{% for v in std.rot_deg %}{{ v | fixed(3) }}{% if not loop.last %}, {% endif %}{% endfor %} deg
{% endmacro %}
{% macro posecells(T) %}{% set p = pose(T) %}
{% for v in p.xyz_m %}<td class="n">{{ v | fixed(4) }}</td>{% endfor %}
{% for v in p.ypr_deg %}<td class="n">{{ v | fixed(3) }}</td>{% endfor %}
{% endmacro %}
{% macro detail_tables(d) %}
{% if d.rows %}<table class="facts">{% for k, v in d.rows %}<tr><th>{{ k }}</th><td>{{ v }}</td></tr>{% endfor %}
</table>{% endif %}
{% for t in d.tables %}<h4>{{ t.name }}</h4>
<table><tr>{% for c in t.columns %}<th>{{ c }}</th>{% endfor %}</tr>
{% for row in t.rows %}<tr>{% for v in row %}<td>{{ v }}</td>{% endfor %}</tr>{% endfor %}</table>
{% if t.more %}<p class="note">and {{ t.more }} more rows</p>{% endif %}
{% endfor %}
{% endmacro %}

{% macro transform_block(e, anchor, figures) %}{% set res = e.result %}{% set rr = e.residual %}
<div class="sensor-block">
<h3 id="{{ anchor }}">{{ res.parent }} &rarr; {{ res.child }}: {{ res.kind }} ({{ res.method or "—" }})
  {{ badge(res.verdict) }}{% if rr and rr.flagged %} <span class="flag">beyond 3 sigma</span>{% endif %}</h3>
<table class="facts">
<tr><th>Result</th><td>{{ e.record.id }}{% if rr %} (slot {{ rr.edge.slot }}){% endif %}, solved
  {{ e.record.created | utc }} in {{ res.seconds | fixed(2) }} s, {{ "converged" if res.converged else
  "NOT converged" }}</td></tr>
<tr><th>Data</th><td>{{ e.n_inputs }} {{ units.get(res.kind, "inputs") }}{% if e.record.inputs %}:
  {{ e.record.inputs[:12] | join(", ") }}{% if e.record.inputs | length > 12 %}, …{% endif %}{% endif %}</td></tr>
{% set p = pose(res.T_parent_child) %}
<tr><th>T_{{ res.parent }}_{{ res.child }}</th><td>xyz {% for v in p.xyz_m %}{{ v | fixed(4) }}{% if not loop.last %},
  {% endif %}{% endfor %} m; ypr {% for v in p.ypr_deg %}{{ v | fixed(3) }}{% if not loop.last %}, {% endif %}
  {% endfor %} deg</td></tr>
<tr><th>1-sigma (t along {{ res.parent }}, r about {{ res.child }})</th><td>{{ sigma(res.std) }}</td></tr>
{% if rr %}<tr><th>Residual in the fused rig</th><td>{{ rr.trans_m | fixed(2, 1000) }} mm, {{ rr.rot_deg | fixed(3) }}
  deg, chi2 {{ rr.chi2 | number(3) }}; against the other edges {% if rr.disagreement_sigma is none %}nothing else
  constrains it{% else %}{{ rr.disagreement_sigma | fixed(2) }} sigma{% endif %}</td></tr>
{% if rr.conflicts_with %}<tr><th>Disagrees with</th><td class="flag">{{ rr.conflicts_with | join(", ") }}</td></tr>
{% endif %}{% if rr.edge.note %}<tr><th>Note</th><td>{{ rr.edge.note }}</td></tr>{% endif %}{% endif %}
</table>
<h4>Verdict and cross-checks</h4>{{ reasons(res.verdict) }}
{% for w in res.warnings %}<p class="warn">warning: {{ w }}</p>{% endfor %}
<h4>Residual statistics</h4>{{ detail_tables(details(res.residuals)) }}
{% if res.diagnostics %}<h4>Diagnostics</h4>{{ detail_tables(details(res.diagnostics)) }}{% endif %}
{% if figures.units %}<figure><img src="{{ figures.units }}" alt="residuals per unit"><figcaption>The residual RMS
  of each unit the transform was solved from.</figcaption></figure>{% endif %}
{% if figures.poses %}<figure><img src="{{ figures.poses }}" alt="per-pose evidence"><figcaption>Each board pose as
  the LiDAR saw it, in the board's plane at the result: the face points coloured by their distance from the plane
  the camera saw, the scan lines' ends (crosses), the fitted plate outline (solid) and the printed pattern (dashed);
  above each, its fit and how far the solve without it moves the result (red: beyond 3 of the Jacobian's sigmas,
  a pose to look at, drop and re-solve).</figcaption></figure>
{% elif e.poses_note %}<p class="warn">No per-pose evidence: {{ e.poses_note }}.</p>{% endif %}
{% if figures.c2c %}<figure><img src="{{ figures.c2c }}" alt="cloud-to-cloud histogram"><figcaption>Cloud-to-cloud
  distances recomputed from the capture pairs: {{ e.c2c_note }}.</figcaption></figure>
{% elif e.c2c_note %}<p class="warn">No cloud-to-cloud histogram: {{ e.c2c_note }}.</p>{% endif %}
</div>
{% endmacro %}

<header>
<h1>Calibration report: {{ session.name }}</h1>
{% if session.title %}<p>{{ session.title }}</p>{% endif %}
<p>Generated {{ generated_at | utc }} &middot; board {{ session.board or "none" }} &middot; rig root
<code>{{ tree.root }}</code></p>
</header>
<nav>{% for id, title in sections %}<a href="#{{ id }}">{{ title }}</a>{% endfor %}</nav>

<section id="overview">
<h2>Overview</h2>
{% if problems %}<ul class="problems">{% for line in problems %}<li>{{ line }}</li>{% endfor %}</ul>
{% endif %}
<table class="facts">
<tr><th>Frames (besides {{ tree.root }})</th><td>{{ frames | length }}</td></tr>
<tr><th>Accepted results</th><td>{{ session.accepted | length }}</td></tr>
<tr><th>Cameras with accepted intrinsics</th><td>{{ cameras | length }} of {{ cameras | length +
  cameras_without_intrinsics | length }}</td></tr>
<tr><th>Accepted rig edges</th><td>{{ edges | length }} (and {{ tree.edges | length - edges | length }} mounting
  priors)</td></tr>
<tr><th>Edges beyond 3 sigma</th><td>{% if flagged %}<span class="flag">{{ flagged | length }}:
  {% for e in flagged %}{{ e.edge.parent }} &rarr; {{ e.edge.child }} ({{ e.edge.kind }}){% if not loop.last %},
  {% endif %}{% endfor %}</span>{% else %}none{% endif %}</td></tr>
<tr><th>Worst edge residual</th><td>{% if worst %}chi2 {{ worst.chi2 | number(3) }},
  {{ worst.trans_m | fixed(2, 1000) }} mm, {{ worst.rot_deg | fixed(3) }} deg ({{ worst.edge.parent }} &rarr;
  {{ worst.edge.child }}, {{ worst.edge.kind }}){% else %}—{% endif %}</td></tr>
<tr><th>Loops</th><td>{{ tree.loops | length }}{% for loop_ in tree.loops %}; {{ loop_.frames | join(" → ") }}:
  {{ loop_.trans_m | fixed(2, 1000) }} mm, {{ loop_.rot_deg | fixed(3) }} deg{% endfor %}</td></tr>
<tr><th>Frames not connected to {{ tree.root }}</th><td>{% if tree.unconnected %}<span class="flag">
  {% for name, links in tree.unconnected.items() %}{{ name }} (connects to {{ links | join(", ") or "nothing" }})
  {% endfor %}</span>{% else %}none{% endif %}</td></tr>
<tr><th>Verdicts of the accepted results</th><td>{% for level, n in verdict_counts.items() %}
  <span class="badge {{ level }}">{{ level }}</span> {{ n }}&nbsp; {% endfor %}</td></tr>
</table>
</section>

<section id="sensors">
<h2>Sensors</h2>
<p class="note">Each frame's fused pose in its parent (m; ROS yaw, pitch, roll in deg) and its 1-sigma from the rig
solve (translation in mm along the parent's axes, rotation in deg about the frame's own axes); each sensor's clock
offset against the rig's clock (ms, 1-sigma), where one was measured and accepted.</p>
<table>
<tr><th>frame</th><th>kind</th><th>parent</th><th>x</th><th>y</th><th>z</th><th>yaw</th><th>pitch</th><th>roll</th>
<th>sigma</th><th>clock (ms)</th><th>captures</th><th>edges</th><th>intrinsics</th></tr>
{% for f in frames %}{% set est = tree.frames.get(f.name) %}
<tr><td><b>{{ f.name }}</b></td><td>{{ f.kind }}</td><td>{{ est.parent if est else f.parent }}</td>
{% if est %}{{ posecells(est.T_parent_child) }}<td>{{ sigma(est.std) }}</td>
{% else %}<td colspan="7" class="flag">not connected to {{ tree.root }}</td>{% endif %}
<td class="n">{% if f.clock_offset_std_s is none %}{% if f.kind != "frame" %}not measured{% else %}—{% endif %}
{% else %}{{ "%.2f" | format(1000 * f.clock_offset_s) }} ± {{ "%.2f" | format(1000 * f.clock_offset_std_s) }}
{% endif %}</td>
<td class="n">{{ f.captures }}</td><td class="n">{{ edge_counts.get(f.name, 0) }}</td>
<td>{% if f.kind == "camera" %}{% if f.name in camera_rms %}{{ camera_rms[f.name] }}{% else %}<span class="warn">
  {{ cameras_without_intrinsics.get(f.name, "none") }}</span>{% endif %}{% else %}—{% endif %}</td></tr>
{% endfor %}
</table>
</section>

<section id="intrinsics">
<h2>Camera intrinsics</h2>
{% for name, why in cameras_without_intrinsics.items() %}<p class="warn">{{ name }}: {{ why }}.</p>{% endfor %}
{% for c in cameras %}{% set r = c.record %}
<div class="sensor-block">
<h3 id="camera-{{ c.sensor }}">{{ c.sensor }} {{ badge(r.verdict) }}</h3>
<table class="facts">
<tr><th>Result</th><td>{{ c.result_id }}, solved {{ r.created | utc }} in {{ r.seconds | fixed(2) }} s</td></tr>
<tr><th>Model</th><td>{{ r.camera.model }}, {{ r.camera.width }}×{{ r.camera.height }} px, board {{ r.board }}</td></tr>
<tr><th>Data</th><td>{{ c.views | selectattr("used") | list | length }} of {{ r.views | length }} views used,
  {{ c.n_corners }} corners (set {{ r.corners.chosen if r.corners else "—" }}){% if r.rejected_corners is defined %},
  {{ r.rejected_corners }} rejected as outliers{% if r.views_dropped %} (views dropped:
  {{ r.views_dropped | join(", ") }}){% endif %}{% endif %}</td></tr>
<tr><th>Reprojection RMS</th><td>{{ r.rms_px | fixed(4) }} px</td></tr>
<tr><th>Projection sigma (mrcal's noise model)</th><td>{% set pu = r.projection_uncertainty %}{% if
  pu.max_covered_px is defined and pu.max_covered_px is not none %}worst {{ pu.max_covered_px | fixed(3) }} px where
  the boards reach ({{ (100 * pu.covered_share) | round | int }} % of the image), {% endif %}max
  {{ r.projection_sigma_px.max | fixed(3) }} px, mean {{ r.projection_sigma_px.mean | fixed(3) }} px, centre
  {{ r.projection_sigma_px.centre | fixed(3) }} px</td></tr>
{% if r.board_flex %}<tr><th>Board flex</th><td>{% if r.board_flex.status == "solved" %}x
  {{ r.board_flex.warp_mm[0] | fixed(3) }} ± {{ r.board_flex.std_mm[0] | fixed(3) }} mm, y
  {{ r.board_flex.warp_mm[1] | fixed(3) }} ± {{ r.board_flex.std_mm[1] | fixed(3) }} mm{% else %}{{
  r.board_flex.status }}: {{ r.board_flex.detail }}{% endif %}</td></tr>{% endif %}
{% if r.jackknife %}<tr><th>Jackknife (cross-check)</th><td>up to {{ r.jackknife.ratio | fixed(1) }}× the
  noise model's parameter sigmas, worst projection {{ r.jackknife.projection_max_px | fixed(3) }} px</td></tr>{%
  endif %}
<tr><th>Cross-validation</th><td>{{ r.cross_validation.status }}: {{ r.cross_validation.detail }}</td></tr>
{% if r.model_comparison %}<tr><th>Model comparison</th><td>{{ r.model_comparison.recommended }}:
  {{ r.model_comparison.reason }}</td></tr>{% endif %}
</table>
<table>
<tr><th>parameter</th>{% for n in params[c.sensor] %}<th>{{ n.name }}</th>{% endfor %}</tr>
<tr><th>value</th>{% for n in params[c.sensor] %}<td class="n">{{ n.value | number(6) }}</td>{% endfor %}</tr>
<tr><th>1-sigma</th>{% for n in params[c.sensor] %}<td class="n">{{ n.std | number(3) }}</td>{% endfor %}</tr>
{% if params[c.sensor][0].value_mm is defined %}
<tr><th>value (mm)</th>{% for n in params[c.sensor] %}<td class="n">{{ n.value_mm | number(6) }}
  {{ n.unit_mm }}</td>{% endfor %}</tr>
<tr><th>1-sigma (mm)</th>{% for n in params[c.sensor] %}<td class="n">{{ n.std_mm | number(3) }}</td>{% endfor %}</tr>
{% endif %}
</table>
{% if r.photogrammetric is defined %}{% set pg = r.photogrammetric %}
<p>Photogrammetric model ({{ pg.axes }}; pixel size {{ pg.pixel_size_um if pg.pixel_size_um else "not given" }}
  um). As OpenCV's pinhole-radtan: {{ "exact" if pg.opencv.exact else "within %.3g px over the image (%s)" |
  format(pg.opencv.max_residual_px, pg.opencv.note) }}.</p>
<table>
<tr><th>correlation</th>{% for n in pg.correlation.names %}<th>{{ n }}</th>{% endfor %}</tr>
{% for row in pg.correlation.matrix %}<tr><th>{{ pg.correlation.names[loop.index0] }}</th>{% for v in row %}
  <td class="n">{{ v | fixed(3) }}</td>{% endfor %}</tr>{% endfor %}
</table>
<table>
<tr><th>interior-exterior (largest over {{ pg.interior_exterior.per_view | length }} views)</th>
  {% for n in pg.interior_exterior.exterior %}<th>{{ n }}</th>{% endfor %}</tr>
{% for row in pg.interior_exterior.largest %}<tr><th>{{ pg.interior_exterior.interior[loop.index0] }}</th>
  {% for v in row %}<td class="n">{{ v | fixed(3) }}</td>{% endfor %}</tr>{% endfor %}
</table>
{% endif %}
{% if r.splined is defined %}{% set sp = r.splined %}
<p>mrcal's splined model <code>{{ sp.lensmodel }}</code>: {{ sp.knots[0] }}×{{ sp.knots[1] }} knots over
  {{ sp.fov_x_deg }}° across, {{ sp.spline_values }} spline values measured {{ sp.measurements_per_value }} times
  each; fx, fy, cx, cy are held, as mrcal holds them. {{ sp.detail }}. As OpenCV's pinhole-radtan (what ROS and
  Kalibr can load; fitted at the views' corners): within {{ sp.opencv.max_residual_px | fixed(3) }} px there (RMS
  {{ sp.opencv.rms_residual_px | fixed(3) }} px; its frame turned {{ sp.opencv.rotation_deg | fixed(2) }}°),
  {{ sp.opencv.max_residual_over_image_px | fixed(3) }} px over the {{ (100 * sp.opencv.image_share_inverting) | round |
  int }} % of the image where it inverts.</p>
<pre class="knots">{% for row in sp.unconstrained_map %}{{ row }}
{% endfor %}</pre>
<p class="note">Knots: # reached by the corners, . under the image but reached by none (held smooth by the
  regularization, extrapolated).</p>
{% endif %}
<h4>Verdict</h4>{{ reasons(r.verdict) }}
{% for w in r.warnings %}<p class="warn">warning: {{ w }}</p>{% endfor %}
{% if c.unreadable %}<p class="warn">views left out of the plots: {{ c.unreadable | join("; ") }}</p>{% endif %}
{% if c.views | selectattr("recomputed") | list %}<p class="note">The record lacks the residuals of
  {{ c.views | selectattr("recomputed") | list | length }} view(s): recomputed from their captures, the accepted
  camera and the board poses.</p>{% endif %}
{% set p = camera_plots[c.sensor] %}
<figure><img src="{{ p.rms }}" alt="{{ c.sensor }} per-view RMS"><figcaption>Per-view reprojection RMS; a view more
  than {{ r.settings.outlier_factor }} times the median is an outlier.</figcaption></figure>
<figure><img src="{{ p.vectors }}" alt="{{ c.sensor }} residual vectors"><figcaption>Residual of every corner of the
  used views (detected minus projected), across the image and by view.</figcaption></figure>
<figure><img src="{{ p.coverage }}" alt="{{ c.sensor }} coverage" class="half"><figcaption>Where the board's corners
  were seen: empty cells are where the lens is extrapolated.</figcaption></figure>
{% if p.maps %}<figure><img src="{{ p.maps }}" alt="{{ c.sensor }} projection uncertainty"><figcaption>Projection
  1-sigma across the image (white contour: the tolerance) and the cross-validation's difference between the two
  halves of the views.</figcaption></figure>{% endif %}
</div>
{% endfor %}
{% if not cameras %}<p>No camera has accepted intrinsics.</p>{% endif %}
</section>

<section id="edges">
<h2>Rig edges</h2>
<p class="note">Every accepted result that relates two frames, with its own uncertainty and verdict, and how far it
lies from the rig fused from all edges.</p>
{% for e in edges %}{{ transform_block(e, "edge-" ~ loop.index, edge_plots[loop.index0]) }}{% endfor %}
{% if not edges %}<p>No accepted result relates two frames yet: the rig holds only its mounting priors.</p>{% endif %}
{% if geometries %}<h3>Sensor geometries</h3>
<p class="note">Accepted transforms inside one sensor (a swept scanner's mount to its scanner): not edges of the rig
graph.</p>
{% for e in geometries %}{{ transform_block(e, "geometry-" ~ loop.index, geometry_plots[loop.index0]) }}{% endfor %}
{% endif %}
</section>

<section id="depth">
<h2>Depth network</h2>
{% set depth = session.depth_network %}{% if depth %}
<p class="note">Every depth node's pose in the cell's world frame in the paper's order: X, Y, Z (m) and RotZ, RotY,
RotX (deg, R = Rz Ry Rx about the node's axes), with the largest 1-sigma of the fused rig (translation in mm,
rotation in deg) and the verdict of its accepted result.</p>
{% if depth.problems %}<ul class="problems">{% for line in depth.problems %}<li>{{ line }}</li>{% endfor %}</ul>
{% endif %}
<table>
<tr><th>node</th><th>X</th><th>Y</th><th>Z</th><th>RotZ</th><th>RotY</th><th>RotX</th><th>sigma (mm)</th>
<th>sigma (deg)</th><th>verdict</th><th>result</th></tr>
{% for row in depth.pose_table %}{% set n = depth.nodes[row.node] %}
<tr><td><b>{{ row.node }}</b></td><td class="n">{{ row.X | fixed(4) }}</td><td class="n">{{ row.Y | fixed(4) }}</td>
<td class="n">{{ row.Z | fixed(4) }}</td><td class="n">{{ row.RotZ | fixed(3) }}</td>
<td class="n">{{ row.RotY | fixed(3) }}</td><td class="n">{{ row.RotX | fixed(3) }}</td>
<td class="n">{{ row.sigma_mm | fixed(2) }}</td><td class="n">{{ row.sigma_deg | fixed(4) }}</td>
<td>{{ badge(n.verdict) }}</td><td>{{ n.result_id or "—" }}</td></tr>
{% endfor %}
</table>
{% for row in depth.pose_table %}{% set n = depth.nodes[row.node] %}<h4>{{ row.node }}: {{ n.verdict.level }}</h4>
{{ reasons(n.verdict) }}{% endfor %}
<h3>Verification against laser-measured distances</h3>
{% if depth.verification %}
<table><tr><th>from</th><th>to</th><th>measured (mm)</th><th>estimated (mm)</th><th>error (mm)</th></tr>
{% for r in depth.verification %}<tr><td>{{ r.a }}</td><td>{{ r.b }}</td>
<td class="n">{{ r.measured_m | fixed(1, 1000) }}</td><td class="n">{{ r.estimated_m | fixed(1, 1000) }}</td>
<td class="n">{{ r.error_m | fixed(1, 1000) }}</td></tr>
{% endfor %}</table>
<p class="note">Estimated: the distance between the two picked points at the nodes' current poses (a point seen by
several nodes is their weighted mean); error = estimated - measured.</p>
{% else %}<p>No verification distance yet: pick two points (the crosses) and type their laser-measured distance.</p>
{% endif %}
{% else %}<p>The rig has no depth nodes.</p>{% endif %}
</section>

<section id="graph">
<h2>Observation graph</h2>
<figure><img src="{{ graph_plot }}" alt="observation graph"><figcaption>Which frames were calibrated against which:
  arrows point from parent to child of each measured relation, coloured by its normalised chi2 in the fused rig
  (green fits, red disagrees; '!' beyond 3 sigma).</figcaption></figure>
</section>

<section id="rig">
<h2>The rig</h2>
<figure><img src="{{ rig_plot }}" alt="the rig in 3D"><figcaption>Every frame in {{ tree.root }} (axes x red, y green,
  z blue), its 1-sigma position ellipsoid scaled {{ ellipsoid_scale | number }} times, the tree's links dashed and the
  accepted edges coloured by residual.</figcaption></figure>
<h4>Every edge of the pose graph</h4>
<table>
<tr><th>parent</th><th>child</th><th>kind</th><th>result</th><th>trans (mm)</th><th>rot (deg)</th><th>chi2</th>
<th>vs the rest (sigma)</th><th></th></tr>
{% for rr in tree.edges %}<tr><td>{{ rr.edge.parent }}</td><td>{{ rr.edge.child }}</td><td>{{ rr.edge.kind }}</td>
<td>{{ rr.edge.result_id or "mounting" }}</td><td class="n">{{ rr.trans_m | fixed(2, 1000) }}</td>
<td class="n">{{ rr.rot_deg | fixed(3) }}</td><td class="n">{{ rr.chi2 | number(3) }}</td>
<td class="n">{{ rr.disagreement_sigma | fixed(2) }}</td><td>{% if rr.flagged %}<span class="flag">flagged</span>
{% endif %}</td></tr>
{% endfor %}
</table>
{% if tree.loops %}<h4>Loops</h4>
<table><tr><th>frames</th><th>closure (mm)</th><th>closure (deg)</th></tr>
{% for loop_ in tree.loops %}<tr><td>{{ loop_.frames | join(" → ") }}</td><td class="n">{{ loop_.trans_m |
  fixed(2, 1000) }}</td><td class="n">{{ loop_.rot_deg | fixed(3) }}</td></tr>{% endfor %}
</table>{% endif %}
</section>

<section id="log">
<h2>Acceptance log</h2>
<table><tr><th>when</th><th>slot</th><th>result</th><th>verdict</th><th>confirmed</th><th>note</th></tr>
{% for a in acceptance_log %}<tr><td>{{ a.at | utc }}</td><td>{{ a.slot }}</td><td>{{ a.result_id or ("emptied" if
a.note else "reverted") }}</td><td>{{ a.verdict or "—" }}</td><td>{{ "yes" if a.confirmed else "" }}</td>
<td>{{ a.note or "" }}</td></tr>{% endfor %}
</table>
</section>
</body>
</html>
"""

SECTIONS = [("overview", "Overview"), ("sensors", "Sensors"), ("intrinsics", "Camera intrinsics"),
            ("edges", "Rig edges"), ("depth", "Depth network"), ("graph", "Observation graph"), ("rig", "The rig"),
            ("log", "Acceptance log")]
"""Section ids and headings, in page order."""
