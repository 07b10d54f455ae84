"""The studio's manual extrinsic editor of one transform ``T_parent_child``: increments about fixed axes.

Six sliders move the transform *from where they were centred* along and about the x, y, z axes of
the parent or the child (translation in m, rotation in degrees as a rotation vector), so no
reading degenerates anywhere, unlike yaw/pitch/roll sliders, which near pitch ±90° turn yaw and
roll into the same axis (the demo's ``T_camera_lidar`` sits at pitch -87°, where a 0.19° error
showed up as 2.2° of yaw and roll). The sliders are re-centred on zero, keeping the transform,
whenever it is set (a solve, *Reset*, a nudge, undo, redo), when the axes change and with
*Re-centre*; never while one is dragged. The full x, y, z (m), ROS yaw, pitch, roll (°) are shown
read-only beside them, with how far the transform is from where the editor was put (an angle and
a distance, which mean the same at any pose), and the ``static_transform_publisher`` line.

The nudge buttons step one axis by a coarse or fine amount (also from the keyboard, once
:meth:`TransformSliders.bind_keys` gave it the keys); undo and redo walk back through the
transforms the editor held. ``on_change(T)`` runs after every change, whatever made it.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import viser

from backend.core.transforms import from_rvec_tvec, invert, rotation_angle_deg, to_rvec_tvec, to_xyz_ypr
from backend.exports.rig_transforms import static_transform_publisher

AXES = ("x", "y", "z", "yaw", "pitch", "roll")
"""The nudges' axes: along x, y, z and about z (yaw), y (pitch) and x (roll) of the parent or the child."""
SLIDERS = ("Δx (m)", "Δy (m)", "Δz (m)", "Δ about x (°)", "Δ about y (°)", "Δ about z (°)")
"""The increment sliders: along x, y, z (m), then the rotation vector about x, y, z (deg)."""
ROTATION_REACH_DEG = 30.0
"""The rotation sliders reach this far either way from where they were centred."""
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


def incremented(T: np.ndarray, increment: np.ndarray, in_child_axes: bool) -> np.ndarray:
    """``T`` moved by ``increment`` = (dx, dy, dz m, rx, ry, rz deg): along, and by the rotation vector about, the
    parent's axes (the increment applied before ``T``, ``D @ T``) or the child's (after it, ``T @ D``)."""
    increment = np.asarray(increment, dtype=float)
    delta = from_rvec_tvec(np.radians(increment[3:]), increment[:3])
    return T @ delta if in_child_axes else delta @ T


def increment_between(T_from: np.ndarray, T_to: np.ndarray, in_child_axes: bool) -> np.ndarray:
    """The increment (dx, dy, dz m, rx, ry, rz deg) that :func:`incremented` needs to take ``T_from`` to ``T_to``."""
    delta = invert(T_from) @ T_to if in_child_axes else T_to @ invert(T_from)
    rvec, tvec = to_rvec_tvec(delta)
    return np.concatenate([tvec, np.degrees(rvec)])


def nudged(T: np.ndarray, axis: str, amount: float, in_child_axes: bool) -> np.ndarray:
    """``T`` moved by ``amount`` (m, or deg for yaw/pitch/roll) along or about ``axis`` of the parent or the child."""
    increment = np.zeros(6)
    increment[3 + ROTATION_AXIS[axis] if axis in ROTATION_AXIS else AXES.index(axis)] = amount
    return incremented(T, increment, in_child_axes)


def pose_markdown(T: np.ndarray, reference: np.ndarray | None) -> str:
    """A read-only table of ``T``'s x, y, z (m) and ROS yaw, pitch, roll (°), and how far it is from ``reference``."""
    xyz, ypr = to_xyz_ypr(T)
    values = " | ".join(f"{v:.4f}" for v in xyz) + " | " + " | ".join(f"{v:.3f}" for v in np.degrees(ypr))
    table = ("| x (m) | y (m) | z (m) | yaw (°) | pitch (°) | roll (°) |\n|---|---|---|---|---|---|\n"
             f"| {values} |")
    if reference is None:
        return table
    delta = invert(reference) @ T
    return (table + f"\n\nFrom where it was put: turned **{rotation_angle_deg(delta[:3, :3]):.3f}°**, moved "
            f"**{np.linalg.norm(T[:3, 3] - reference[:3, 3]) * 1000:.1f} mm**.")


class TransformSliders:
    """The editor; build it inside the GUI folder it belongs to.

    ``max_translation_m`` is how far the translation sliders reach either way from where they were centred.
    """

    def __init__(self, gui: viser.GuiApi, on_change: Callable[[np.ndarray], None], *, max_translation_m: float = 1.0):
        self.on_change = on_change
        self.frames: tuple[str, str] | None = None
        """(parent, child) for the ``static_transform_publisher`` line, or None."""
        self._undo: list[np.ndarray] = []
        self._redo: list[np.ndarray] = []
        self._last_push = 0.0
        self._quiet = False
        self._centre = np.eye(4)
        """The transform the sliders are centred on (all at zero)."""
        self._reference: np.ndarray | None = None
        """Where the editor was put (:meth:`set` with ``undoable=False``), for the read-only distance."""
        self.axes = gui.add_dropdown("In the axes of", options=["parent", "child"],
                                     hint="the sliders and nudges move along and turn about these axes")
        self.sliders = {
            label: gui.add_slider(label, min=-max_translation_m, max=max_translation_m, step=0.001, initial_value=0.0)
            for label in SLIDERS[:3]
        } | {
            label: gui.add_slider(label, min=-ROTATION_REACH_DEG, max=ROTATION_REACH_DEG, step=0.01, initial_value=0.0)
            for label in SLIDERS[3:]
        }
        self.recentre_button = gui.add_button("Re-centre the sliders", hint="keep the transform, put the sliders at 0")
        self.pose_text = gui.add_markdown("")
        self.text = gui.add_markdown("")
        with gui.add_folder("Nudge", expand_by_default=False):
            self.step = gui.add_dropdown("Step", options=list(STEPS))
            self.nudges = {axis: gui.add_button_group(axis, ["−", "+"]) for axis in AXES}
            self.undo_button = gui.add_button("Undo", disabled=True)
            self.redo_button = gui.add_button("Redo", disabled=True)
        self._held = self.T
        for slider in self.sliders.values():
            slider.on_update(lambda _: self._changed())
        self.axes.on_update(lambda _: self.recentre())
        self.recentre_button.on_click(lambda _: self.recentre())
        for axis, group in self.nudges.items():
            group.on_click(lambda event, axis=axis: self.nudge(axis, 1 if event.target.value == "+" else -1))
        self.undo_button.on_click(lambda _: self.undo())
        self.redo_button.on_click(lambda _: self.redo())

    @property
    def in_child_axes(self) -> bool:
        return self.axes.value == "child"

    @property
    def increment(self) -> np.ndarray:
        """The sliders' (dx, dy, dz m, rx, ry, rz deg) from the transform they were centred on."""
        return np.array([self.sliders[label].value for label in SLIDERS], dtype=float)

    @property
    def T(self) -> np.ndarray:
        """``T_parent_child``: the sliders' increment applied to the transform they were centred on."""
        return incremented(self._centre, self.increment, self.in_child_axes)

    def set(self, T: np.ndarray, *, undoable: bool = True) -> None:
        """Put ``T`` in the editor, sliders centred (one change, one undo step unless ``undoable`` is False, which
        also makes ``T`` where the read-only distance is measured from)."""
        if not undoable:
            self._undo.clear()
            self._redo.clear()
            self._reference = np.array(T, dtype=float)
        self._put(T)
        self._last_push = 0.0  # its own undo step, and the next drag starts another
        self._changed(undoable=undoable)
        self._last_push = 0.0

    def recentre(self) -> None:
        """Put the sliders back at zero, keeping the transform (nothing changes on screen but the sliders).

        From the transform last reported, which the sliders read in the axes they were moved in (when the axes
        change, this runs once the dropdown already shows the new ones)."""
        self._put(self._held)
        self._report(notify=False)

    def _put(self, T: np.ndarray) -> None:
        """Centre the sliders on ``T`` without reporting each slider (each fires its callback)."""
        self._centre = np.array(T, dtype=float)
        self._quiet = True
        try:
            for slider in self.sliders.values():
                slider.value = 0.0
        finally:
            self._quiet = False

    def nudge(self, axis: str, direction: int, step: str | None = None) -> None:
        """One step (of the chosen size, or ``step``, a :data:`STEPS` key; in the chosen axes) along or about
        ``axis``; ``direction`` is +1 or -1."""
        metres, degrees = STEPS[step or self.step.value]
        amount = (degrees if axis in ROTATION_AXIS else metres) * direction
        self.set(nudged(self.T, axis, amount, self.in_child_axes))

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

    def _report(self, notify: bool = True) -> None:
        T = self.T
        self.pose_text.content = pose_markdown(T, self._reference)
        if self.frames is not None:
            self.text.content = f"```\n{static_transform_publisher(*self.frames, T)}\n```"
        self.undo_button.disabled, self.redo_button.disabled = not self._undo, not self._redo
        if notify:
            self.on_change(T)
