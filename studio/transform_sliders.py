"""Six sliders that *are* one transform ``T_parent_child``, as the studio's manual extrinsic editor.

x, y, z (m) and ROS yaw, pitch, roll (degrees), like ``static_transform_publisher``, whose
line follows them. Values can be dragged or typed; the nudge buttons step one axis by a
coarse or fine amount in the parent's or the child's axes (also from the keyboard, once
:meth:`TransformSliders.bind_keys` gave it the keys); undo and redo walk back through the
transforms the editor held. ``on_change(T)`` runs after every change, whatever made it
(a slider, a nudge, undo, or :meth:`set` from a solve).
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import viser

from backend.core.transforms import from_xyz_ypr, to_xyz_ypr
from backend.exports.rig_transforms import static_transform_publisher

AXES = ("x", "y", "z", "yaw", "pitch", "roll")
STEPS = {"coarse: 1 cm, 0.5°": (0.01, 0.5), "fine: 1 mm, 0.05°": (0.001, 0.05)}
"""Nudge steps: (translation m, rotation deg)."""
ROTATION_AXIS = {"roll": 0, "pitch": 1, "yaw": 2}
UNDO_MERGE_S = 0.6
"""Changes closer together than this (a slider being dragged) make one undo step."""
UNDO_DEPTH = 200
NUDGE_KEYS = {"x": ("S", "W"), "y": ("D", "A"), "z": ("F", "R"), "yaw": ("L", "J"), "pitch": ("K", "I"),
              "roll": ("O", "U")}
"""(minus, plus) keys of each axis: W/S forward and back along x, A/D along y, R/F up and down along z; I/K, J/L
and U/O turn about pitch, yaw and roll, like a game's movement keys and the vi-like cluster beside them."""


def nudged(T: np.ndarray, axis: str, amount: float, in_child_axes: bool) -> np.ndarray:
    """``T`` moved by ``amount`` (m, or deg for yaw/pitch/roll) along or about ``axis`` of the parent or the child."""
    delta = np.eye(4)
    if axis in ROTATION_AXIS:
        rotation = np.zeros(3)
        rotation[2 - ROTATION_AXIS[axis]] = np.radians(amount)  # from_xyz_ypr takes (yaw, pitch, roll)
        delta = from_xyz_ypr(np.zeros(3), rotation)
    else:
        delta[AXES.index(axis), 3] = amount
    return T @ delta if in_child_axes else delta @ T


class TransformSliders:
    """The editor; build it inside the GUI folder it belongs to."""

    def __init__(self, gui: viser.GuiApi, on_change: Callable[[np.ndarray], None], *, max_translation_m: float = 5.0):
        self.on_change = on_change
        self.frames: tuple[str, str] | None = None
        """(parent, child) for the ``static_transform_publisher`` line, or None."""
        self._undo: list[np.ndarray] = []
        self._redo: list[np.ndarray] = []
        self._last_push = 0.0
        self._quiet = False
        self.sliders = {
            axis: gui.add_slider(f"{axis} (m)", min=-max_translation_m, max=max_translation_m, step=0.001,
                                 initial_value=0.0) for axis in AXES[:3]
        } | {
            axis: gui.add_slider(f"{axis} (°)", min=-180.0, max=180.0, step=0.05, initial_value=0.0)
            for axis in AXES[3:]
        }
        self.text = gui.add_markdown("")
        with gui.add_folder("Nudge", expand_by_default=False):
            self.step = gui.add_dropdown("Step", options=list(STEPS))
            self.axes = gui.add_dropdown("In the axes of", options=["parent", "child"])
            self.nudges = {axis: gui.add_button_group(axis, ["−", "+"]) for axis in AXES}
            self.undo_button = gui.add_button("Undo", disabled=True)
            self.redo_button = gui.add_button("Redo", disabled=True)
        self._held = self.T
        for slider in self.sliders.values():
            slider.on_update(lambda _: self._changed())
        for axis, group in self.nudges.items():
            group.on_click(lambda event, axis=axis: self.nudge(axis, 1 if event.target.value == "+" else -1))
        self.undo_button.on_click(lambda _: self.undo())
        self.redo_button.on_click(lambda _: self.redo())

    @property
    def T(self) -> np.ndarray:
        """``T_parent_child`` from the six sliders (m, degrees)."""
        xyz = [self.sliders[a].value for a in AXES[:3]]
        ypr = [self.sliders[a].value for a in AXES[3:]]
        return from_xyz_ypr(np.array(xyz, float), np.radians(ypr))

    def set(self, T: np.ndarray, *, undoable: bool = True) -> None:
        """Put ``T`` on the sliders (one change, one undo step unless ``undoable`` is False)."""
        if not undoable:
            self._undo.clear()
            self._redo.clear()
        self._put(T)
        self._last_push = 0.0  # its own undo step, and the next drag starts another
        self._changed(undoable=undoable)
        self._last_push = 0.0

    def _put(self, T: np.ndarray) -> None:
        """Move the sliders to ``T`` without reporting each slider (each fires its callback)."""
        xyz, ypr = to_xyz_ypr(np.asarray(T, dtype=float))
        self._quiet = True
        try:
            for axis, value in zip(AXES, [*xyz, *np.degrees(ypr)], strict=True):
                self.sliders[axis].value = float(value)
        finally:
            self._quiet = False

    def nudge(self, axis: str, direction: int, step: str | None = None) -> None:
        """One step (of the chosen size, or ``step``, a :data:`STEPS` key; in the chosen axes) along or about
        ``axis``; ``direction`` is +1 or -1."""
        metres, degrees = STEPS[step or self.step.value]
        amount = (degrees if axis in ROTATION_AXIS else metres) * direction
        self.set(nudged(self.T, axis, amount, self.axes.value == "child"))

    def bind_keys(self, gui: viser.GuiApi, name: str) -> None:
        """Nudge from the keyboard (:data:`NUDGE_KEYS`, Shift for the fine step) and undo/redo with Z/Y, as
        commands of the page's command palette named after the editor (``name``)."""
        for axis, keys in NUDGE_KEYS.items():
            for direction, key in zip((-1, 1), keys, strict=True):
                for modifier, step in ((None, 0), ("shift", 1)):
                    command = gui.add_command(f"{name}: {axis} {'−+'[direction > 0]} ({list(STEPS)[step]})",
                                              hotkey=key, modifier=modifier)
                    command.on_trigger(lambda _, a=axis, d=direction, s=step: self.nudge(a, d, list(STEPS)[s]))
        gui.add_command(f"{name}: undo", hotkey="Z").on_trigger(lambda _: self.undo())
        gui.add_command(f"{name}: redo", hotkey="Y").on_trigger(lambda _: self.redo())

    def undo(self) -> None:
        self._walk(self._undo, self._redo)

    def redo(self) -> None:
        self._walk(self._redo, self._undo)

    def _walk(self, back: list[np.ndarray], forth: list[np.ndarray]) -> None:
        if not back:
            return
        forth.append(self.T)
        self._put(back.pop())
        self._held = self.T
        self._report()

    def _changed(self, undoable: bool = True) -> None:
        if self._quiet:
            return
        now = time.monotonic()
        if undoable and now - self._last_push > UNDO_MERGE_S:
            self._undo.append(self._held)
            del self._undo[:-UNDO_DEPTH]
            self._redo.clear()
        self._last_push = now
        self._held = self.T
        self._report()

    def _report(self) -> None:
        T = self.T
        if self.frames is not None:
            self.text.content = f"```\n{static_transform_publisher(*self.frames, T)}\n```"
        self.undo_button.disabled, self.redo_button.disabled = not self._undo, not self._redo
        self.on_change(T)
