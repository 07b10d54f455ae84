"""Request models of the depth-network routes (pydantic, finite numbers only); the services take plain values."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field

from backend.api.pose import Pose, PoseRow, deprecated, deprecated_row
from backend.core.rig import DEFAULT_MOUNT_SIGMA
from backend.store.schema import NAME_PATTERN, FiniteModel

"""X, Y, Z (m), RotZ, RotY, RotX (deg): the paper's pose row (``backend.core.depth.pose_from_row``)."""


class TableBody(FiniteModel):
    name: str = Field(pattern=NAME_PATTERN)
    height_m: float = Field(gt=0, lt=10, description="top above the floor, m")
    size_m: tuple[Annotated[float, Field(gt=0)], Annotated[float, Field(gt=0)]] = (1.6, 0.8)


class FloorLineBody(FiniteModel):
    name: str = Field(pattern=NAME_PATTERN)
    axis: Literal["x", "y"]
    value_m: float
    span_m: tuple[float, float] = Field(description="extent along the other axis, m")
    width_m: float = Field(0.05, gt=0)


class CrossBody(FiniteModel):
    name: str = Field(pattern=NAME_PATTERN)
    position_m: tuple[float, float, float]
    size_m: float = Field(0.3, gt=0)
    surveyed: bool = False


class DistanceBody(FiniteModel):
    a: str = Field(pattern=NAME_PATTERN)
    b: str = Field(pattern=NAME_PATTERN)
    measured_m: float = Field(gt=0)
    what: str = Field("", max_length=200)


class LayoutBody(FiniteModel):
    """A cell's known geometry (``backend.core.depth_cell.CellLayout``; m, world frame)."""

    size_m: tuple[Annotated[float, Field(gt=0)], Annotated[float, Field(gt=0)], Annotated[float, Field(gt=0)]] = (
        10.0, 15.0, 5.0)
    tables: list[TableBody] = Field(default_factory=list, max_length=100)
    lines: list[FloorLineBody] = Field(default_factory=list, max_length=1000)
    crosses: list[CrossBody] = Field(default_factory=list, max_length=1000)
    distances: list[DistanceBody] = Field(default_factory=list, max_length=1000)


class DepthNodeCreate(FiniteModel):
    name: str = Field(pattern=NAME_PATTERN, examples=["sn1"])
    pose: Pose | None = Field(None, description="T_world_node as measured (laser meter, tape); null: unknown "
                              "(identity, no mounting prior)",
                              examples=[{"xyz_m": [9.95, 0.3, 4.9], "ypr_deg": [45, 0, -140]}])
    pose_row: PoseRow | None = deprecated("pose")
    fold_pose = deprecated_row("pose", "pose_row")
    mount_sigma: tuple[Annotated[float, Field(gt=0)], Annotated[float, Field(gt=0)]] | None = Field(
        DEFAULT_MOUNT_SIGMA, description="1-sigma of the measured pose (m, deg), a weak prior edge of the rig graph")
    device: dict[str, Any] = Field(default_factory=dict, description="the node agent's device spec, if any")


class LiveCapture(FiniteModel):
    arrangement: Literal["behind", "beside", "free"] = "free"
    tables: list[str] = Field(default_factory=list, description="names of the layout's tables in view")
    timeout_s: float = Field(10.0, gt=0, le=120)


class NodeSolveRequest(FiniteModel):
    init: Pose | None = Field(None, description="initial T_world_node; null: the rig's current pose")
    init_pose_row: PoseRow | None = deprecated("init")
    fold_init = deprecated_row("init", "init_pose_row")


class NetworkSolveRequest(FiniteModel):
    nodes: list[str] | None = Field(None, description="nodes to solve; null: every node with captures")
    icp: bool = Field(False, description="add pairwise ICP between overlapping nodes as extra edges")
    confirm: bool = Field(False, description="accept results judged 'check' too")


class DepthAccept(FiniteModel):
    result_id: str = Field(pattern=NAME_PATTERN)
    confirm: bool = False


class GuidedStart(FiniteModel):
    pose: Pose = Field(description="T_world_node")
    pose_row: PoseRow | None = deprecated("pose")
    fold_pose = deprecated_row("pose", "pose_row")


class GuidedStep(FiniteModel):
    step: str = Field(max_length=40, examples=["tables_behind"], description="one of GUIDED_STEPS after 'initial'")


class GuidedFinish(FiniteModel):
    accept: bool = False
    confirm: bool = False


class PointView(FiniteModel):
    node: str = Field(pattern=NAME_PATTERN)
    point_node_m: tuple[float, float, float]
    weight: float = Field(1.0, gt=0)


class PickedPoint(FiniteModel):
    name: str = Field(min_length=1, max_length=64)
    point_m: tuple[float, float, float] = Field(description="world frame, m")
    views: list[PointView] = Field(default_factory=list, description="as the pick or targets routes give them")


class VerificationCreate(FiniteModel):
    a: PickedPoint
    b: PickedPoint
    measured_m: float = Field(gt=0, lt=1000, description="laser-measured distance, m")


class PickRequest(FiniteModel):
    origin_m: tuple[float, float, float] = Field(description="ray origin, world frame, m")
    direction: tuple[float, float, float] = Field(description="ray direction, world frame")
