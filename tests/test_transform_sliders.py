"""The studio's transform editor: nudges in the parent's and the child's axes, undo and redo, one report per change."""

from __future__ import annotations

import numpy as np
import pytest
import viser

from backend.core.transforms import from_xyz_ypr
from studio.transform_sliders import TransformSliders, nudged

T0 = from_xyz_ypr(np.array([0.3, -0.1, 0.5]), np.radians([20.0, -5.0, 3.0]))


@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_translation_nudges_move_along_the_parent_or_the_child_axis(axis):
    k = "xyz".index(axis)
    parent = nudged(T0, axis, 0.01, in_child_axes=False)
    child = nudged(T0, axis, 0.01, in_child_axes=True)
    np.testing.assert_allclose(parent[:3, 3] - T0[:3, 3], 0.01 * np.eye(3)[k], atol=1e-12)
    np.testing.assert_allclose(child[:3, 3] - T0[:3, 3], 0.01 * T0[:3, k], atol=1e-12)
    np.testing.assert_allclose(parent[:3, :3], T0[:3, :3]) and np.testing.assert_allclose(child[:3, :3], T0[:3, :3])


@pytest.mark.parametrize(("axis", "k"), [("roll", 0), ("pitch", 1), ("yaw", 2)])
def test_rotation_nudges_turn_about_the_parent_or_the_child_axis(axis, k):
    ypr = np.zeros(3)
    ypr[2 - k] = np.radians(0.5)
    R = from_xyz_ypr(np.zeros(3), ypr)
    np.testing.assert_allclose(nudged(T0, axis, 0.5, in_child_axes=False), R @ T0, atol=1e-12)
    np.testing.assert_allclose(nudged(T0, axis, 0.5, in_child_axes=True), T0 @ R, atol=1e-12)
    turned = nudged(T0, axis, 0.5, in_child_axes=True)[:3, :3]
    np.testing.assert_allclose(turned[:, k], T0[:3, k], atol=1e-12)  # the child's own axis stays put


def test_editor_undo_redo_and_reports(free_port):
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        reports = []
        editor = TransformSliders(server.gui, reports.append)
        editor.frames = ("cam_front", "lidar_front")
        editor.set(T0, undoable=False)
        assert len(reports) == 1 and editor.undo_button.disabled
        np.testing.assert_allclose(editor.T, T0, atol=1e-9)
        assert "--frame-id cam_front --child-frame-id lidar_front" in editor.text.content

        editor.axes.value = "child"
        editor.step.value = "fine: 1 mm, 0.05°"
        editor.nudge("x", +1)
        np.testing.assert_allclose(editor.T, nudged(T0, "x", 0.001, True), atol=1e-9)
        editor.nudge("yaw", -1)
        np.testing.assert_allclose(editor.T, nudged(nudged(T0, "x", 0.001, True), "yaw", -0.05, True), atol=1e-9)
        assert len(reports) == 3 and not editor.undo_button.disabled

        editor.undo()  # what the Undo button runs
        np.testing.assert_allclose(editor.T, nudged(T0, "x", 0.001, True), atol=1e-9)
        editor.undo()
        np.testing.assert_allclose(editor.T, T0, atol=1e-9)
        assert editor.undo_button.disabled and not editor.redo_button.disabled
        editor.redo()
        np.testing.assert_allclose(editor.T, nudged(T0, "x", 0.001, True), atol=1e-9)

        editor.sliders["z"].value = 0.9  # a drag: one report, undoable back to where it was
        assert reports[-1][2, 3] == pytest.approx(0.9)
        editor.undo()
        np.testing.assert_allclose(editor.T, nudged(T0, "x", 0.001, True), atol=1e-9)
    finally:
        server.stop()
