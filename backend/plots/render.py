"""One drawing style for every plot, and the two ways a plot leaves: an SVG ``data:`` URI for the report, an RGB
array for the studio's panel.

Figures are made with :class:`matplotlib.figure.Figure` directly (no pyplot state), so plots can be drawn from
any thread.
"""

from __future__ import annotations

import base64
import io
import math

import matplotlib as mpl
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

USED, OUTLIER, UNUSED = "#3b6ea8", "#c0392b", "#a0a0a0"
"""Colours of a view (or frame) the solve used, flagged as an outlier, or left out."""
STYLE = {"font.size": 8, "axes.titlesize": 9, "axes.labelsize": 8, "svg.fonttype": "path", "figure.dpi": 100}
PANEL_WIDTH_PX = 480
"""Width of a plot in the studio's side panel (px)."""


def styled():
    """The house style as a matplotlib ``rc_context``: draw (and save) every figure inside it."""
    return mpl.rc_context(STYLE)


def new_figure(width_in: float, height_in: float) -> Figure:
    """A figure of ``width_in`` x ``height_in`` inches, laid out so labels fit."""
    with styled():
        return Figure(figsize=(width_in, height_in), layout="constrained")


def to_svg(figure: Figure) -> bytes:
    """The figure as a self-contained SVG document (fonts drawn as paths)."""
    buffer = io.BytesIO()
    with styled():
        figure.savefig(buffer, format="svg", bbox_inches="tight")
    return buffer.getvalue()


def to_data_uri(figure: Figure) -> str:
    """The figure as an SVG ``data:`` URI (:func:`to_svg`)."""
    return "data:image/svg+xml;base64," + base64.b64encode(to_svg(figure)).decode("ascii")


def to_rgb(figure: Figure, width_px: int = PANEL_WIDTH_PX) -> np.ndarray:
    """The figure rasterised ``width_px`` wide, as an (H, W, 3) uint8 RGB array (the studio's image widgets)."""
    figure.set_dpi(width_px / figure.get_figwidth())
    canvas = FigureCanvasAgg(figure)
    with styled():
        canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def nice_factor(value: float) -> float:
    """The 1-2-5 step at or below ``value`` (for arrow and ellipsoid scales), at least 1."""
    if not math.isfinite(value) or value <= 1:
        return 1.0
    exponent = math.floor(math.log10(value))
    mantissa = max(m for m in (1, 2, 5) if m * 10**exponent <= value)
    return float(mantissa * 10**exponent)


def image_axes(ax, size: tuple[int, int], title: str) -> None:
    """Axes over an image of ``size`` (width, height) px, rows down as in the image."""
    ax.set_xlim(0, size[0])
    ax.set_ylim(size[1], 0)
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title(title)


def empty_note(figure: Figure, text: str) -> Figure:
    """``figure`` with ``text`` written in its middle (a plot with nothing to show yet)."""
    figure.text(0.5, 0.5, text, ha="center", va="center", color="#787878")
    return figure
