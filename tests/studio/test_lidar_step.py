"""The LiDAR step in process (no browser): its clouds in the step's layer group, posed where the rig has each
sensor and following it when an accept re-fits the rig; the result card and the scenes beside it."""

from __future__ import annotations

import numpy as np
import pytest
import viser

from backend.calib._session import store_cloud
from backend.calib.lidar_lidar import service
from backend.calib.lidar_lidar.gicp import LidarLidarSettings
from backend.core.transforms import from_xyz_ypr
from backend.devices.base import create_device
from backend.services.demo import ROBOT_PLACE_NAMES, move_simulated_robot, simulated_place
from backend.services.jobs import JobRunner
from backend.sim.demo_rig import demo_rig
from backend.store.session import SessionStore
from studio.context import StudioContext
from studio.marks import mark
from studio.scene import RigScene
from studio.wizard.lidar_step import LidarStep

SOURCE, TARGET = "lidar_front", "lidar_top"


@pytest.fixture
def step(tmp_path, free_port):
    """The step on the demo rig with lidar_front's mounting (and its guess) 6 cm / 3 deg off, one cloud per LiDAR."""
    rig = demo_rig()
    source = rig.get(SOURCE)
    source.T_parent_child = source.T_mount = source.T_parent_child @ from_xyz_ypr(
        np.array([0.06, -0.04, 0.03]), np.radians([3.0, 0.0, 0.0]))
    session = SessionStore(tmp_path).create("lidars", rig=rig)
    for sensor in (SOURCE, TARGET):
        with create_device(demo_rig().get(sensor).device) as device:
            store_cloud(session, sensor, device.read(), device=device.describe())
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    jobs = JobRunner()
    ctx = StudioContext(server, SessionStore(tmp_path), jobs, RigScene(server))
    lidar_step = LidarStep(ctx)
    ctx.open_session(session)
    lidar_step.target.value, lidar_step.source.value = TARGET, SOURCE
    try:
        yield lidar_step
    finally:
        ctx.close_session()
        jobs.shutdown()
        server.stop()


def _position(step: LidarStep, sensor: str) -> np.ndarray:
    return np.asarray(step.ctx.server.scene._handle_from_node_name[f"/steps/lidar/{sensor}"].position)


@pytest.mark.slow
def test_clouds_in_the_step_group_follow_the_rig_and_the_card_shows_the_result(step):
    session, nodes = step.ctx.session, step.ctx.server.scene._handle_from_node_name
    assert {"/steps/lidar", "/steps/lidar/lidar_top/l2l/target", "/steps/lidar/lidar_top/l2l/source"} <= set(nodes)
    assert not any(name.startswith("/rig/") and "/l2l" in name for name in nodes)
    before = session.rig.T_root_frame(TARGET)[:3, 3]
    np.testing.assert_allclose(_position(step, TARGET), before)
    assert step.card.text.content == "No LiDAR-to-LiDAR result yet."

    result_id, result = service.solve_session(session, SOURCE, TARGET, settings=LidarLidarSettings(spread=False))
    step._show_history(result_id, move_sliders=True)
    np.testing.assert_allclose(step.slider_T(), result.T_parent_child, atol=1e-9)
    card = step.card.text.content
    assert f"**{result_id}** (not accepted) · lidar_lidar · gicp" in card and "lidar_top → lidar_front" in card
    assert "fitness" in card and "c2c mean" in card
    assert "scene 1" in step.scenes_text.content and "One scene" in step.scenes_text.content

    step.card.accept()  # not previewed yet: nothing happens
    assert session.accepted(f"{SOURCE}/T_{TARGET}_{SOURCE}") is None and not step.card.apply_button.visible
    step.card.preview()  # *Accept*: the preview, nothing written
    assert "would" in step.card.preview_text.content and session.accepted(f"{SOURCE}/T_{TARGET}_{SOURCE}") is None
    assert step.card.accept_button.label == "Accept" and step.card.apply_button.visible  # labels stay as they are
    step.card.confirm.checkbox.value = True  # one scene: a 'check'
    step.card.accept()  # *Confirm accept*
    assert session.accepted(f"{SOURCE}/T_{TARGET}_{SOURCE}") == result_id
    assert f"**{result_id}** ({mark('accepted', 'good')})" in step.card.text.content
    # the measured edge against two 5 cm mounting guesses moved lidar_top too: its clouds' node followed it
    after = session.rig.T_root_frame(TARGET)[:3, 3]
    assert np.linalg.norm(after - before) > 0.005
    np.testing.assert_allclose(_position(step, TARGET), after, atol=1e-9)


def test_robot_stands_at_drives_the_simulated_robot_and_only_once(step):
    session = step.ctx.session
    assert step.place.visible and step.place.value == ROBOT_PLACE_NAMES[0]
    revision = session.revision
    step.place.value = ROBOT_PLACE_NAMES[2]  # as the page's dropdown sets it
    assert simulated_place(session) == 2 and session.revision == revision + 1
    assert session.rig.get(TARGET).device["place"] == session.rig.get("cam_front").device["place"] == 2
    step.ctx.follow()  # the studio follows its session's change: the control keeps the place, nothing moves again
    assert step.place.value == ROBOT_PLACE_NAMES[2] and session.revision == revision + 1
    move_simulated_robot(session, 1)  # driven elsewhere (another page, the API's device edit)
    step.ctx.follow()
    assert step.place.value == ROBOT_PLACE_NAMES[1] and session.revision == revision + 2
