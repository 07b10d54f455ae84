"""Request models of the swept scanner's LiDAR-camera routes (pydantic, finite numbers only): the corners method and
the camera's pan axis; the services take plain values."""

from __future__ import annotations

from pydantic import Field

from backend.api.pose import Pose
from backend.store.schema import FiniteModel


class SweepCornersSolveRequest(FiniteModel):
    camera: str = Field(examples=["cam_top"])
    pan_deg: float = Field(0.0, ge=-360, le=360, description="solve from the pairs taken at this pan reading (deg)")
    image_ids: list[str] | None = Field(None, description="solve from the pairs of these image captures; default all "
                                                          "at the pan reading")
    init: Pose | None = Field(None, description="the mounting guess T_camera_lidar at pan reading 0; default the rig's "
                                                "current transform")


class PanAxisSolveRequest(FiniteModel):
    camera: str = Field(examples=["cam_top"])
    init: Pose | None = Field(None, description="the mounting guess T_camera_lidar at pan reading 0; default the rig's "
                                                "current transform")
