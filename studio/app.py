"""The studio: a viser page with the rig in 3D and the wizard panel beside it."""

from __future__ import annotations

import viser

from backend.services.jobs import JobRunner
from backend.store.session import Session, SessionStore
from studio.context import StudioContext
from studio.layers import Layers
from studio.scene import RigScene
from studio.wizard.camera_imu_step import CameraImuStep
from studio.wizard.depth_network_step import DepthNetworkStep
from studio.wizard.intrinsics_step import IntrinsicsStep
from studio.wizard.lidar_camera_step import LidarCameraStep
from studio.wizard.lidar_step import LidarStep
from studio.wizard.multicam_step import MulticamStep
from studio.wizard.rig_step import RigStep
from studio.wizard.sensors_step import SensorsStep
from studio.wizard.session_step import SessionStep
from studio.wizard.sweep_step import SweepStep
from studio.wizard.time_offset_step import TimeOffsetStep

PANEL_WIDTH_PX = 560
"""The control panel's width (px); the page's user can drag its edge."""


class StudioApp:
    """Builds the wizard on a viser server and opens an initial session."""

    def __init__(self, server: viser.ViserServer, store: SessionStore, jobs: JobRunner,
                 session: Session | None = None, api_url: str = ""):
        server.gui.configure_theme(control_width="large", dark_mode=False, show_logo=False)
        # Docked beside the 3D view, not floating over it, and wide enough for a result's tables to read unwrapped.
        server.gui.main_panel.dock_right()
        server.gui.main_panel.set_width(PANEL_WIDTH_PX)
        server.gui.add_markdown("## Calibration Studio\nFrom raw sensors to trusted transforms, step by step.")
        self.ctx = StudioContext(server, store, jobs, RigScene(server), api_url=api_url)
        self.layers = Layers(self.ctx)
        self.session_step = SessionStep(self.ctx)
        self.sensors_step = SensorsStep(self.ctx)
        self.intrinsics_step = IntrinsicsStep(self.ctx)
        self.lidar_step = LidarStep(self.ctx)
        self.sweep_step = SweepStep(self.ctx)
        self.lidar_camera_step = LidarCameraStep(self.ctx)
        self.multicam_step = MulticamStep(self.ctx)
        self.rig_step = RigStep(self.ctx)
        self.depth_network_step = DepthNetworkStep(self.ctx)
        self.camera_imu_step = CameraImuStep(self.ctx)
        self.time_offset_step = TimeOffsetStep(self.ctx)
        if session is not None:
            self.ctx.open_session(session)

    def attach_node_network(self, network) -> None:
        """Let the depth-network step use the server's open :class:`~backend.devices.node_network.NodeNetwork`
        (the demo cell's agents connect to it) instead of listening on its own."""
        self.depth_network_step.attach(network)

    def close(self) -> None:
        """Stop what the open session streams (every step's closing hook)."""
        self.ctx.close_session()
