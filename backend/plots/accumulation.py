"""An accumulated cloud's coverage of its sensor's field of view: the returns per angular cell as an image, cells
never hit in red, cells outside the field of view blank, the share hit in the title."""

from __future__ import annotations

import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure

from backend.core.accumulation import Coverage
from backend.plots.render import empty_note, new_figure, styled


def coverage_image(coverage: Coverage | None, title: str = "") -> Figure:
    """The counts per cell (log scale, row 0 at the top, the sensor's left on the left) over the field of view."""
    figure = new_figure(4.8, 2.4)
    if coverage is None:
        return empty_note(figure, "no accumulated cloud yet")
    half_h, half_v = np.degrees(coverage.fov.horizontal_rad) / 2, np.degrees(coverage.fov.vertical_rad) / 2
    with styled():
        ax = figure.add_subplot(1, 1, 1)
        counts = np.where(coverage.inside, np.log10(1 + coverage.counts), np.nan)
        missed = np.where(coverage.inside & (coverage.counts == 0), 1.0, np.nan)
        extent = (half_h, -half_h, -half_v, half_v)  # azimuth from left (+) to right (-), elevation up
        image = ax.imshow(counts, extent=extent, cmap="viridis", aspect="auto", interpolation="nearest")
        ax.imshow(missed, extent=extent, cmap=ListedColormap(["#e03131"]), aspect="auto", interpolation="nearest")
        figure.colorbar(image, ax=ax, label="log10(1 + returns)")
        ax.set_xlabel("azimuth (deg, left +)")
        ax.set_ylabel("elevation (deg)")
        ax.set_title(f"{title}{' · ' if title else ''}{100 * coverage.share:.1f} % of the field of view hit "
                     f"(cells {np.degrees(coverage.cell_rad):g} deg; red: none yet)")
    return figure
