"""The LiDAR-LiDAR plot: the histogram of cloud-to-cloud distances, its bars coloured as the 3D view colours the
source cloud (:func:`backend.core.colour_maps.distance_colours`). The studio redraws it as the sliders move; the
report draws it for every accepted edge."""

from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from backend.core.colour_maps import distance_colours
from backend.plots.render import empty_note, new_figure, styled

BINS = 40


def c2c_histogram(distances_m: np.ndarray, max_m: float, title: str = "cloud-to-cloud distance") -> Figure:
    """Histogram of cloud-to-cloud distances (m, drawn in mm) from 0 to ``max_m``, with their mean, median and
    95th percentile; distances beyond ``max_m`` are counted in the last bar (red, as in the 3D view)."""
    d = np.asarray(distances_m, float)
    d = d[np.isfinite(d)]
    figure = new_figure(4.8, 1.9)
    if d.size == 0 or max_m <= 0:
        return empty_note(figure, "no distances yet")
    d_mm, max_mm = d * 1e3, max_m * 1e3
    counts, edges = np.histogram(np.clip(d_mm, 0, max_mm), bins=BINS, range=(0.0, max_mm))
    colours = distance_colours((edges[:-1] + edges[1:]) / 2e3, max_m) / 255.0
    if (d_mm > max_mm).any():
        colours[-1] = distance_colours(np.array([np.inf]), max_m)[0] / 255.0
    with styled():
        ax = figure.add_subplot()
        ax.bar(edges[:-1], counts, width=np.diff(edges), align="edge", color=colours)
        for value, label, style in ((d_mm.mean(), "mean", "-"), (np.median(d_mm), "median", "--"),
                                    (np.percentile(d_mm, 95), "p95", ":")):
            ax.axvline(min(value, max_mm), color="#333333", ls=style, lw=0.9, label=f"{label} {value:.1f} mm")
        ax.set_xlim(0, max_mm)
        ax.set_xlabel("distance to the target cloud (mm)")
        ax.set_ylabel("points")
        ax.set_title(f"{title} ({len(d_mm)} points)")
        ax.legend(fontsize=6)
    return figure
