"""Camera-IMU plots: the motion's excitation per axis against what the fit needs, and the IMU's measured signals
with the fitted trajectory's (the two should lie on each other; where they part, the fit does not explain the
motion)."""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.figure import Figure

from backend.plots.render import empty_note, new_figure, styled


def excitation_bars(excitation: dict[str, Any] | None) -> Figure:
    """Bars of the RMS angular rate about each axis and the specific force's spread along each, with the least each
    needs (dashed); an axis below it is drawn red."""
    figure = new_figure(4.8, 1.7)
    if excitation is None:
        return empty_note(figure, "no recording yet")
    with styled():
        for index, (key, minimum, title, unit) in enumerate((
                ("rate_rms_rad_s", "min_rate_rms_rad_s", "rotation: RMS rate", "rad/s"),
                ("accel_std_m_s2", "min_accel_std_m_s2", "translation: force spread", "m/s²"))):
            ax = figure.add_subplot(1, 2, index + 1)
            values = np.asarray(excitation[key])
            colours = ["#2f9e44" if v >= excitation[minimum] else "#e03131" for v in values]
            ax.bar(["x", "y", "z"], values, color=colours)
            ax.axhline(excitation[minimum], color="#333333", ls="--", lw=0.9)
            ax.set_title(title, fontsize=8)
            ax.set_ylabel(unit)
    return figure


def fitted_signals(signals: dict[str, Any] | None) -> Figure:
    """The gyro's and the accelerometer's samples (thin) and the fitted trajectory's (thick), per axis, over time."""
    figure = new_figure(4.8, 3.2)
    if not signals:
        return empty_note(figure, "no fit yet")
    t = np.asarray(signals["t_s"])
    with styled():
        for row, (measured, fitted, unit) in enumerate((("gyro_rad_s", "gyro_fit_rad_s", "rad/s"),
                                                       ("accel_m_s2", "accel_fit_m_s2", "m/s²"))):
            ax = figure.add_subplot(2, 1, row + 1)
            for axis, colour in zip(range(3), ("#e03131", "#2f9e44", "#1971c2"), strict=True):
                ax.plot(t, np.asarray(signals[measured])[:, axis], color=colour, lw=0.4, alpha=0.5)
                ax.plot(t, np.asarray(signals[fitted])[:, axis], color=colour, lw=0.9, label="xyz"[axis])
            ax.set_ylabel(f"{measured.split('_')[0]} ({unit})")
            ax.legend(fontsize=6, ncols=3, loc="upper right")
        ax.set_xlabel("time on the IMU's clock (s)")
    return figure
