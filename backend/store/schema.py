"""On-disk schema of a session, validated with pydantic on every load.

``session.json`` holds the rig and which result is accepted for what; captures and
results live in their own write-once files beside it. ``SCHEMA_VERSION`` is bumped
whenever the layout changes; loading a different version says so.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator, model_validator

from backend.core.finite import first_non_finite
from backend.core.rig import DEFAULT_MOUNT_SIGMA

SCHEMA_VERSION = 1
NAME_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_\-]{0,63}$"
FILE_NAME_PATTERN = r"[A-Za-z0-9][A-Za-z0-9_\-]{0,63}\.[a-z0-9]{1,5}"
"""A file kept in a session folder: a plain name and one extension, never a path."""
REMOVAL_ID_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_\-]{0,63}-[0-9]{1,6}$"
"""A sensor removal's id: the sensor's name, ``-`` and its removal's number (``lidar_top-1``)."""


class FiniteModel(BaseModel):
    """A model whose float fields refuse NaN and infinity (also as the strings ``"nan"``, ``"inf"``)."""

    model_config = ConfigDict(allow_inf_nan=False)


def _finite_tree(value: dict[str, Any]) -> dict[str, Any]:
    found = first_non_finite(value)
    if found is not None:
        raise ValueError(f"'{found[0]}' is {found[1]!r}; expected a finite number")
    return value


FiniteTree = Annotated[dict[str, Any], AfterValidator(_finite_tree)]
"""Free-form settings (a device's options) in which every number must be finite."""


class SplineModel(FiniteModel):
    """The splined model's knots and field of view (:class:`~backend.core.splined.SplineGrid`)."""

    order: Literal[3] = 3
    nx: int = Field(ge=4, description="knots across")
    ny: int = Field(ge=4, description="knots down")
    fov_x_deg: float = Field(gt=0, lt=360, description="the field of view across the knots span (deg)")
    mrcal: str | None = Field(None, description="mrcal's name of the model")


class CameraModel(FiniteModel):
    model: Literal["pinhole-radtan", "fisheye-equidistant", "photogrammetric", "splined-stereographic"]
    width: int = Field(gt=0, description="image width (px)")
    height: int = Field(gt=0, description="image height (px)")
    K: list[list[float]] = Field(description="3x3 camera matrix (px), row-major")
    dist: list[float] = Field(description="distortion coefficients in the model's OpenCV order (the splined model: "
                                          "its control points, mrcal's order)")
    spline: SplineModel | None = Field(None, description="the splined model's knots (that model only)")

    @field_validator("K")
    @classmethod
    def _three_by_three(cls, K: list[list[float]]) -> list[list[float]]:
        if len(K) != 3 or any(len(row) != 3 for row in K):
            raise ValueError("K must be 3x3")
        return K

    @model_validator(mode="after")
    def _spline_for_the_splined_model(self) -> CameraModel:
        if (self.model == "splined-stereographic") != (self.spline is not None):
            raise ValueError("the splined-stereographic model, and only it, has a spline")
        if self.spline is not None and len(self.dist) != 2 * self.spline.nx * self.spline.ny:
            raise ValueError(f"dist holds {len(self.dist)} control points; the spline's {self.spline.nx}x"
                             f"{self.spline.ny} knots need {2 * self.spline.nx * self.spline.ny}")
        return self


class FrameModel(FiniteModel):
    name: str = Field(pattern=NAME_PATTERN)
    parent: str | None
    kind: Literal["frame", "camera", "lidar3d", "lidar2d", "depth", "imu"] = "frame"
    T_parent_child: list[list[float]] = Field(description="4x4 transform, translation in metres")
    covariance: list[list[float]] | None = Field(None, description="6x6 over [t (m), r (rad)]")
    intrinsics: CameraModel | None = None
    device: FiniteTree = Field(default_factory=dict)
    T_mount: list[list[float]] | None = Field(None, description="4x4 mounting guess (tape, CAD), m; None: "
                                               "the T_parent_child the frame was made with")
    mount_sigma: tuple[float, float] | None = Field(DEFAULT_MOUNT_SIGMA, description="1-sigma of the mounting "
                                                     "guess: m, deg; null when the mounting is unknown")
    not_connected: bool = Field(False, description="added as not connected; its device has not answered since")
    clock_offset_s: float = Field(0.0, description="how much the sensor's clock reads more than the rig's reference "
                                  "clock at the same instant (s)")
    clock_offset_std_s: float | None = Field(None, ge=0, description="1-sigma of clock_offset_s (s); null: not "
                                             "measured")

    @field_validator("T_parent_child", "T_mount")
    @classmethod
    def _four_by_four(cls, T: list[list[float]] | None) -> list[list[float]] | None:
        if T is not None and (len(T) != 4 or any(len(row) != 4 for row in T)):
            raise ValueError("must be 4x4")
        return T

    @field_validator("covariance")
    @classmethod
    def _six_by_six(cls, C: list[list[float]] | None) -> list[list[float]] | None:
        if C is not None and (len(C) != 6 or any(len(row) != 6 for row in C)):
            raise ValueError("covariance must be 6x6")
        return C


class RigModel(FiniteModel):
    root: str = "base_link"
    frames: list[FrameModel]


class Acceptance(FiniteModel):
    """One entry of the acceptance log: which result became current for which slot, when."""

    slot: str = Field(description="what the result calibrates, e.g. 'cam_front/intrinsics'")
    result_id: str | None = Field(description="the result made current; None: the slot was reverted (emptied)")
    at: float = Field(description="seconds since the epoch")
    verdict: Literal["trusted", "check", "reject"] | None = Field(
        None, description="the result's verdict when accepted (None in logs from before verdicts)")
    confirmed: bool = Field(False, description="the user confirmed a 'check' verdict to accept it")
    note: str | None = Field(None, description="why the slot changed when no accept or revert did it (its sensor "
                             "was removed or restored)")


class Removal(FiniteModel):
    """A sensor taken out of the rig: its frame as it was, the slots it emptied and where its captures went.
    Nothing is deleted: the captures move to ``removed/<id>/captures``, the results stay in ``results/``."""

    id: str = Field(pattern=REMOVAL_ID_PATTERN, description="'<sensor>-<n>', the folder under 'removed/'")
    sensor: str = Field(pattern=NAME_PATTERN)
    frame: FrameModel = Field(description="the frame as it was when removed")
    slots: dict[str, str] = Field(default_factory=dict, description="accepted slot -> result id the removal emptied")
    results: list[str] = Field(default_factory=list, description="the sensor's results, left out of its listings "
                               "while it is removed")
    at: float = Field(description="when it was removed, s since the epoch")
    restored_at: float | None = Field(None, description="when it was restored; None while it is removed")


class SessionFile(FiniteModel):
    schema_version: int
    name: str = Field(pattern=NAME_PATTERN)
    title: str = ""
    created: float
    board: str | None = None
    v_target: str | None = Field(None, description="the V-target's spec for LiDAR-camera solves, if one is used")
    test_field: str | None = Field(None, description="a wall test field beside the board (testfield:DICT:MARKER:"
                                   "survey.csv), for cameras' exterior orientation, if one is used")
    rig: RigModel
    accepted: dict[str, str] = Field(default_factory=dict, description="slot -> result id")
    acceptance_log: list[Acceptance] = Field(default_factory=list)
    removals: list[Removal] = Field(default_factory=list, description="every sensor removal, oldest first")


RECORDING_META_KEY = "recording"
"""The capture ``meta`` key naming the live recording a capture belongs to (sensors recorded together, every frame,
by :mod:`backend.services.motion_recording`)."""


class CaptureRecord(BaseModel):
    """Metadata of one capture; its data sits beside it as ``<id>.png`` (image) or ``<id>.npy`` (cloud)."""

    id: str
    sensor: str
    timestamp_s: float
    device: str
    source: str | None = Field(None, description="original file name of an upload or import")
    image_size: tuple[int, int] | None = Field(None, description="(width, height) px")
    n_points: int | None = Field(None, description="points in a cloud capture")
    n_imu_samples: int | None = Field(None, description="samples in an IMU capture (a stretch of an IMU's stream)")
    board: str | None = None
    detection: dict[str, Any] | None = None
    meta: dict[str, Any] = Field(default_factory=dict)


DEPTH_NETWORK_VERSION = 1
"""Version of ``depth_network.json``; a file of another version is refused (and quarantined) naming it."""


class GuidedNodeState(FiniteModel):
    """Where one depth node stands in the guided procedure (``backend.calib.depth.guided_service``)."""

    step: str | None = Field(None, description="the step to work on next; None: not started, or every step done")
    done: list[str] = Field(default_factory=list, description="steps whose criterion held when they were applied")
    history: list[list[list[float]]] = Field(default_factory=list, description="T_world_node (4x4, m) after "
                                             "every start, apply and nudge, oldest first; the last is current")
    result_id: str | None = Field(None, description="the result finish() stored, once finished")


class VerificationView(FiniteModel):
    """One node's sighting of a verification point: where that node sees it, in its own frame (m)."""

    node: str = Field(pattern=NAME_PATTERN)
    point_node_m: tuple[float, float, float]
    weight: float = Field(1.0, gt=0, description="its share in the point's estimate (e.g. the pixels it covers)")


class VerificationPoint(FiniteModel):
    """One end of a verified distance: a named point in the world (m) and the nodes that see it."""

    name: str = Field(min_length=1, max_length=64)
    point_m: tuple[float, float, float] = Field(description="world frame, m, when picked")
    views: list[VerificationView] = Field(default_factory=list, description="the nodes it was seen by; its "
                                          "estimate is their weighted mean at the nodes' current poses (none: "
                                          "point_m as it is)")


class VerificationEntry(FiniteModel):
    """A laser-measured distance between two picked points."""

    a: VerificationPoint
    b: VerificationPoint
    measured_m: float = Field(gt=0, description="laser-measured distance, m")


class DepthNetworkFile(FiniteModel):
    """``depth_network.json``: a depth cell's layout, the guided state per node and the verification table."""

    schema_version: int = DEPTH_NETWORK_VERSION
    layout: dict[str, Any] | None = Field(None, description="CellLayout.to_dict(); None: the default cell")
    guided: dict[str, GuidedNodeState] = Field(default_factory=dict)
    verification: list[VerificationEntry] = Field(default_factory=list)
