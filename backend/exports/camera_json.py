"""The camera JSON file: the conventions' camera object, for the models ROS's camera_info cannot carry.

``{"camera_name", "model", "width", "height", "K", "dist"}`` with ``K`` nested row-major (px) and ``dist`` in the
model's order (``../shared/conventions.md``), optionally with the solve's ``std`` and, for the photogrammetric model,
its report (parameters in px and mm, correlations). ``intrinsics --out camera.json`` writes it and every
``--camera`` option reads it beside ``camera.yaml`` (:func:`load_camera`): the suffix picks the format.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from backend.core.camera import CAMERA_MODELS, DIST_NAMES, CameraIntrinsics
from backend.core.errors import InputError, shorten
from backend.core.finite import require_finite
from backend.core.splined import SplineGrid
from backend.exports.mrcal_cameramodel import load_mrcal_cameramodel
from backend.exports.ros_camera_info import load_camera_info
from backend.exports.text_file import read_text

_EXPECTED_FILE = "a camera JSON object with model, width, height, K (3x3, px) and dist (the model's coefficients)"


def dump_camera_json(camera: CameraIntrinsics, camera_name: str, extra: dict[str, Any] | None = None) -> str:
    """The camera as camera JSON text, with ``extra`` keys (``std``, ``board_flex``, ``photogrammetric``) after the
    camera's own."""
    require_finite({"K": camera.K, "dist": camera.dist}, f"camera JSON of {shorten(camera_name)}", camera_name)
    return json.dumps({"camera_name": camera_name, **camera.to_dict(), **(extra or {})}, indent=2) + "\n"


def load_camera(path: Path) -> tuple[CameraIntrinsics, str]:
    """A camera file by its suffix: ``.json`` is :func:`load_camera_json`, ``.cameramodel`` mrcal's
    (:func:`~backend.exports.mrcal_cameramodel.load_mrcal_cameramodel`, named by its file), anything else ROS
    camera_info YAML."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".cameramodel":
        return load_mrcal_cameramodel(path), path.stem
    return load_camera_json(path) if suffix == ".json" else load_camera_info(path)


def load_camera_json(path: Path) -> tuple[CameraIntrinsics, str]:
    """The camera and its ``camera_name`` (``"unknown"`` if absent) from a camera JSON file.

    Every field is checked: problems raise :class:`InputError` naming the file and the field and saying what was
    expected.
    """
    path = Path(path)
    try:
        document = json.loads(read_text(path, _EXPECTED_FILE))
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not JSON ({exc.msg} at line {exc.lineno}); expected {_EXPECTED_FILE}",
                         str(path)) from None
    if not isinstance(document, dict):
        raise InputError(f"{path}: the document is a {type(document).__name__}; expected {_EXPECTED_FILE}", str(path))

    def error(field: str, problem: str, expected: str) -> InputError:
        return InputError(f"{path}: field '{field}' {problem}; expected {expected}", str(path))

    model = document.get("model")
    if model not in CAMERA_MODELS:
        raise error("model", f"is {shorten(model)}", f"one of {list(CAMERA_MODELS)}")
    size = {}
    for key in ("width", "height"):
        value = document.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise error(key, "is missing" if key not in document else f"is {shorten(value)}",
                        "a positive integer (pixels)")
        size[key] = value
    K = _numbers(document.get("K"), (3, 3))
    if K is None or not (K[0, 0] > 0 and K[1, 1] > 0 and np.array_equal(K[2], [0.0, 0.0, 1.0])):
        raise error("K", f"is {shorten(document.get('K'))}", "[[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0")
    spline = _spline(document.get("spline"), error) if model == "splined-stereographic" else None
    names = DIST_NAMES[model] if spline is None else ["the control points"]
    count = len(names) if spline is None else spline.n_control
    dist = _numbers(document.get("dist"), (count,))
    if dist is None:
        raise error("dist", f"is {shorten(document.get('dist'))}", f"{count} numbers for {model}: "
                    f"[{', '.join(names)}]")
    name = document.get("camera_name", "unknown")
    if not isinstance(name, str):
        raise error("camera_name", f"is {shorten(name)}", "a string")
    return CameraIntrinsics(model, size["width"], size["height"], K, dist, spline), name


def _spline(value: Any, error) -> SplineGrid:
    """The splined model's ``spline`` object (``nx``, ``ny``: 4 or more knots; ``fov_x_deg``: 0 to 360), or
    ``error``'s :class:`InputError`."""
    expected = "an object with nx and ny (knots, 4 or more) and fov_x_deg (0 to 360 deg)"
    if not isinstance(value, dict):
        raise error("spline", "is missing" if value is None else f"is {shorten(value)}", expected)
    nx, ny, fov = value.get("nx"), value.get("ny"), value.get("fov_x_deg")
    if not (all(isinstance(k, int) and not isinstance(k, bool) and k >= 4 for k in (nx, ny))
            and isinstance(fov, int | float) and not isinstance(fov, bool) and 0 < fov < 360):
        raise error("spline", f"is {shorten(value)}", expected)
    return SplineGrid(nx, ny, float(fov))


def _numbers(value: Any, shape: tuple[int, ...]) -> np.ndarray | None:
    """``value`` as a finite float array of ``shape``, or None if it is not one."""
    try:
        array = np.array(value, dtype=float)
    except (TypeError, ValueError):
        return None
    if array.shape != shape or not np.all(np.isfinite(array)):
        return None
    return array
