"""What the calibration report shows, read from a session.

Everything comes from the session as stored: the accepted results (the acceptance slots), the
captures they were solved from, and the rig tree fused from every accepted edge
(:func:`backend.calib.rig.service.solve_rig`). Residuals a record does not keep are recomputed from
its captures: the corners of an intrinsics view from the stored detection and the accepted
camera and board pose, the cloud-to-cloud distances of a LiDAR-LiDAR edge from its clouds.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from backend.calib.board.detection import Detection
from backend.calib.intrinsics.flex import solved_board
from backend.calib.lidar_camera.service import session_pose_evidence
from backend.calib.lidar_camera.target_evidence import PoseEvidence
from backend.calib.lidar_lidar.gicp import LidarLidarSettings, evaluate_alignment
from backend.calib.rig.graph import EdgeResidual, RigTree
from backend.calib.rig.service import solve_rig
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import StoredResult, TransformResult
from backend.core.transforms import transform_points
from backend.store.schema import Acceptance
from backend.store.session import Session

C2C_POINTS_PER_PAIR = 30_000
"""Source points (at most) per capture pair whose cloud-to-cloud distance the histogram shows."""


@dataclass
class ViewResiduals:
    """One board view of an intrinsics solve."""

    name: str
    """The capture id the view was solved from."""
    used: bool
    outlier: bool
    rms_px: float
    corners_px: np.ndarray
    """(N, 2) detected corner positions (px), the corner set the solve used."""
    residuals_px: np.ndarray | None
    """(N, 2) detected minus projected corner positions (px); None when neither stored nor recomputable (a view
    without a board pose)."""
    recomputed: bool
    """True when the residuals were recomputed from the capture, the camera and the board pose."""


@dataclass
class CameraReport:
    """A camera's accepted intrinsics result with its views."""

    sensor: str
    result_id: str
    record: dict[str, Any]
    views: list[ViewResiduals]
    unreadable: list[str] = field(default_factory=list)
    """``"<capture>: <why>"`` for views whose corners could not be read back."""

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in px."""
        return int(self.record["camera"]["width"]), int(self.record["camera"]["height"])

    @property
    def n_corners(self) -> int:
        """Corners of the used views."""
        return sum(len(v.corners_px) for v in self.views if v.used)

    def rejected_corners(self) -> np.ndarray:
        """(M, 2) detected positions (px) of the corners the solve rejected as outliers, every view's."""
        rejected = [view["rejected"]["corners_px"] for view in self.record.get("views", []) if view.get("rejected")]
        return np.array([corner for corners in rejected for corner in corners], float).reshape(-1, 2)

    def used_corners(self) -> np.ndarray:
        """(N, 2) corners (px) of the used views."""
        corners = [v.corners_px for v in self.views if v.used]
        return np.vstack(corners) if corners else np.zeros((0, 2))

    def residual_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Corners (N, 2) px, residuals (N, 2) px and view index (N,) of the used views that have residuals."""
        kept = [(i, v) for i, v in enumerate(self.views) if v.used and v.residuals_px is not None]
        if not kept:
            return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int)
        corners = np.vstack([v.corners_px for _, v in kept])
        residuals = np.vstack([v.residuals_px for _, v in kept])
        views = np.concatenate([np.full(len(v.corners_px), i) for i, v in kept])
        return corners, residuals, views


@dataclass
class EdgeReport:
    """One accepted transform: a rig edge with its residual in the fused tree, or a sensor's own geometry (a swept
    scanner's, ``residual`` None: not an edge of the rig graph)."""

    residual: EdgeResidual | None
    result: TransformResult
    record: dict[str, Any]
    """The stored service record (``id``, ``sensor``, ``inputs``, ``created``...), which may hold several
    transforms (multi-camera)."""
    c2c_m: np.ndarray | None = None
    """LiDAR-LiDAR: cloud-to-cloud distances (m) of the inlier source points after the transform."""
    c2c_note: str = ""
    """How the distances were taken, or why they could not be."""
    poses: list[PoseEvidence] = field(default_factory=list)
    """LiDAR-camera target: each pose's board points against the plate outline at the result
    (:func:`~backend.calib.lidar_camera.service.session_pose_evidence`)."""
    poses_note: str = ""
    """Why a target result's poses could not be shown, or empty."""

    @property
    def n_inputs(self) -> int:
        """Data units the result was solved from (views, pairs, sets)."""
        return len(self.record.get("inputs", []))


@dataclass
class ReportData:
    """Everything the report shows."""

    session: dict[str, Any]
    """:meth:`Session.info`, with ``depth_network``: the depth nodes' :func:`~backend.calib.depth.service.
    network_summary` (None when the rig has no depth node), which the template reads from here."""
    generated_at: float
    """s since the epoch."""
    frames: list[dict[str, Any]]
    """Every non-root frame of the rig: ``name``, ``kind``, ``parent``, ``captures`` (how many it holds),
    ``clock_offset_s`` and ``clock_offset_std_s`` (its clock against the rig's, s; the sigma None if not measured)."""
    tree: RigTree
    cameras: list[CameraReport]
    cameras_without_intrinsics: dict[str, str]
    """Camera -> why the report has no intrinsics section for it."""
    edges: list[EdgeReport]
    geometries: list[EdgeReport]
    """Accepted sensor geometries that are transforms but no rig edge (a swept scanner's mount to scanner)."""
    acceptance_log: list[Acceptance]


def gather(session: Session) -> ReportData:
    """Read the report's data from ``session`` (nothing is written). The accepted results, the rig and its tree are
    read under the session's lock, so an accept cannot land in between; results and captures are write-once, so
    what is read from them afterwards (corners, clouds) is what they were."""
    with session.lock:
        accepted = [session.result(result_id) for result_id in session.accepted_slots().values()]
        tree = solve_rig(session)
        rig = copy.deepcopy(session.rig)
        info, acceptance_log = session.info(), session.acceptance_log
        info["depth_network"] = depth_network_summary(session) if rig.sensors("depth") else None
    frames = [{"name": f.name, "kind": f.kind, "parent": f.parent,
               "captures": len(session.captures(f.name)) if f.kind != "frame" else 0,
               "clock_offset_s": f.clock_offset_s, "clock_offset_std_s": f.clock_offset_std_s}
              for f in rig.frames.values() if f.parent is not None]
    cameras, missing = [], {}
    intrinsics = {r["sensor"]: r for r in accepted if StoredResult(r).kind == "intrinsics"}
    for camera in rig.sensors("camera"):
        if camera.name in intrinsics:
            cameras.append(camera_report(session, intrinsics[camera.name]))
        else:
            count = len(session.results(camera.name, "intrinsics"))
            missing[camera.name] = ("its intrinsics come from another accepted result (a multi-camera solve)"
                                    if camera.intrinsics is not None else
                                    f"no accepted intrinsics result ({count} in the history)" if count else
                                    "no intrinsics solve yet")
    edges = [edge_report(session, residual) for residual in tree.edges if residual.edge.result_id is not None]
    geometries = [EdgeReport(None, transform, r) for r in accepted if StoredResult(r).kind == "sweep"
                  for transform in StoredResult(r).transforms]
    return ReportData(session=info, generated_at=time.time(), frames=frames, tree=tree, cameras=cameras,
                      cameras_without_intrinsics=missing, edges=edges, geometries=geometries,
                      acceptance_log=acceptance_log)


def depth_network_summary(session: Session) -> dict[str, Any]:
    """The depth network as the report shows it: :func:`~backend.calib.depth.service.network_summary` (each
    node's pose, sigma and verdict; the verification table) with the pose table's rows."""
    from backend.calib.depth.service import network_summary

    return network_summary(session)


def camera_report(session: Session, record: dict[str, Any]) -> CameraReport:
    """The views of an intrinsics ``record`` with their corners read from the captures, and their residuals as
    stored or, where the record lacks them, recomputed (:func:`view_residuals`)."""
    camera = CameraIntrinsics.from_dict(record["camera"])
    board = solved_board(record)
    corner_set = record.get("corners", {}).get("chosen", "sb")
    captures = {c.id: c for c in session.captures(record["sensor"])}
    views, unreadable = [], []
    for view in record["views"]:
        capture = captures.get(view["image"])
        if capture is None or not capture.detection:
            unreadable.append(f"{view['image']}: no such capture with a detection in the session")
            continue
        views.append(view_residuals(view, Detection.from_dict(capture.detection), corner_set, camera, board))
    return CameraReport(record["sensor"], record["id"], record, views, unreadable)


def view_residuals(view: dict[str, Any], detection: Detection, corner_set: str, camera: CameraIntrinsics,
                   board: BoardSpec) -> ViewResiduals:
    """A stored view (``image``, ``ids``, ``residuals_px``, ``T_camera_board``...) with its corners from
    ``detection`` (``corner_set``: ``sb`` or a refinement name). Residuals missing from the record are the
    detected corners minus the board corners projected through ``T_camera_board`` (px)."""
    ids = np.asarray(view["ids"], dtype=int)
    positions = detection.refined.get(corner_set, detection.corners_px)
    index = {corner_id: i for i, corner_id in enumerate(detection.ids.tolist())}
    unknown = [int(i) for i in ids if int(i) not in index]
    if unknown:
        raise InputError(f"view {view['image']}: corners {unknown[:5]} are not in its capture's detection",
                         view["image"])
    corners = positions[[index[int(i)] for i in ids]]
    residuals, recomputed = view.get("residuals_px"), False
    if residuals is not None:
        residuals = np.asarray(residuals, dtype=float).reshape(-1, 2)
    elif view.get("T_camera_board") is not None:
        points_camera = transform_points(np.asarray(view["T_camera_board"], dtype=float), board.object_points[ids])
        residuals, recomputed = corners - camera.project(points_camera), True
    return ViewResiduals(view["image"], bool(view.get("used", True)), bool(view.get("outlier", False)),
                         float(view["rms_px"]), corners, residuals, recomputed)


def edge_report(session: Session, residual: EdgeResidual) -> EdgeReport:
    """An accepted edge with its stored result (and, for LiDAR-LiDAR, its cloud-to-cloud distances)."""
    record = session.result(residual.edge.result_id)
    edge = residual.edge
    result = next(t for t in StoredResult(record).edges if (t.parent, t.child) == (edge.parent, edge.child))
    report = EdgeReport(residual, result, record)
    if result.kind == "lidar_lidar":
        report.c2c_m, report.c2c_note = c2c_distances(session, result, record.get("inputs", []))
    if result.kind == "lidar_camera" and result.method == "target":
        try:
            report.poses = session_pose_evidence(session, record["sensor"], record["id"])
        except InputError as error:
            report.poses_note = f"{error.input}: {error.message}"
    return report


def c2c_distances(session: Session, result: TransformResult, pairs: list[str]) -> tuple[np.ndarray | None, str]:
    """Cloud-to-cloud distances (m) of a LiDAR-LiDAR result's capture pairs (``"SOURCE_ID:TARGET_ID"``: the
    child's and the parent's captures), recomputed: the source points mapped by ``T_parent_child``, their nearest
    target point within the solve's correspondence distance; at most :data:`C2C_POINTS_PER_PAIR` source points a
    pair (a fixed random subset). Returns the distances and how they were taken, or None and why not."""
    max_distance_m = float(result.settings.get("max_correspondence_m", LidarLidarSettings.max_correspondence_m))
    rng = np.random.default_rng(0)
    distances = []
    for pair in pairs:
        source_id, _, target_id = pair.partition(":")
        try:
            source, _ = session.capture_cloud(result.child, source_id)
            target, _ = session.capture_cloud(result.parent, target_id)
        except InputError as exc:
            return None, f"pair {pair}: {exc.message}"
        if len(source) > C2C_POINTS_PER_PAIR:
            source = source[rng.choice(len(source), C2C_POINTS_PER_PAIR, replace=False)]
        distances.append(evaluate_alignment(source, target, result.T_parent_child, max_distance_m)["distances_m"])
    if not distances:
        return None, "the record names no capture pairs"
    return np.concatenate(distances), (f"{len(pairs)} pair(s), at most {C2C_POINTS_PER_PAIR} source points each, "
                                       f"inliers within {max_distance_m * 1e3:.0f} mm")
