"""LiDAR-to-camera workflow shared by the CLI and the studio.

Solving: image + cloud pairs of a board seen by both sensors -> the camera's board pose per
image (detection and PnP with the known intrinsics) and the LiDAR's cloud -> the target-based
solve of ``T_camera_lidar`` (:mod:`backend.calib.lidar_camera.target`). Every input that
cannot be used is refused naming the file: an image or cloud that cannot be read, an image
whose size disagrees with the intrinsics, a board that is not found.

Every solve is kept as the solver's :class:`~backend.core.result.TransformResult` between the rig's
frames (parent: the camera, child: the LiDAR) with its before/after overlays. By hand: a transform set
with the studio's sliders is kept the same way, of method ``manual`` (covariance undetermined: nothing
measured it) naming the image and cloud it was judged on. Either is accepted into the rig graph by
:func:`backend.calib.rig.service.accept`, like every result kind.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from backend.calib._session import check_camera, check_lidar, result_of, session_plane_board, session_v_target
from backend.calib.board.detection import Detection
from backend.calib.lidar_camera.capture import check_image_size, stored_pairs
from backend.calib.lidar_camera.checks import MANUAL_VERDICT, CrossCheck, compare_methods, judge
from backend.calib.lidar_camera.edges import EdgeObservation, LidarCameraEdgesSettings, solve_edges
from backend.calib.lidar_camera.intensity import (
    IntensityObservation,
    LidarCameraIntensitySettings,
    solve_intensity,
)
from backend.calib.lidar_camera.lens_uncertainty import LensUncertainty
from backend.calib.lidar_camera.target import (
    LidarCameraTargetSettings,
    TargetObservation,
    camera_board_pose,
    found_board,
    solve_target,
)
from backend.calib.lidar_camera.target_evidence import PoseEvidence, pose_evidence
from backend.calib.lidar_camera.v_target import camera_v_target_pose, solve_v_target
from backend.calib.lidar_lidar.accumulation import accumulate_scans
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.overlay import ColourScale, OverlayStyle, mosaic, render_overlay, render_overlays
from backend.core.projection import Projection
from backend.core.result import ProgressCallback, StoredResult, TransformResult, no_progress
from backend.core.transforms import check_transform
from backend.core.v_target import VTarget
from backend.devices.cloud_files import read_cloud
from backend.devices.image_io import encode_jpeg, read_image
from backend.store.session import Session

METHODS = ("target", "vtarget", "edges", "intensity")
TARGETLESS = ("edges", "intensity")
"""The targetless methods: each cross-checks the other on the same pairs."""
DEFAULT_PLATE_MARGIN_SQUARES = 1.0
"""Unless told the plate margin, the target solve estimates it starting from this many squares beyond the
pattern's outer corners (a white border of one square, as printed boards often have; the LiDAR sees the plate's
edges)."""


KIND = "lidar_camera"


def lidar_camera_record(session: Session, lidar: str, result_id: str) -> dict[str, Any]:
    """The stored record of a LiDAR-to-camera result of ``lidar``; :class:`InputError` naming ``result`` when it is
    another kind or another sensor's."""
    return result_of(session, KIND, result_id, lidar)


def store_manual(session: Session, camera: str, lidar: str, T_camera_lidar: np.ndarray, *,
                 inputs: list[str]) -> str:
    """Keep a hand-set ``T_camera_lidar`` as a result of ``lidar`` (``inputs``: the captures it was judged on): a
    :class:`~backend.core.result.TransformResult` record of method ``manual`` whose covariance is undetermined
    (the rig service gives such an edge an assumed sigma)."""
    check_lidar(session, lidar)
    check_camera(session, camera)
    T_camera_lidar, _ = check_transform(T_camera_lidar, "T_camera_lidar")
    result = TransformResult(kind=KIND, method="manual", parent=camera, child=lidar, T_parent_child=T_camera_lidar,
                             covariance=np.full((6, 6), np.nan), verdict=MANUAL_VERDICT,
                             warnings=["set by hand: no uncertainty"])
    return session.add_result(lidar, result.to_record(), inputs=inputs)


def cli_summary(result: TransformResult) -> dict[str, Any]:
    """``{"T_camera_lidar", "std", "residuals", "seconds", "verdict"}``: the ``lidar-camera`` command's JSON as
    ``conventions.md`` gives it (``verdict`` None until judged)."""
    summary = result.summary()
    return {"T_camera_lidar": summary["T_parent_child"]} | {key: summary[key] for key in
                                                            ("std", "residuals", "seconds", "verdict")}


def target_settings(board: BoardSpec, plate_margin_m: float | None = None) -> LidarCameraTargetSettings:
    """The target solve's settings for ``board``, whose plate reaches ``plate_margin_m`` (m) beyond the pattern's
    outer corners; None estimates it with the transform, from :data:`DEFAULT_PLATE_MARGIN_SQUARES` squares."""
    if plate_margin_m is None:
        return replace(LidarCameraTargetSettings(), plate_margin_m=DEFAULT_PLATE_MARGIN_SQUARES * board.square_m,
                       solve_plate_margin=True)
    if not plate_margin_m >= 0:
        raise InputError(f"expected a plate margin of 0 m or more, got {plate_margin_m}", "--plate-margin")
    return replace(LidarCameraTargetSettings(), plate_margin_m=float(plate_margin_m))


PRIOR_SEARCH_SIGMAS = 2.5
"""With a translation prior, the coarse edge search stays within this many of its sigmas of the initial translation."""


def edges_settings(translation_prior_m: float | None = None) -> LidarCameraEdgesSettings:
    """The targetless solve's settings; ``translation_prior_m`` (m, 1-sigma per axis) holds the initial guess's
    translation as a measurement (for scenes whose edges are all far, where edges fix the rotation but hardly the
    translation), and keeps the coarse search within :data:`PRIOR_SEARCH_SIGMAS` of it."""
    if translation_prior_m is None:
        return LidarCameraEdgesSettings()
    if not translation_prior_m > 0:
        raise InputError(f"expected a translation prior above 0 m, got {translation_prior_m}", "--translation-prior")
    defaults = LidarCameraEdgesSettings()
    return replace(defaults, fine=replace(defaults.fine, translation_prior_m=float(translation_prior_m)),
                   coarse=replace(defaults.coarse, max_translation_m=PRIOR_SEARCH_SIGMAS * translation_prior_m))


def intensity_settings(translation_prior_m: float | None = None) -> LidarCameraIntensitySettings:
    """The intensity solve's settings; ``translation_prior_m`` (m, 1-sigma per axis) holds the initial guess's
    translation as a measurement, as for the edges (:func:`edges_settings`)."""
    if translation_prior_m is None:
        return LidarCameraIntensitySettings()
    if not translation_prior_m > 0:
        raise InputError(f"expected a translation prior above 0 m, got {translation_prior_m}", "--translation-prior")
    return replace(LidarCameraIntensitySettings(), translation_prior_m=float(translation_prior_m))


def edge_observation(image: np.ndarray, points: np.ndarray, intensity: np.ndarray | None, name: str
                     ) -> EdgeObservation:
    """A targetless observation; the cloud's intensities, when it has them, give reflectivity edges."""
    return EdgeObservation(image, points if intensity is None else np.column_stack([points, intensity]), name=name)


@dataclass
class PairData:
    """One image and the cloud taken with it, as the solvers take them."""

    name: str
    """How the solve names the pair (``image.png:cloud.pcd``, or a stored pair's name)."""
    image_source: str
    """How errors about the image name it (its path, or the stored pair's name)."""
    image: np.ndarray
    """uint8 gray or BGR image."""
    points: np.ndarray
    """(N, 3) cloud in the LiDAR frame (m)."""
    intensity: np.ndarray | None
    """(N,) return intensities, or None."""
    detection: Detection | None = None
    """The board's corners found in the image when the pair was stored (the accurate detector's), or None: the
    target solve then finds them again."""


def check_method(method: str, input_name: str, cross_check: bool = False) -> None:
    if method not in METHODS:
        raise InputError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}", input_name)
    if cross_check and method not in TARGETLESS:
        raise InputError(f"the cross-check between methods is made for the targetless methods ({', '.join(TARGETLESS)}"
                         f"), each against the other; got method {method!r}", input_name)


def read_pair_files(pairs: Sequence[tuple[Path, Path | Sequence[Path]]],
                    progress: ProgressCallback = no_progress) -> list[PairData]:
    """The (image, cloud) files read; an unreadable one raises :class:`InputError` naming it. A pair's cloud may be
    several files: scans of a static scene from a sensor at rest, merged into one denser cloud
    (:func:`~backend.calib.lidar_lidar.accumulation.accumulate_scans`, in the first scan's frame)."""
    read = []
    for i, (image_path, cloud_paths) in enumerate(pairs):
        cloud_paths = [cloud_paths] if isinstance(cloud_paths, Path | str) else list(cloud_paths)
        cloud_name = ",".join(Path(c).name for c in cloud_paths)
        progress(0.1 * i / max(len(pairs), 1), f"reading {image_path.name} and {cloud_name}")
        image, clouds = read_image(image_path), [read_cloud(c) for c in cloud_paths]
        if len(clouds) == 1:
            points, intensity = clouds[0].points, clouds[0].intensity
        else:
            merged = accumulate_scans([c.points if c.intensity is None else np.column_stack([c.points, c.intensity])
                                       for c in clouds], names=[str(c) for c in cloud_paths])
            points, intensity = merged[:, :3], merged[:, 3] if merged.shape[1] > 3 else None
        read.append(PairData(f"{image_path.name}:{cloud_name}", str(image_path), image, points, intensity))
    return read


def solve_pairs(camera: CameraIntrinsics, board: BoardSpec | VTarget | None, pairs: Sequence[PairData],
                T_init: np.ndarray, *, method: str = "target", plate_margin_m: float | None = None,
                translation_prior_m: float | None = None, cross_check: bool = False,
                lens: LensUncertainty | None = None, progress: ProgressCallback = no_progress) -> TransformResult:
    """``T_camera_lidar`` from images and clouds of the same moments, starting from ``T_init``.

    ``method="target"`` needs the ``board`` both sensors see (``method="vtarget"``: the V-target,
    :func:`solve_v_target_pairs`); ``plate_margin_m``: how far its plate reaches
    beyond the pattern's outer corners (m; default: estimated, :func:`target_settings`); ``lens``: the camera's
    intrinsics' sigmas, carried into the board poses and so into the result's sigma (else the result says they
    are not known).
    ``method="edges"`` is targetless (:func:`~backend.calib.lidar_camera.edges.solve_edges`): it aligns the
    edges of ordinary scenes and takes the clouds' intensities, where there are any, for reflectivity edges;
    ``translation_prior_m``: see :func:`edges_settings`. ``method="intensity"`` is targetless too
    (:func:`~backend.calib.lidar_camera.intensity.solve_intensity`): it matches the clouds' intensities (which
    it needs) with the images' grey values; ``cross_check`` (targetless methods) also solves the same pairs with
    the other targetless method and puts the two methods' agreement into the result's verdict
    (:func:`cross_check_methods`). An image whose size is not the intrinsics' is refused. A pose whose board is not
    found in the image (or in the cloud) is skipped and named in the result's warnings.
    """
    check_method(method, "method", cross_check)
    for pair in pairs:
        check_image_size(pair.image, camera, pair.image_source)
    if method in TARGETLESS:
        share = 0.45 if cross_check else 0.9
        result = solve_targetless(method, camera, pairs, T_init, translation_prior_m,
                                  lambda fraction, message: progress(0.1 + share * fraction, message))
        extra = [] if not cross_check else [cross_check_methods(
            result, camera, pairs, T_init, translation_prior_m,
            lambda fraction, message: progress(0.55 + 0.45 * fraction, f"cross-check: {message}"))]
        judge(result, extra)
        return result
    if method == "vtarget":
        if not isinstance(board, VTarget):
            raise InputError("the vtarget method needs the V-target's spec, e.g. "
                             "vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50", "--board")
        return solve_v_target_pairs(camera, board, pairs, T_init, progress)
    if not isinstance(board, BoardSpec):
        raise InputError("the target method needs the board's spec, e.g. checkerboard:9x6:0.04", "--board")
    settings = target_settings(board, plate_margin_m)
    observations, skipped = [], []
    for i, p in enumerate(pairs):
        progress(0.1 + 0.2 * i / max(len(pairs), 1), f"finding the board in {p.name}")
        try:
            detection = found_board(p.image, board, p.image_source, p.detection)
            T_camera_board = camera_board_pose(p.image, camera, board, name=p.image_source, detection=detection)
        except InputError as error:
            skipped.append(f"{error.input}: {error.message}")
            continue
        observations.append(TargetObservation(T_camera_board, p.points, name=p.name, T_camera_board_lens=None if (
            lens is None) else lens.board_poses(camera, board, detection)))
    result = solve_target(board, observations, T_init, settings,
                          lambda fraction, message: progress(0.3 + 0.7 * fraction, message), skipped,
                          None if lens is None else lens.correlation)
    result.diagnostics["lens_uncertainty"] = (
        f"carried into the board poses, from {lens.source} ({', '.join(lens.names)})" if lens is not None else
        "not known: the result's sigma leaves out the camera's intrinsics' own (give their sigmas, or accept the "
        "camera's intrinsics from a solve)")
    result.diagnostics["board_flex_mm"] = [1e3 * w for w in board.warp_m]  # as the camera's intrinsics measured it
    judge(result)
    return result


def solve_v_target_pairs(camera: CameraIntrinsics, target: VTarget, pairs: Sequence[PairData], T_init: np.ndarray,
                         progress: ProgressCallback = no_progress) -> TransformResult:
    """The V-target method on the pairs (:func:`~backend.calib.lidar_camera.v_target.solve_v_target`); a pair whose
    image does not show the target's markers is left out, named in the result's warnings."""
    placements, skipped = [], []
    for i, p in enumerate(pairs):
        progress(0.1 + 0.4 * i / max(len(pairs), 1), f"finding the V-target's markers in {p.name}")
        try:
            placement = camera_v_target_pose(p.image, camera, target, p.image_source, p.points)
        except InputError as error:
            skipped.append(f"{error.input}: {error.message}")
            continue
        placements.append(replace(placement, name=p.name))
    if not placements:
        raise InputError("no image shows the V-target's markers: " + "; ".join(skipped[:3]), pairs[0].image_source)
    progress(0.5, f"fitting the plates in {len(placements)} clouds")
    result = solve_v_target(target, placements, T_init)
    result.warnings[:0] = skipped
    result.diagnostics["lens_uncertainty"] = ("not carried: the result's sigma holds the markers' and the clouds' "
                                              "noise with the camera's intrinsics taken as exact")
    return result


def solve_targetless(method: str, camera: CameraIntrinsics, pairs: Sequence[PairData], T_init: np.ndarray,
                     translation_prior_m: float | None = None, progress: ProgressCallback = no_progress
                     ) -> TransformResult:
    """One targetless solve (``method`` "edges" or "intensity") of the pairs; see :func:`solve_pairs`."""
    if method == "edges":
        observations = [edge_observation(p.image, p.points, p.intensity, p.name) for p in pairs]
        return solve_edges(camera, observations, T_init, edges_settings(translation_prior_m), progress)
    observations = [IntensityObservation(p.image, p.points, p.intensity, p.name) for p in pairs]
    return solve_intensity(camera, observations, T_init, intensity_settings(translation_prior_m), progress)


def cross_check_methods(result: TransformResult, camera: CameraIntrinsics, pairs: Sequence[PairData],
                        T_init: np.ndarray, translation_prior_m: float | None = None,
                        progress: ProgressCallback = no_progress) -> CrossCheck:
    """Solve the same pairs with the other targetless method and compare the two answers
    (:func:`~backend.calib.lidar_camera.checks.compare_methods`; kept in ``result.diagnostics["cross_check"]``): the
    cross-check for :func:`judge`, not made when the other method cannot answer (refused, or not one answer)."""
    other_method = next(m for m in TARGETLESS if m != result.method)
    name = f"against the {other_method} method"
    try:
        other = solve_targetless(other_method, camera, pairs, T_init, translation_prior_m, progress)
    except InputError as refused:
        return CrossCheck(name, f"the {other_method} method could not solve these pairs: {refused.message}")
    if not other.converged:
        return CrossCheck(name, f"the {other_method} method gave no usable answer: " + "; ".join(other.warnings))
    agreement = compare_methods(result.T_parent_child, result.covariance, other.T_parent_child, other.covariance,
                                other_method)
    result.diagnostics["cross_check"] = agreement.to_record()
    return CrossCheck(name, agreement.detail(), agreement.sigmas)


def solve_files(camera: CameraIntrinsics, board: BoardSpec | VTarget | None, pairs: Sequence[tuple[Path, Path]],
                T_init: np.ndarray, *, method: str = "target", plate_margin_m: float | None = None,
                translation_prior_m: float | None = None, cross_check: bool = False,
                lens: LensUncertainty | None = None, progress: ProgressCallback = no_progress) -> TransformResult:
    """:func:`solve_pairs` on (image, cloud) files of the same moments (a pair's cloud may be several scans: see
    :func:`read_pair_files`)."""
    check_method(method, "--method", cross_check)
    return solve_pairs(camera, board, read_pair_files(pairs, progress), T_init, method=method,
                       plate_margin_m=plate_margin_m, translation_prior_m=translation_prior_m,
                       cross_check=cross_check, lens=lens, progress=progress)


OVERLAY_PAIRS = 4
"""Before/after overlays are stored with a result for at most this many of its pairs."""
OVERLAY_WIDTH_PX = 1280
"""Width of a stored before/after overlay mosaic (px)."""


def load_pairs(session: Session, camera: str, lidar: str, image_ids: list[str] | None = None) -> list[PairData]:
    """The stored pairs (all, or those whose image is in ``image_ids``) with their data."""
    found = stored_pairs(session, camera, lidar, image_ids)
    if not found:
        raise InputError(f"no image+cloud pairs of {camera} and {lidar} yet: capture or upload pairs of the same "
                         "moments first", "pairs")
    return [PairData(p.name, p.name, session.capture_image(camera, p.image.id),
                     *session.capture_cloud(lidar, p.cloud.id),
                     Detection.from_dict(p.image.detection) if p.image.detection else None) for p in found]


def session_pose_evidence(session: Session, lidar: str, result_id: str) -> list[PoseEvidence]:
    """Each pose's evidence (:func:`~backend.calib.lidar_camera.target_evidence.pose_evidence`) of the stored target
    result ``result_id`` of ``lidar``: its pairs read back, the board posed in each image with the camera's
    intrinsics, the board's points found again at the result's transform with the solve's own settings.
    :class:`InputError` naming ``result`` for another method's result."""
    record = lidar_camera_record(session, lidar, result_id)
    result = StoredResult(record).edges[0]
    if result.method != "target":
        raise InputError(f"result {result_id} is of the {result.method} method; only the board (target) method has "
                         "poses", "result")
    camera, board = camera_intrinsics(session, result.parent), session_plane_board(session, "the target method")
    names = {pose["name"] for pose in result.diagnostics.get("poses", [])}
    image_ids = [p.image.id for p in stored_pairs(session, result.parent, lidar) if p.name in names]
    observations = []
    for pair in load_pairs(session, result.parent, lidar, image_ids) if image_ids else []:
        T_camera_board = camera_board_pose(pair.image, camera, board, name=pair.image_source, detection=pair.detection)
        observations.append(TargetObservation(T_camera_board, pair.points, name=pair.name))
    known = {f.name for f in fields(LidarCameraTargetSettings)}
    settings = LidarCameraTargetSettings(**{k: v for k, v in result.settings.items() if k in known})
    return pose_evidence(board, observations, result.diagnostics, result.T_parent_child, settings)


def overlay_scene(session: Session, camera: str, lidar: str, image_id: str, cloud_id: str | None = None) -> PairData:
    """The scene an overlay draws: the image capture ``image_id`` with its stored pair's cloud, or with the LiDAR's
    cloud capture ``cloud_id`` (any two captures)."""
    if cloud_id is None:
        return load_pairs(session, camera, lidar, [image_id])[0]
    return PairData(image_id, image_id, session.capture_image(camera, image_id),
                    *session.capture_cloud(lidar, cloud_id))


def render_scenes(session: Session, camera: str, lidar: str, scenes: Sequence[PairData], T_camera_lidar: np.ndarray,
                  style: OverlayStyle) -> tuple[list[np.ndarray], list[Projection], ColourScale]:
    """The LiDAR's cloud drawn on each scene's image with ``T_camera_lidar`` (4x4, m): the one overlay the API,
    the studio and the stored results show (:func:`backend.core.overlay.render_overlays`, heights from the rig's
    root). Each image must have the size the camera's intrinsics are for (:class:`InputError` naming it)."""
    intrinsics = camera_intrinsics(session, camera)
    for scene in scenes:
        check_image_size(scene.image, intrinsics, scene.image_source)
    return render_overlays([(s.image, s.points, s.intensity) for s in scenes], T_camera_lidar, intrinsics, style,
                           session.rig.T_root_frame(lidar))


def overlay_files(loaded: Sequence[PairData], camera: CameraIntrinsics, T_before: np.ndarray,
                  T_after: np.ndarray) -> dict[str, bytes]:
    """``overlay_before.jpg`` and ``overlay_after.jpg``: mosaics of the last :data:`OVERLAY_PAIRS` pairs (the newest,
    as the studio tiles them) drawn with the initial and the solved ``T_camera_lidar``."""
    files = {}
    for name, T in (("overlay_before.jpg", T_before), ("overlay_after.jpg", T_after)):
        drawn = [render_overlay(p.image, p.points, p.intensity, T, camera)[0] for p in loaded[-OVERLAY_PAIRS:]]
        files[name] = encode_jpeg(mosaic(drawn, OVERLAY_WIDTH_PX))
    return files


def camera_intrinsics(session: Session, camera: str) -> CameraIntrinsics:
    """The camera's accepted intrinsics; :class:`InputError` when it is not a camera or has none yet."""
    check_camera(session, camera)
    intrinsics = session.rig.get(camera).intrinsics
    if intrinsics is None:
        raise InputError(f"{camera} has no intrinsics yet: calibrate and accept them first", camera)
    return intrinsics


def result_transform(session: Session, lidar: str, result_id: str) -> np.ndarray:
    """The ``T_camera_lidar`` (4x4, m) of a stored LiDAR-to-camera result of ``lidar`` (records stored before the
    results were :class:`~backend.core.result.TransformResult` ones included)."""
    return StoredResult(lidar_camera_record(session, lidar, result_id)).edges[0].T_parent_child


def solve_session(session: Session, camera: str, lidar: str, *, method: str = "target",
                  T_init: np.ndarray | None = None, image_ids: list[str] | None = None,
                  plate_margin_m: float | None = None, translation_prior_m: float | None = None,
                  cross_check: bool = False,
                  progress: ProgressCallback = no_progress) -> tuple[str, TransformResult]:
    """Solve ``T_camera_lidar`` from the session's stored pairs and keep the result (not yet accepted).

    ``T_init`` defaults to the rig's current transform (what was accepted or nudged so far). The record is the
    result's between ``camera`` (parent) and ``lidar`` (child), and before/after overlays are stored with it;
    the returned result is so named too. ``plate_margin_m`` is for the
    target method (:func:`target_settings`), ``translation_prior_m`` and ``cross_check`` for the targetless methods
    (:func:`edges_settings`, :func:`cross_check_methods`).
    """
    check_method(method, "method", cross_check)
    check_lidar(session, lidar)
    intrinsics = camera_intrinsics(session, camera)
    T_init = session.rig.T_a_b(camera, lidar) if T_init is None else T_init
    loaded = load_pairs(session, camera, lidar, image_ids)
    board = (session_plane_board(session, "the target method") if method == "target" else
             session_v_target(session) if method == "vtarget" else None)
    lens_result = session.accepted(f"{camera}/intrinsics")
    lens = None if lens_result is None else LensUncertainty.from_record(session.result(lens_result))
    result = solve_pairs(intrinsics, board, loaded, T_init, method=method, plate_margin_m=plate_margin_m,
                         translation_prior_m=translation_prior_m, cross_check=cross_check, lens=lens,
                         progress=lambda fraction, message: progress(0.9 * fraction, message))
    progress(0.95, "drawing the before/after overlays")
    files = overlay_files(loaded, intrinsics, np.asarray(T_init, float), result.T_parent_child)
    result = result.named(camera, lidar)
    result_id = session.add_result(lidar, result.to_record(), inputs=[p.name for p in loaded], files=files)
    return result_id, result
