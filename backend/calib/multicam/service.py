"""Multi-camera calibration as the studio, the API and the CLI run it.

Two sources of board views seen together:

* a session's synchronised sets (:mod:`backend.calib.multicam.capture`): a frame is a set;
* folders of images, one per camera (the CLI): a frame is the number in a file name
  (``left07.png`` and ``cam_b_0007.jpg`` are both frame 7).

A camera with intrinsics (accepted in its own step, or a ``camera.yaml``) keeps them
unless asked to refine; a camera without any is first calibrated from its own views
and then refined with the rig. Results are kept under the reference camera (the first
named) with kind ``multicam``: ``"transforms": {CAMERA: TransformResult record}`` (parent the
reference) beside every camera's intrinsics. The rig service (:mod:`backend.calib.rig.service`)
accepts one as an edge per camera and calls :func:`apply_refined_intrinsics` for the lenses
refined with the rig.

The stereo check of a result (:func:`stereo_check`: epipolar error, rectification, row offsets
and a rectified preview of one pair on one set) is here too, so the studio and the API make it alike.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from backend.calib._session import check_camera, require_kind, result_of, session_plane_board
from backend.calib.board.detection import Detection, common_corners, detect_board
from backend.calib.intrinsics.solver import IntrinsicsSettings, View, calibrate_intrinsics
from backend.calib.lidar_camera.capture import check_image_size
from backend.calib.multicam.bundle import MulticamResult, MulticamSettings, calibrate_multicam
from backend.calib.multicam.capture import MulticamSet, stored_sets
from backend.calib.multicam.graph import Observation
from backend.calib.multicam.stereo import LINE_COLOUR_BGR as LINE_COLOUR_BGR  # re-exported for previews
from backend.calib.multicam.stereo import (
    Rectification,
    epipolar_errors,
    rectified_preview,
    rectified_row_errors,
    rectify,
)
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, no_progress
from backend.core.rig import Frame, Rig
from backend.core.transforms import invert
from backend.devices.image_folder import image_files
from backend.devices.image_io import read_image
from backend.exports.camera_json import load_camera
from backend.store.session import Session

KIND = "multicam"
FRAME_NUMBER = re.compile(r"(\d+)(?!.*\d)")
"""The last run of digits in a file's stem: its frame number."""


@dataclass
class StartingCameras:
    """Each camera's intrinsics to start from, and which of them the solve refines."""

    cameras: dict[str, CameraIntrinsics]
    estimate: list[str]


def slot(cameras: Sequence[str]) -> str:
    """The acceptance slot of a set of cameras, whatever their order."""
    return f"{KIND}:{'+'.join(sorted(cameras))}"


def check_cameras(names: Sequence[str]) -> list[str]:
    """At least two distinct camera names, in the order given."""
    names = list(names)
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise InputError(f"camera {duplicates[0]} is named twice", duplicates[0])
    if len(names) < 2:
        raise InputError(f"a multi-camera calibration needs at least two cameras, got {names}", "cameras")
    return names


def _calibrated_from_views(name: str, views: list[View], board: BoardSpec, size: tuple[int, int],
                           progress: ProgressCallback) -> CameraIntrinsics:
    """A camera without intrinsics, calibrated from its own board views (refined later with the rig)."""
    if len(views) < 3:
        raise InputError(f"camera {name} has no intrinsics and only {len(views)} board views to calibrate them "
                         f"from; calibrate it in its own step or give at least 3 views", name)
    # Only the camera is kept (the rig solve refines it): no jackknife, no two-halves cross-validation.
    settings = IntrinsicsSettings(jackknife=False, cross_validate=False)
    return calibrate_intrinsics(views, board, size, settings, progress).camera


def starting_cameras(known: dict[str, CameraIntrinsics | None], observations: list[Observation], board: BoardSpec,
                     sizes: dict[str, tuple[int, int]], refine: bool, progress: ProgressCallback = no_progress
                     ) -> StartingCameras:
    """Intrinsics for every camera: the known ones, and a calibration from its own views for the others
    (which the rig solve then refines, as it does all of them with ``refine``)."""
    cameras, estimate = {}, []
    for name, camera in known.items():
        if camera is not None and not camera.is_opencv:
            raise InputError(f"{name}'s intrinsics are in the {camera.model} model, which the rig's bundle adjustment "
                             "does not solve (it takes pinhole-radtan and fisheye-equidistant); calibrate "
                             f"{name} with one of those for the multi-camera solve", name)
        if camera is None:
            views = [View(o.frame, o.detection) for o in observations if o.camera == name]
            progress(0.0, f"calibrating {name}'s intrinsics from its {len(views)} views")
            camera = _calibrated_from_views(name, views, board, sizes[name], no_progress)
            estimate.append(name)
        elif refine:
            estimate.append(name)
        cameras[name] = camera
    return StartingCameras(cameras, estimate)


def result_rig(result: MulticamResult) -> Rig:
    """The result as a rig rooted at the reference camera: each camera's ``T_ref_cam`` with its covariance."""
    rig = Rig(root=result.reference)
    rig.get(result.reference).kind, rig.get(result.reference).intrinsics = "camera", result.cameras[result.reference]
    for name, transform in result.transforms.items():
        covariance = transform.covariance if np.isfinite(transform.covariance).all() else None
        rig.add(Frame(name, result.reference, transform.T_parent_child, kind="camera",
                      intrinsics=result.cameras[name], covariance=covariance))
    return rig


# --------------------------------------------------------------------------------------------
# Sessions


def session_observations(session: Session, cameras: list[str], set_names: list[str] | None = None
                         ) -> tuple[list[Observation], list[str]]:
    """Every stored board view of ``cameras`` in the session's sets (or the sets named), and the sets used."""
    sets = stored_sets(session, cameras)
    if set_names is not None:
        unknown = sorted(set(set_names) - {s.name for s in sets})
        if unknown:
            raise InputError(f"no set {unknown[0]} of {', '.join(cameras)} in session {session.name}", unknown[0])
        sets = [s for s in sets if s.name in set(set_names)]
    observations = [Observation(camera, s.name, Detection.from_dict(capture.detection))
                    for s in sets for camera, capture in s.captures.items() if capture.detection]
    if not sets:
        raise InputError(f"session {session.name} holds no synchronised sets of {', '.join(cameras)}; capture "
                         f"sets with the board in view of at least two cameras first", "cameras")
    return observations, [s.name for s in sets]


def solve_session(session: Session, cameras: list[str], *, refine_intrinsics: bool = False,
                  set_names: list[str] | None = None, progress: ProgressCallback = no_progress
                  ) -> tuple[str, MulticamResult]:
    """Solve the rig of ``cameras`` (the first is the reference) from the session's sets; keep the result."""
    cameras = check_cameras(cameras)
    for name in cameras:
        check_camera(session, name)
    board = session_plane_board(session, "the multi-camera rig")
    observations, used = session_observations(session, cameras, set_names)
    sizes = {}
    for obs in observations:
        sizes.setdefault(obs.camera, tuple(obs.detection.image_size))
    start = starting_cameras({n: session.rig.get(n).intrinsics for n in cameras}, observations, board, sizes,
                             refine_intrinsics, progress)
    result = calibrate_multicam(start.cameras, board, observations, MulticamSettings(start.estimate), progress)
    record = result.to_record() | {"camera_order": cameras}
    return session.add_result(cameras[0], record, inputs=used), result


def apply_refined_intrinsics(rig: Rig, record: dict[str, Any]) -> None:
    """Give the cameras whose intrinsics a multicam result refined (``settings.estimate_intrinsics``) those
    intrinsics; the rig service calls it when it accepts the result (the poses are its edges)."""
    require_kind(record, KIND)
    for name in record["settings"]["estimate_intrinsics"]:
        rig.get(name).intrinsics = CameraIntrinsics.from_dict(record["cameras"][name])


def record_T_ref_cam(record: dict[str, Any]) -> dict[str, np.ndarray]:
    """Every camera's ``T_ref_cam`` (4x4, m) of a stored result, the reference's identity included (a record stored
    before the per-camera transforms holds them under ``T_ref_cam``)."""
    reference = record["reference"]
    if "transforms" not in record:
        return {name: np.array(T, dtype=float) for name, T in record["T_ref_cam"].items()}
    return {name: np.eye(4) if name == reference else np.array(record["transforms"][name]["T_parent_child"])
            for name in record["cameras"]}


# --------------------------------------------------------------------------------------------
# The stereo check of one pair


@dataclass
class StereoCheck:
    """One pair of a multicam result on one of its sets: how well the solved rig and lenses explain the corners
    both cameras saw (``left`` is the first camera of the pair, ``right`` the second)."""

    result_id: str
    set_name: str
    left: str
    right: str
    corners: int
    """Corners seen by both cameras in the set."""
    epipolar_rms_px: float
    epipolar_max_px: float
    """Distance (px) of each right corner from the epipolar line of its left corner, under the solved rig."""
    rectification: Rectification | None
    """None when the pair cannot be rectified together (``no_preview`` says why)."""
    row_offset_rms_px: float | None
    """RMS (px) of the corners' offset across the rectified images (rows, or columns for a vertical pair)."""
    preview_bgr: np.ndarray | None
    """Both rectified images side by side (or stacked) with lines every ``line_spacing_px`` (BGR)."""
    no_preview: str | None = None

    def to_dict(self) -> dict[str, Any]:
        """The JSON form (without the images): numbers in px and m."""
        rect = self.rectification
        return {"result_id": self.result_id, "set": self.set_name, "left": self.left, "right": self.right,
                "corners": self.corners, "epipolar_rms_px": self.epipolar_rms_px,
                "epipolar_max_px": self.epipolar_max_px, "row_offset_rms_px": self.row_offset_rms_px,
                "vertical": None if rect is None else rect.vertical,
                "baseline_m": None if rect is None else rect.baseline_m, "no_preview": self.no_preview}


def _result_pair(record: dict[str, Any], left: str, right: str) -> None:
    """Refuse a pair that is not two cameras of the result that saw the board together."""
    for name in (left, right):
        if name not in record["cameras"]:
            raise InputError(f"camera {name} is not in result {record['id']} (cameras "
                             f"{', '.join(record['cameras'])})", name)
    if not any({p["a"], p["b"]} == {left, right} for p in record.get("pairs", [])):
        raise InputError(f"cameras {left} and {right} never saw the board together in result {record['id']}", right)


def stereo_sets(session: Session, record: dict[str, Any], left: str, right: str) -> dict[str, MulticamSet]:
    """The result's sets (those it used) in which both cameras of the pair saw the board, by name."""
    _result_pair(record, left, right)
    used = set(record["T_ref_board"])
    return {s.name: s for s in stored_sets(session, [left, right])
            if s.name in used and {left, right} <= set(s.cameras_with_board)}


def stereo_check(session: Session, result_id: str, left: str, right: str, set_name: str,
                 line_spacing_px: int = 64) -> StereoCheck:
    """The stereo check of cameras ``left`` and ``right`` of a stored multicam result on its set ``set_name``.

    The epipolar errors need only the rig and the lenses; the rectification also needs both cameras to share
    one model and image size, and 8-bit images (else ``no_preview`` says why and only the errors are given)."""
    record = result_of(session, KIND, result_id)
    found = stereo_sets(session, record, left, right).get(set_name)
    if found is None:
        raise InputError(f"set {set_name} is not one of result {result_id}'s sets in which {left} and {right} both "
                         "saw the board", set_name)
    cameras = {n: CameraIntrinsics.from_dict(record["cameras"][n]) for n in (left, right)}
    T_ref_cam = record_T_ref_cam(record)
    T_left_right = invert(T_ref_cam[left]) @ T_ref_cam[right]
    left_px, right_px = common_corners(*(Detection.from_dict(found.captures[n].detection) for n in (left, right)))
    errors = epipolar_errors(cameras[left], cameras[right], T_left_right, left_px, right_px)
    check = StereoCheck(result_id, set_name, left, right, len(left_px), _rms(errors), float(errors.max(initial=0.0)),
                        None, None, None)
    try:
        rect = rectify(cameras[left], cameras[right], T_left_right)
        images = [session.capture_image(n, found.captures[n].id) for n in (left, right)]
        check.preview_bgr = rectified_preview(rect, *images, line_spacing_px)
    except InputError as exc:
        check.no_preview = exc.message
        return check
    check.rectification = rect
    check.row_offset_rms_px = _rms(rectified_row_errors(rect, left_px, right_px))
    return check


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else 0.0


# --------------------------------------------------------------------------------------------
# Folders (the CLI)


def frame_number(path: Path) -> int:
    """The frame number in a file name (its last run of digits), or an error naming the file."""
    match = FRAME_NUMBER.search(path.stem)
    if match is None:
        raise InputError(f"{path.name} has no frame number in its name; frames are matched across cameras by the "
                         f"number in their file names (e.g. left07.png and right07.png)", str(path))
    return int(match.group(1))


def _folder_images(camera: str, folder: Path) -> dict[str, Path]:
    """Frame name -> image of one camera's folder; refuses a missing or empty folder and repeated numbers."""
    files = image_files(folder, f"{folder} (camera {camera})")
    frames: dict[str, Path] = {}
    for path in files:
        name = f"{frame_number(path):06d}"
        if name in frames:
            raise InputError(f"{path.name} and {frames[name].name} of camera {camera} have the same frame number "
                             f"{int(name)}", str(path))
        frames[name] = path
    return frames


def _detect(camera: str, path: Path, board: BoardSpec, expected: CameraIntrinsics | None
            ) -> tuple[tuple[int, int], Detection | None]:
    image = read_image(path, grayscale=True)
    if expected is not None:
        check_image_size(image, expected, str(path))
    return (image.shape[1], image.shape[0]), detect_board(image, board)


def folder_observations(folders: dict[str, Path], board: BoardSpec, known: dict[str, CameraIntrinsics | None],
                        progress: ProgressCallback = no_progress
                        ) -> tuple[list[Observation], dict[str, tuple[int, int]], list[str]]:
    """Board views of every camera's folder, each image's size, and warnings about frames some cameras lack.

    Refuses a camera whose images disagree in size, or in which the board is never found."""
    images = {camera: _folder_images(camera, folder) for camera, folder in folders.items()}
    jobs = [(camera, frame, path) for camera, frames in images.items() for frame, path in frames.items()]
    with ThreadPoolExecutor(max_workers=2) as pool:  # OpenCV releases the GIL while detecting
        found = []
        for i, detected in enumerate(pool.map(lambda job: _detect(job[0], job[2], board, known[job[0]]), jobs)):
            progress(i / len(jobs), f"detecting the board in {jobs[i][2].name}")
            found.append(detected)
    observations, sizes = [], {}
    for (camera, frame, path), (size, detection) in zip(jobs, found, strict=True):
        if sizes.setdefault(camera, size) != size:
            raise InputError(f"{path.name} is {size[0]}x{size[1]} px but camera {camera}'s other images are "
                             f"{sizes[camera][0]}x{sizes[camera][1]}", str(path))
        if detection is not None:
            observations.append(Observation(camera, frame, detection))
    for camera, frames in images.items():
        if not any(o.camera == camera for o in observations):
            raise InputError(f"the board {board} was not found in any of camera {camera}'s {len(frames)} images in "
                             f"{folders[camera]}; check the board spec (inner corners for checkerboards, squares "
                             f"for ChArUco)", camera)
    every = set().union(*(frames.keys() for frames in images.values()))
    warnings = []
    for camera, frames in images.items():
        if every - frames.keys():
            missing = ", ".join(str(int(f)) for f in sorted(every - frames.keys()))
            warnings.append(f"camera {camera} has no image for frames {missing}; those frames relate the others only")
    return observations, sizes, warnings


def parse_named(values: Sequence[str], what: str) -> dict[str, Path]:
    """``NAME=PATH`` arguments in order; refuses a value without ``=`` or a name given twice."""
    named: dict[str, Path] = {}
    for value in values:
        name, sep, path = value.partition("=")
        if not sep or not name or not path:
            raise InputError(f"expected NAME={what}, got {value!r}", value)
        if name in named:
            raise InputError(f"camera {name} is given twice", name)
        named[name] = Path(path)
    return named


def solve_files(folders: dict[str, Path], board: BoardSpec, intrinsics_files: dict[str, Path], *,
                  refine_intrinsics: bool = False, progress: ProgressCallback = no_progress
                  ) -> tuple[MulticamResult, list[str]]:
    """The CLI's path: calibrate the rig of ``folders`` (camera -> images, the first the reference) with the
    intrinsics of ``intrinsics_files`` (camera -> ROS camera_info YAML) where given. Returns the result and
    warnings about frames some cameras lack."""
    check_cameras(list(folders))
    unknown = sorted(set(intrinsics_files) - set(folders))
    if unknown:
        raise InputError(f"--intrinsics names camera {unknown[0]}, which has no --camera folder", unknown[0])
    known = {name: load_camera(intrinsics_files[name])[0] if name in intrinsics_files else None
             for name in folders}
    observations, sizes, warnings = folder_observations(folders, board, known,
                                                        lambda f, m: progress(0.4 * f, m))
    start = starting_cameras(known, observations, board, sizes, refine_intrinsics,
                             lambda f, m: progress(0.4, m))
    result = calibrate_multicam(start.cameras, board, observations, MulticamSettings(start.estimate),
                                lambda f, m: progress(0.45 + 0.55 * f, m))
    return result, warnings + result.warnings
