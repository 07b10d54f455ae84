"""Request and response models at the API edge (pydantic); the services take plain values.

Every request model is a :class:`~backend.store.schema.FiniteModel`: a NaN or infinity in any number
(JSON's ``NaN``/``Infinity`` literals, which FastAPI's parser accepts, or the strings ``"nan"``, ``"inf"``)
is a 422 naming the field, and so is one inside a free-form ``device`` mapping.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, Field

from backend.api.pose import Pose, Vector3, deprecated, deprecated_pair
from backend.core.rig import DEFAULT_MOUNT_SIGMA
from backend.store.schema import NAME_PATTERN, FiniteModel, FiniteTree


class ErrorBody(BaseModel):
    message: str
    input: str | None = None


class ErrorResponse(BaseModel):
    error: ErrorBody


class SessionCreate(FiniteModel):
    name: str = Field(pattern=NAME_PATTERN, examples=["robot-2026-11-23"])
    title: str = ""
    board: str | None = Field(None, examples=["checkerboard:9x6:0.025"])


class BoardUpdate(FiniteModel):
    board: str = Field(examples=["charuco:11x8:0.03:0.022:DICT_5X5_100", "testfield:DICT_4X4_50:0.15:survey.csv"],
                       max_length=500)


class VTargetUpdate(FiniteModel):
    v_target: str = Field(examples=["vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50"], max_length=200)


class TestFieldUpdate(FiniteModel):
    test_field: str = Field(examples=["testfield:DICT_4X4_50:0.15:survey.csv"], max_length=200,
                            description="a wall test field beside the board, its survey the session's survey.csv")


class ExteriorRequest(FiniteModel):
    capture_id: str = Field(max_length=64, description="the camera's capture that shows the wall")
    intrinsics_result: str | None = Field(None, max_length=64, description="a stored intrinsics result of the camera "
                                          "to resect with; default: the camera's intrinsics in the rig (accepted)")


class SensorCreate(FiniteModel):
    name: str = Field(pattern=NAME_PATTERN, examples=["cam_front"])
    parent: str = "base_link"
    kind: Literal["frame", "camera", "lidar3d", "lidar2d", "depth", "imu"] = "camera"
    pose: Pose = Field(default_factory=Pose, description="T_parent_sensor, the mounting guess (tape, CAD)")
    xyz_m: Vector3 | None = deprecated("pose.xyz_m")
    ypr_deg: Vector3 | None = deprecated("pose.ypr_deg")
    fold_pose = deprecated_pair("pose", "xyz_m", "ypr_deg")
    mount_sigma: MountSigma | None = Field(
        DEFAULT_MOUNT_SIGMA, description="1-sigma of the mounting above (m, deg), a weak prior edge of the rig graph; "
        "null: unknown, only calibrations place the sensor")
    device: FiniteTree = Field(default_factory=dict, examples=[{"driver": "uvc", "device": 0, "width": 1280,
                                                                     "height": 720}])
    connected: bool = Field(True, description="false: add as not connected (the rig defined before the hardware is "
                            "plugged in): the device is not opened now, and the sensor is listed as not connected "
                            "until it answers; true: the device is opened first, and one that does not answer is "
                            "refused (422 naming 'device')")


MountSigma = tuple[Annotated[float, Field(gt=0)], Annotated[float, Field(gt=0)]]
"""1-sigma of a mounting guess: translation (m, per axis), rotation (deg, per axis)."""


class SensorUpdate(FiniteModel):
    """An edit of one sensor: every field left out stays as it is."""

    parent: str | None = Field(None, pattern=NAME_PATTERN, description="the frame to hang from; without a pose "
                               "the sensor keeps its place")
    pose: Pose | None = Field(None, description="the new mounting guess T_parent_sensor (tape, CAD)")
    mount_sigma: MountSigma | None = Field(None, description="1-sigma of the mounting guess (m, deg); null: unknown "
                                           "(left out: kept)")
    device: FiniteTree | None = Field(None, examples=[{"driver": "uvc", "device": 1}])


class IntrinsicsSolveRequest(FiniteModel):
    model: Literal["pinhole-radtan", "fisheye-equidistant", "photogrammetric", "splined-stereographic", "auto"] = Field(
        "pinhole-radtan", description="'photogrammetric': the collinearity model with K1-K3, P1, P2, A1, A2; "
                                      "'splined-stereographic': mrcal's splined model, for wide and fisheye lenses; "
                                      "'auto': compare the lens models on held-out views and solve with the best")
    auto_for: Literal["any", "camera_info", "kalibr"] = Field(
        "any", description="with 'auto': choose only among the models this export carries (kalibr: no k3)")
    estimate_k3: bool = False
    estimate_tangential: bool = True
    fix_aspect: bool = False
    board_flex: bool = Field(True, description="solve the board's bow with the lens (mrcal's calobject_warp)")
    reject_corners: bool = Field(True, description="leave out single corners far beyond the corner noise")
    drop_outliers: bool = False
    outlier_factor: float = Field(3.0, gt=1.0)
    pixel_size_um: float | None = Field(None, gt=0, lt=1000, description="the pixel pitch (um): the photogrammetric "
                                        "model's parameters are reported in mm too")
    spline_knots: tuple[Annotated[int, Field(ge=4, le=40)], Annotated[int, Field(ge=4, le=40)]] | None = Field(
        None, description="splined-stereographic: the knots across and down (left out: chosen from the views)")
    spline_fov_x_deg: float | None = Field(None, gt=0, lt=360, description="splined-stereographic: the field of "
                                           "view across (deg) the knots span (left out: the image's plus a margin)")
    capture_ids: list[str] | None = None


class AcceptRequest(FiniteModel):
    result_id: str
    confirm: bool = Field(False, description="accept a result whose verdict is 'check' (its reasons were read)")
    revert: list[str] = Field(default_factory=list, description="accepted slots to empty in the same change (keep "
                              "this result over the ones it disagrees with)")


class PreviewRequest(FiniteModel):
    result_id: str
    revert: list[str] = Field(default_factory=list, description="accepted slots the accept would empty")


class RevertRequest(FiniteModel):
    slot: str = Field(description="the accepted slot to empty, e.g. 'lidar_front/T_lidar_top_lidar_front'")


class JobStatus(BaseModel):
    id: str
    title: str
    state: Literal["running", "done", "failed", "cancelled"]
    fraction: float
    message: str
    error: ErrorBody | None = None
    started: float
    finished: float | None = None
    result_id: str | None = None
    summary: dict[str, Any] | None = Field(None, description="what a job that makes no single result did "
                                                             "(an import: added capture ids, skipped, ended)")


class ImportResponse(BaseModel):
    added: list[dict[str, Any]]
    skipped: list[ErrorBody]


class LidarLidarSolveRequest(FiniteModel):
    source: str = Field(examples=["lidar_front"])
    target: str = Field(examples=["lidar_top"])
    init: Pose | None = Field(None, description="initial T_target_source")
    init_xyz_m: Vector3 | None = deprecated("init.xyz_m")
    init_ypr_deg: Vector3 | None = deprecated("init.ypr_deg")
    fold_init = deprecated_pair("init", "init_xyz_m", "init_ypr_deg")
    use_rig_guess: bool = Field(True, description="start from the rig's current transform when no init is given; "
                                                  "false runs global registration")
    voxel_m: float | None = Field(None, gt=0, description="fine GICP voxel size (m)")
    pairs: list[tuple[str, str]] | None = Field(
        None, description="(source capture id, target capture id) pairs, default the i-th capture of each; pairs "
                          "taken in different places are scenes: one transform is solved for all of them and each "
                          "scene's own solve cross-checks the others (the result's 'scenes' and 'verdict')")


class LidarLidarAccept(FiniteModel):
    result_id: str
    confirm: bool = Field(False, description="accept a result whose verdict is 'check' (its reasons were read)")


class RecordingImportRequest(FiniteModel):
    device: FiniteTree | None = Field(
        None, description="device settings of the recording; default the sensor's own device",
        examples=[{"driver": "rosbag", "path": "/data/run.mcap", "topic": "/points", "start_s": 5.0, "end_s": 20.0}])
    every: int = Field(1, ge=1, description="keep every n-th scan")
    limit: int = Field(200, ge=1, le=10_000, description="stop after this many scans")


class SweepCalibrateRequest(FiniteModel):
    capture_id: str | None = Field(None, description="the sweep to calibrate from; default the latest swept capture")
    up_mount: tuple[float, float, float] | None = Field(
        None, description="the floor's up direction in the sensor (mount) frame; default the rig root's +z")
    estimate_tilt: bool = Field(True, description="also estimate the scanner's tilt on the servo horn")


class LidarCameraPairCapture(FiniteModel):
    camera: str = Field(examples=["cam_front"])
    lidar: str = Field(examples=["lidar_top"])
    require_board: bool = Field(True, description="refuse a pair whose image shows no board (off for the "
                                                  "targetless method), and wait for the board to hold still")
    integration_s: float | None = Field(None, gt=0, le=60, description="add the LiDAR's frames up over this many "
                                        "seconds of its time (a non-repetitive Livox); null: one scan")


class LidarCameraSolveRequest(FiniteModel):
    camera: str = Field(examples=["cam_front"])
    lidar: str = Field(examples=["lidar_top"])
    method: Literal["target", "vtarget", "edges", "intensity"] = Field(
        "target", description="target: the session's board; vtarget: the session's V-target (PUT .../v-target); "
                              "edges, intensity: targetless")
    image_ids: list[str] | None = Field(None, description="solve from the pairs of these image captures; default all")
    init: Pose | None = Field(None, description="initial T_camera_lidar; default the rig's current transform")
    init_xyz_m: Vector3 | None = deprecated("init.xyz_m")
    init_ypr_deg: Vector3 | None = deprecated("init.ypr_deg")
    fold_init = deprecated_pair("init", "init_xyz_m", "init_ypr_deg")
    plate_margin_m: float | None = Field(None, ge=0, description="the board plate's margin beyond the pattern (m); "
                                                                  "default: estimated with the transform")
    translation_prior_m: float | None = Field(None, gt=0, description="edges, intensity: hold the initial "
                                                                       "translation as measured to this 1-sigma (m)")
    cross_check: bool = Field(False, description="edges, intensity: also solve with the other targetless method; "
                                                 "their agreement is a cross-check in the verdict")


class LidarCameraManual(FiniteModel):
    camera: str = Field(examples=["cam_front"])
    lidar: str = Field(examples=["lidar_top"])
    pose: Pose = Field(description="T_camera_lidar")
    xyz_m: Vector3 | None = deprecated("pose.xyz_m")
    ypr_deg: Vector3 | None = deprecated("pose.ypr_deg")
    fold_pose = deprecated_pair("pose", "xyz_m", "ypr_deg")
    inputs: list[str] = Field(default_factory=list, description="the captures it was judged on, as sensor:capture")


class MulticamSetCapture(FiniteModel):
    cameras: list[str] = Field(min_length=2, examples=[["cam_front", "cam_wide"]])
    tolerance_s: float = Field(0.02, ge=0, description="largest spread of the cameras' frame stamps (s)")
    require_board: bool = Field(True, description="refuse a set in which fewer than two cameras see the board")


class MulticamBagImport(FiniteModel):
    path: str = Field(description="a ROS 2 bag (folder, .mcap or .db3) on the server's machine")
    topics: dict[str, str] = Field(min_length=2, description="camera -> image topic",
                                   examples=[{"cam_front": "/cam_front/image_raw", "cam_wide": "/cam_wide/image_raw"}])
    tolerance_s: float = Field(0.02, ge=0, description="frames of one set lie within this many seconds (s)")
    every: int = Field(1, ge=1, description="keep every n-th matched set")
    limit: int | None = Field(None, ge=1, description="store at most this many sets")
    start_s: float | None = Field(None, description="skip frames before this bag time (s)")
    end_s: float | None = Field(None, description="skip frames after this bag time (s)")


class MulticamSolveRequest(FiniteModel):
    cameras: list[str] = Field(min_length=2, description="the first is the reference", examples=[["cam_front",
                                                                                                 "cam_wide"]])
    refine_intrinsics: bool = Field(False, description="refine every camera's intrinsics with the rig (cameras "
                                                       "without intrinsics are always estimated)")
    set_names: list[str] | None = Field(None, description="solve from these sets only; default all")
