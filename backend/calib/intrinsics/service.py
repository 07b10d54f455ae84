"""Intrinsics workflow shared by the API, the studio and the CLI.

capture or import images -> detect the board -> store captures -> solve -> store
the result -> accept it into the rig (:func:`backend.calib.rig.service.accept`, whose effect is
:func:`apply_intrinsics`). Routers and wizard steps call these functions and hold no logic of
their own.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from backend.calib._session import check_camera, require_kind, result_of, session_board
from backend.calib.board.detection import Detection
from backend.calib.intrinsics.models import solve_auto
from backend.calib.intrinsics.solver import IntrinsicsResult, IntrinsicsSettings, View
from backend.calib.test_field.detection import detect_target
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, no_progress
from backend.core.rig import Rig
from backend.core.targets import CameraTarget
from backend.core.test_field import SESSION_SURVEY
from backend.devices.image_folder import image_files
from backend.devices.image_io import decode_image_bytes, read_image
from backend.store.schema import CaptureRecord
from backend.store.session import Session

KIND = IntrinsicsResult.kind
WALL_VIEW_META = "wall_view"
"""``meta`` key of an image kept for the camera's pose in a test field, not for its lens
(:func:`backend.calib.test_field.service.resect_upload`)."""
OTHER_STEPS_META = ("paired_cloud", "multicam_set", WALL_VIEW_META)
"""``meta`` keys that mark a camera capture kept for another calibration: a LiDAR-camera pair's image
(:func:`backend.calib.lidar_camera.capture.store_pair`), a camera set's
(:func:`backend.calib.multicam.capture.capture_set`) and a test-field image kept for its pose
(:func:`backend.calib.test_field.service.resect_upload`). Such an image is not a view of the lens
(:func:`is_lens_view`)."""


@dataclass
class DetectedImage:
    name: str
    image: np.ndarray
    detection: Detection | None
    reason: str = ""
    """Why the target was not found (empty when it was)."""
    notes: list[str] = field(default_factory=list)
    """What was left out of the detection (a test field's markers not surveyed or seen twice)."""


@dataclass
class ImportReport:
    added: list[CaptureRecord] = field(default_factory=list)
    skipped: list[dict[str, str]] = field(default_factory=list)
    """``{"input": file name, "message": why}`` for images that were not stored."""
    notes: list[str] = field(default_factory=list)
    """What was left out of the stored images' detections (a test field's markers not surveyed or seen twice)."""


def detect_upload(image: np.ndarray, board: CameraTarget, name: str) -> DetectedImage:
    """:func:`~backend.calib.test_field.detection.detect_target` on an uploaded image; OpenCV failing on an odd image
    is an :class:`InputError` naming the file, not a server error."""
    try:
        return DetectedImage(name, image, *detect_target(image, board, name))
    except cv2.error as exc:
        reason = " ".join(str(exc.err or exc).split())[:200]
        raise InputError(f"{name}: the target search failed on this {image.shape[1]}x{image.shape[0]} px image "
                         f"(OpenCV: {reason}); expected an ordinary photo of the target", name) from None


def detect_uploads(files: list[tuple[str, bytes]], board: CameraTarget,
                   progress: ProgressCallback = no_progress) -> list[DetectedImage]:
    """Decode and detect every file; a corrupt or too large file raises :class:`InputError` naming it."""
    out = []
    for i, (name, data) in enumerate(files):
        progress(i / max(len(files), 1), f"detecting the target in {name}")
        out.append(detect_upload(decode_image_bytes(data, name, grayscale=False), board, name))
    return out


def check_size(session: Session, sensor: str, name: str, image: np.ndarray) -> None:
    camera = session.rig.get(sensor)
    if camera.kind != "camera":
        raise InputError(f"sensor {sensor!r} is a {camera.kind}, not a camera", "sensor")
    size = (image.shape[1], image.shape[0])
    previous = [c.image_size for c in session.captures(sensor, limit=1)]
    expected = tuple(previous[0]) if previous else None
    if expected and size != expected:
        raise InputError(f"{name} is {size[0]}x{size[1]} px but earlier captures of {sensor} are "
                         f"{expected[0]}x{expected[1]} px; all images of one camera must share one size", name)


def store_capture(session: Session, sensor: str, image: np.ndarray, detection: Detection | None, *,
                  device: str, timestamp_s: float, source: str | None = None,
                  meta: dict[str, Any] | None = None) -> CaptureRecord:
    """Keep one image (live or imported) with its board detection."""
    check_size(session, sensor, source or "image", image)
    return session.add_capture(sensor, image, {
        "timestamp_s": timestamp_s, "device": device, "source": source, "board": target_identity(session),
        "detection": None if detection is None else detection.to_dict(), "meta": meta or {},
    })


def import_images(session: Session, sensor: str, files: list[tuple[str, bytes]], *, skip_unusable: bool = False,
                  progress: ProgressCallback = no_progress) -> ImportReport:
    """Add uploaded images as captures. All-or-nothing unless ``skip_unusable``.

    Without ``skip_unusable`` any image without the board rejects the whole batch
    and the session stays as it was; with it, such images are reported and skipped.
    Corrupt files always reject the batch.
    """
    board = session_board(session)
    detected = detect_uploads(files, board, progress)
    report = ImportReport()
    missing = [d for d in detected if d.detection is None]
    if missing and not skip_unusable:
        others = f" (and {len(missing) - 1} more image(s) without it)" if len(missing) > 1 else ""
        raise InputError(missing[0].reason + others, missing[0].name)
    with session.lock:
        for d in detected:
            check_size(session, sensor, d.name, d.image)
            # also within the batch, so a camera's first upload cannot be half stored
            first = detected[0]
            if d.image.shape[:2] != first.image.shape[:2]:
                raise InputError(f"{d.name} is {d.image.shape[1]}x{d.image.shape[0]} px but {first.name} in the same "
                                 f"upload is {first.image.shape[1]}x{first.image.shape[0]} px; all images of one "
                                 "camera must share one size", d.name)
        for d in detected:
            if d.detection is None:
                report.skipped.append({"input": d.name, "message": d.reason})
                continue
            report.notes += d.notes
            report.added.append(store_capture(session, sensor, d.image, d.detection, device="upload",
                                              timestamp_s=0.0, source=Path(d.name).name))
    return report


def target_identity(session: Session) -> str | None:
    """What a capture's detection is made against, as its record keeps it (``board``): the session's board spec;
    for a test field followed by ``@`` and the first 12 hex digits of its survey's SHA-256, since a detection's ids
    index the survey's rows and a survey replaced under the same name makes earlier detections another target's."""
    if not (session.board or "").startswith("testfield:"):
        return session.board
    survey = session.path / SESSION_SURVEY
    return f"{session.board}@{hashlib.sha256(survey.read_bytes()).hexdigest()[:12] if survey.exists() else 'none'}"


def of_target(capture: CaptureRecord, target: str | None) -> bool:
    """Whether ``capture``'s detection was made against ``target`` (:func:`target_identity`). A test-field capture
    kept before its survey's digest was recorded counts as its spec's."""
    return capture.board in (target, (target or "").split("@")[0])


def is_lens_view(capture: CaptureRecord, target: str | None) -> bool:
    """Whether ``capture`` is a view of the session's current ``target`` (:func:`target_identity`) taken for the
    lens (live in step 3, imported or uploaded): it has a detection made against that target (a board changed
    since, or a survey replaced, makes it another target's) and is not kept for another calibration
    (:data:`OTHER_STEPS_META`). A pair's or a set's board stands metres away, small in the image: it adds little
    to the lens, and its corners' larger noise (per-view residuals 0.06-0.25 px RMS against 0.02-0.05 px for the
    demo's close views) would raise every projection sigma of the lens solve, whose noise is estimated from all
    residuals at once. As Kalibr and ROS keep one recording for the lens, the lens step counts its own views; a
    solve given ``capture_ids`` may still name any capture of the target."""
    return (capture.detection is not None and of_target(capture, target)
            and not any(key in capture.meta for key in OTHER_STEPS_META))


def other_target_views(captures: list[CaptureRecord], target: str | None) -> list[CaptureRecord]:
    """The lens views among ``captures`` of another target than ``target``, the session's now (a board changed
    since, a survey replaced): kept, not used, named in the solve's warnings."""
    return [c for c in captures if is_lens_view(c, c.board) and not of_target(c, target)]


def _targets_text(captures: list[CaptureRecord], board: str | None) -> str:
    """The targets ``captures`` were detected against, each once; the session's ``board`` with a survey replaced
    since is named so."""
    specs = dict.fromkeys((c.board or "an unknown target").split("@")[0] for c in captures)
    return ", ".join(f"{spec} (its survey replaced since)" if spec == board else spec for spec in specs)


def session_views(session: Session, sensor: str, capture_ids: list[str] | None = None
                  ) -> tuple[list[View], tuple, list[CaptureRecord]]:
    """The lens views (:func:`is_lens_view`) of one camera, or those of ``capture_ids`` (any capture with a
    detection) if given, its image size, and the lens views of another target left out
    (:func:`other_target_views`; none when ``capture_ids`` are given, which may not name such views)."""
    check_camera(session, sensor)
    captures = session.captures(sensor)
    unknown = sorted(set(capture_ids or ()) - {c.id for c in captures})
    if unknown:
        raise InputError(f"{sensor} has no capture {', '.join(map(repr, unknown[:5]))}"
                         f"{' (and more)' if len(unknown) > 5 else ''}", "capture_ids", status_code=404)
    if not captures:
        raise InputError(f"no captures for {sensor} yet; capture or import images of the board first", sensor)
    size = tuple(captures[0].image_size)
    target = target_identity(session)
    others = []
    if capture_ids is None:
        chosen = [c for c in captures if is_lens_view(c, target)]
        others = other_target_views(captures, target)
        if not chosen:
            elsewhere = f"; {len(others)} view(s) of another target: {_targets_text(others, session.board)}"
            raise InputError(f"no views of the board taken for {sensor}'s lens yet ({len(captures)} image(s) kept "
                             "as LiDAR-camera pairs or camera sets are not used for it" + (elsewhere if others else "")
                             + "); capture or import images of the board close to the camera first", sensor)
    else:
        chosen = [c for c in captures if c.id in capture_ids and c.detection]
        elsewhere = [c for c in chosen if not of_target(c, target)]
        if elsewhere:
            raise InputError(f"capture(s) {', '.join(c.id for c in elsewhere[:5])} of {sensor} show another target "
                             f"than the session's {session.board} ({_targets_text(elsewhere, session.board)}); set "
                             "that target as the board again to solve with them", "capture_ids")
    return [View(c.id, Detection.from_dict(c.detection)) for c in chosen], size, others


def solve_session(session: Session, sensor: str, settings: IntrinsicsSettings, capture_ids: list[str] | None = None,
                  progress: ProgressCallback = no_progress) -> tuple[str, IntrinsicsResult]:
    """Solve from the session's captures and store the result (not yet accepted)."""
    board = session_board(session)
    views, size, others = session_views(session, sensor, capture_ids)
    result = solve_auto(views, board, size, settings, progress)
    if others:
        result.warnings.append(f"{len(others)} earlier view(s) of {sensor} show another target "
                               f"({_targets_text(others, session.board)}); kept, not used")
    result_id = session.add_result(sensor, result.to_record(), inputs=[v.name for v in views])
    return result_id, result


def intrinsics_result(session: Session, sensor: str, result_id: str) -> dict[str, Any]:
    """The stored intrinsics result ``result_id`` of the camera ``sensor``; raises :class:`InputError`
    naming the result when it belongs to another sensor or is another kind."""
    return result_of(session, KIND, result_id, sensor)


def apply_intrinsics(rig: Rig, record: dict[str, Any]) -> None:
    """Write a stored intrinsics result into the rig's camera: the effect of accepting it
    (:func:`backend.calib.rig.service.accept`, slot ``"<camera>/intrinsics"``)."""
    require_kind(record, KIND)
    rig.get(record["sensor"]).intrinsics = CameraIntrinsics.from_dict(record["camera"])


def solve_files(images_dir: Path, board: CameraTarget, settings: IntrinsicsSettings,
                progress: ProgressCallback = no_progress) -> tuple[IntrinsicsResult, list[dict[str, str]]]:
    """The CLI's path: every image in a folder, no session; the target a board or a wall test field. Returns the
    result (its warnings name any test-field markers left out) and the skipped images."""
    files = image_files(images_dir)
    views, skipped, notes, size = [], [], [], None
    for i, path in enumerate(files):
        progress(0.5 * i / len(files), f"detecting the target in {path.name}")
        image = read_image(path, grayscale=True)
        if size is None:
            size = (image.shape[1], image.shape[0])
        detection, reason, left_out = detect_target(image, board, path.name)
        notes += left_out
        if detection is None:
            skipped.append({"input": path.name, "message": reason})
        else:
            views.append(View(path.name, detection))
    if skipped and (len(views) < 3 or len(skipped) > len(files) / 2):
        names = ", ".join(s["input"] for s in skipped[:5]) + (", ..." if len(skipped) > 5 else "")
        raise InputError(f"only {len(views)} of {len(files)} images show the target {board} (none in {names}: "
                         f"{skipped[0]['message']})", skipped[0]["input"])

    def solve_progress(fraction: float, message: str) -> None:
        progress(0.5 + 0.5 * fraction, message)

    result = solve_auto(views, board, size, settings, solve_progress)
    result.warnings[:0] = notes
    return result, skipped
