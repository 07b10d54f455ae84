"""The studio's transform editor: increments about fixed axes (sound at pitch -87°), nudges in the parent's and the
child's axes, re-centring, the read-only pose, undo and redo, one report per change."""

from __future__ import annotations

import numpy as np
import pytest
import viser

from backend.core.transforms import from_rvec_tvec, from_xyz_ypr, invert, rotation_angle_deg, to_xyz_ypr
from studio.transform_sliders import SLIDERS, TransformSliders, increment_between, incremented, nudged

T0 = from_xyz_ypr(np.array([0.3, -0.1, 0.5]), np.radians([20.0, -5.0, 3.0]))
T_STEEP = from_xyz_ypr(np.array([0.07, 0.63, -0.35]), np.radians([35.0, -87.0, 40.0]))
"""Near gimbal lock, as the demo's T_camera_lidar (pitch -87°)."""
ERROR_DEG = 0.19


def _error_rotation(axis: np.ndarray) -> np.ndarray:
    return from_rvec_tvec(np.radians(ERROR_DEG) * axis / np.linalg.norm(axis), np.zeros(3))


@pytest.mark.parametrize("in_child_axes", [False, True])
def test_a_small_error_at_pitch_minus_87_reads_as_itself(in_child_axes):
    axis = np.array([0.3, -0.5, 0.8])
    off = T_STEEP @ _error_rotation(axis) if in_child_axes else _error_rotation(axis) @ T_STEEP
    increment = increment_between(T_STEEP, off, in_child_axes)
    # The increment is the error itself: 0.19° about the axis it was made about, no translation.
    assert np.linalg.norm(increment[3:]) == pytest.approx(ERROR_DEG, abs=1e-9)
    np.testing.assert_allclose(increment[3:], ERROR_DEG * axis / np.linalg.norm(axis), atol=1e-9)
    np.testing.assert_allclose(increment[:3], 0.0, atol=1e-12)
    np.testing.assert_allclose(incremented(T_STEEP, increment, in_child_axes), off, atol=1e-12)


def test_yaw_pitch_roll_would_read_the_same_error_as_two_degrees():
    """Why the sliders are increments: 0.19° about the child's y at pitch -87° is 2.2° of yaw and of roll."""
    off = T_STEEP @ _error_rotation(np.array([0, 1.0, 0]))
    ypr_change = np.degrees(to_xyz_ypr(off)[1] - to_xyz_ypr(T_STEEP)[1])
    assert np.abs(ypr_change[[0, 2]]).min() > 2.0, ypr_change
    assert np.linalg.norm(increment_between(T_STEEP, off, in_child_axes=True)[3:]) == pytest.approx(ERROR_DEG)


@pytest.mark.parametrize("k", [0, 1, 2])
def test_each_rotation_slider_turns_about_one_fixed_axis_at_pitch_minus_87(k):
    increment = np.zeros(6)
    increment[3 + k] = ERROR_DEG
    for in_child_axes in (False, True):
        moved = incremented(T_STEEP, increment, in_child_axes)
        delta = invert(T_STEEP) @ moved if in_child_axes else moved @ invert(T_STEEP)
        assert rotation_angle_deg(delta[:3, :3]) == pytest.approx(ERROR_DEG, abs=1e-9)
        np.testing.assert_allclose(delta[:3, k], np.eye(3)[k], atol=1e-12)  # the axis itself stays put


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


@pytest.fixture(scope="module")
def gui(free_port):
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield server.gui
    server.stop()


def _editor(gui, T: np.ndarray) -> tuple[TransformSliders, list[np.ndarray]]:
    """An editor between cam_front and lidar_front put at ``T``, and the list of transforms it reported."""
    reports = []
    editor = TransformSliders(gui, reports.append)
    editor.frames = ("cam_front", "lidar_front")
    editor.set(T, undoable=False)
    assert len(reports) == 1 and editor.undo_button.disabled
    np.testing.assert_allclose(editor.T, T, atol=1e-12)
    assert "--frame-id cam_front --child-frame-id lidar_front" in editor.text.content
    return editor, reports


def test_editor_undo_redo_and_reports(gui):
    editor, reports = _editor(gui, T0)

    editor.axes.value = "child"
    assert len(reports) == 1  # changing the axes only re-centres the sliders
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

    before = editor.T
    editor.sliders["Δz (m)"].value = 0.2  # a drag: one report, along the child's z, undoable back
    np.testing.assert_allclose(reports[-1][:3, 3], before[:3, 3] + 0.2 * before[:3, 2], atol=1e-9)
    editor.undo()
    np.testing.assert_allclose(editor.T, before, atol=1e-9)
    assert all(slider.value == 0.0 for slider in editor.sliders.values())  # undo re-centres the sliders


def test_sliders_at_pitch_minus_87_show_the_error_and_recentre(gui):
    editor, reports = _editor(gui, T_STEEP)
    assert "| -87.000 |" in editor.pose_text.content  # the read-only pose: pitch as it is
    editor.sliders["Δ about z (°)"].value = ERROR_DEG  # the parent's z (the default axes)
    np.testing.assert_allclose(editor.T, _error_rotation(np.array([0, 0, 1.0])) @ T_STEEP, atol=1e-12)
    assert "turned **0.190°**" in editor.pose_text.content

    editor.axes.value = "child"  # re-centres on the same transform
    moved = editor.T
    assert all(editor.sliders[label].value == 0.0 for label in SLIDERS)
    np.testing.assert_allclose(moved, reports[-1], atol=1e-12)
    editor.sliders["Δ about x (°)"].value = -ERROR_DEG
    np.testing.assert_allclose(editor.T, moved @ _error_rotation(np.array([-1.0, 0, 0])), atol=1e-12)
    editor.recentre()
    np.testing.assert_allclose(editor.T, moved @ _error_rotation(np.array([-1.0, 0, 0])), atol=1e-12)
    assert editor.sliders["Δ about x (°)"].value == 0.0
