"""The time offset's plot: both sensors' signals on sensor a's clock and axes (b's shifted by the offset and turned
by the fitted mounting rotation: where the offset is right, the two lie on each other), and the alignment's score
over the offsets searched."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from backend.plots.render import empty_note, new_figure, styled

AXIS_COLOURS = ("#c92a2a", "#2b8a3e", "#1864ab")


def aligned_signals(record: dict[str, Any] | None) -> Figure:
    """A time-offset result's signals per axis (a thin, b thick and shifted) and its score curve."""
    figure = new_figure(4.8, 3.6)
    if record is None:
        return empty_note(figure, "no time offset measured yet")
    a, b = record["sensor_a"], record["sensor_b"]
    signal_a, signal_b = record["signals"][a], record["signals"][b]
    offset_s = float(record["time_offset_s"])
    R_a_b = np.asarray(record["R_a_b"])
    t0 = float(signal_a["t_s"][0])
    unit = {"rates": "rad/s", "lines": "line direction"}.get(signal_a["kind"], "unit normal")
    with styled():
        top, bottom = figure.subplots(2, 1, height_ratios=(2, 1))
        b_in_a = np.asarray(signal_b["vectors"]) @ R_a_b.T
        t_b_on_a = np.asarray(signal_b["t_s"]) - offset_s - t0
        for axis, colour in enumerate(AXIS_COLOURS):
            top.plot(np.asarray(signal_a["t_s"]) - t0, np.asarray(signal_a["vectors"])[:, axis], color=colour, lw=0.6)
            top.plot(t_b_on_a, b_in_a[:, axis], color=colour, lw=1.6, alpha=0.45)
        top.set_title(f"{a} (thin) and {b} (thick, {1e3 * offset_s:+.2f} ms, in {a}'s axes)")
        top.set_xlabel(f"{a}'s time since its first sample (s)")
        top.set_ylabel(unit)
        curve = record["alignment"]["curve"]
        score = np.array([np.nan if v is None else v for v in curve["score"]], dtype=float)
        bottom.plot(1e3 * np.asarray(curve["offset_s"]), score, color="#333333", lw=0.8)
        bottom.axvline(1e3 * offset_s, color="#e8590c", lw=1.0)
        bottom.set_xlabel(f"offset t_{b} - t_{a} (ms)")
        bottom.set_ylabel(curve.get("score_name", "score"), fontsize=7)
    return figure
