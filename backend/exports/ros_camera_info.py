"""ROS camera_info YAML, as written and read by ``camera_calibration_parsers``.

This is the ``camera.yaml`` of ``../shared/conventions.md``: what ``intrinsics
--out`` writes and every ``--camera`` option reads. Keys, their order and layout
follow ``writeCalibrationYml`` in ros-perception/image_common
``camera_calibration_parsers/src/parse_yml.cpp``: ``image_width``,
``image_height``, ``camera_name``, ``camera_matrix``, ``distortion_model``,
``distortion_coefficients``, ``rectification_matrix``, ``projection_matrix``; each
matrix is a block map ``{rows, cols, data}`` with ``data`` a flow sequence in
row-major order. Pixel quantities (``K``, ``P``) are in pixels, the image size in
pixels, and the distortion coefficients are unitless.

Floats are written at full precision (Python ``repr``), so a camera survives a
write and read unchanged; ROS's own ``camera_calibration`` node writes its
``ost.yaml`` with 5-8 decimals instead.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np

from backend.core.camera import DIST_NAMES, ROS_DISTORTION_NAMES, SPLINED_HINT, CameraIntrinsics, CameraModelName
from backend.core.errors import InputError, shorten
from backend.core.finite import require_finite
from backend.exports.text_file import read_text, write_text
from backend.exports.yaml_fields import YamlFields, dump_yaml, parse_yaml

MODELS_BY_ROS_NAME: dict[str, CameraModelName] = {
    "plumb_bob": "pinhole-radtan",
    "equidistant": "fisheye-equidistant",
}
"""Our camera model for each ROS ``distortion_model`` we read."""

_EXPECTED_FILE = (
    "a ROS camera_info YAML mapping with image_width, image_height, camera_name, camera_matrix, "
    "distortion_model, distortion_coefficients, rectification_matrix and projection_matrix"
)


def projection_matrix(camera: CameraIntrinsics) -> np.ndarray:
    """The 3x4 projection matrix ``P`` (px) ROS ``camera_calibration`` stores for a monocular camera.

    Matches ``MonoCalibrator.set_alpha(0.0)`` in ros-perception/image_pipeline
    ``camera_calibration/calibrator.py``, which ``cal_fromcorners`` calls after
    every calibration:

    - pinhole (``plumb_bob``): ``P[:3, :3] = cv2.getOptimalNewCameraMatrix(K, D,
      (width, height), alpha)`` with ``alpha = 0`` (every pixel of the rectified
      image is valid), default ``newImgSize`` and ``centerPrincipalPoint=False``;
    - fisheye (``equidistant``): ``P[:3, :3] = K`` with ``fx`` and ``fy`` divided
      by ``1 + alpha``, i.e. ``K`` itself for ``alpha = 0`` (ROS notes that
      ``cv2.fisheye.estimateNewCameraMatrixForUndistortRectify`` gave poor results).

    The last column is zero: the rectified frame is the camera's optical frame.
    """
    P = np.zeros((3, 4))
    if camera.is_fisheye:
        P[:, :3] = camera.K
    else:
        P[:, :3], _ = cv2.getOptimalNewCameraMatrix(camera.K, camera.dist, camera.image_size, 0.0)
    return P


def dump_camera_info(camera: CameraIntrinsics, camera_name: str) -> str:
    """The camera as ROS camera_info YAML text.

    ``R`` is the identity (a monocular camera is not rectified against another)
    and ``P`` is :func:`projection_matrix`. Raises ``ValueError`` if ``camera``
    holds more distortion coefficients than its model has, and :class:`InputError` for a NaN or infinity or a
    model ROS has no name for (:func:`ros_refusal`).
    """
    refusal = ros_refusal(camera)
    if refusal is not None:
        raise InputError(refusal, "model")
    expected = len(DIST_NAMES[camera.model])
    if camera.dist.size != expected:
        raise ValueError(f"{camera.model} has {expected} distortion coefficients, the camera holds {camera.dist.size}")
    require_finite({"K": camera.K, "dist": camera.dist}, f"camera_info of {shorten(camera_name)}", camera_name)
    document = {
        "image_width": int(camera.width),
        "image_height": int(camera.height),
        "camera_name": str(camera_name),
        "camera_matrix": _matrix_node(camera.K),
        "distortion_model": ROS_DISTORTION_NAMES[camera.model],
        "distortion_coefficients": _matrix_node(camera.dist.reshape(1, -1)),
        "rectification_matrix": _matrix_node(np.eye(3)),
        "projection_matrix": _matrix_node(projection_matrix(camera)),
    }
    # default_flow_style=None puts only the all-scalar ``data`` lists in flow style,
    # which is exactly yaml-cpp's layout in parse_yml.cpp; an infinite width keeps
    # each list on one line.
    return dump_yaml(document)


def ros_refusal(camera: CameraIntrinsics) -> str | None:
    """Why camera_info cannot carry ``camera``'s model (naming it, and what to write instead), or None if it can."""
    if camera.model in ROS_DISTORTION_NAMES:
        return None
    return (f"camera_info cannot carry the {camera.model} model: ROS's distortion models here are "
            f"{' and '.join(ROS_DISTORTION_NAMES.values())}; write the camera JSON (camera.json)"
            f"{SPLINED_HINT if camera.spline else ' or the OpenCV YAML'}, or solve with pinhole-radtan")


def write_camera_info(path: Path, camera: CameraIntrinsics, camera_name: str) -> None:
    """Write :func:`dump_camera_info` to ``path`` atomically (:func:`write_text`), creating its folder as ROS's
    writer does."""
    write_text(path, dump_camera_info(camera, camera_name))


def load_camera_info(path: Path) -> tuple[CameraIntrinsics, str]:
    """Read a ROS camera_info YAML file: the camera and its ``camera_name``.

    Every field is checked and any problem raises :class:`InputError` whose
    message names the file and the field and says what was expected. As in ROS's
    reader, ``camera_name`` may be absent (giving ``"unknown"``) and so may
    ``distortion_model`` (giving ``plumb_bob``); ``rectification_matrix`` and
    ``projection_matrix`` must be well-formed but are not used, since the camera
    is defined by ``K`` and the distortion alone. Numbers written as YAML 1.2
    floats that YAML 1.1 reads as strings (``1e-05``) are accepted.
    """
    path = Path(path)
    text = read_text(path, _EXPECTED_FILE)
    document = parse_yaml(text, str(path), _EXPECTED_FILE)
    if not isinstance(document, dict):
        found = "empty" if document is None else f"a {type(document).__name__}"
        raise InputError(f"{path}: the document is {found}; expected {_EXPECTED_FILE}", str(path))

    fields = _Fields(path, document)
    width = fields.positive_int("image_width")
    height = fields.positive_int("image_height")
    camera_name = fields.name("camera_name")
    K = fields.matrix("camera_matrix", 3, 3)
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.array_equal(K[2], [0.0, 0.0, 1.0])):
        expected = "[fx, 0, cx, 0, fy, cy, 0, 0, 1] with fx, fy > 0"
        raise fields.error("camera_matrix.data", f"is {K.ravel().tolist()}", expected)
    model = fields.distortion_model("distortion_model")
    dist = fields.matrix("distortion_coefficients", None, None).ravel()
    names = DIST_NAMES[model]
    if dist.size != len(names):
        raise fields.error(
            "distortion_coefficients.data",
            f"has {dist.size} values",
            f"{len(names)} for {ROS_DISTORTION_NAMES[model]}: [{', '.join(names)}]",
        )
    fields.matrix("rectification_matrix", 3, 3)
    fields.matrix("projection_matrix", 3, 4)
    return CameraIntrinsics(model, width, height, K, dist), camera_name


def _matrix_node(M: np.ndarray) -> dict[str, Any]:
    """``{rows, cols, data}`` of a 2-D array, ``data`` row-major as Python floats."""
    return {"rows": int(M.shape[0]), "cols": int(M.shape[1]), "data": [float(v) for v in M.ravel()]}


class _Fields(YamlFields):
    """Typed, checked access to the fields of one camera_info document."""

    def __init__(self, path: Path, document: dict[str, Any]):
        super().__init__(str(path))
        self.document = document

    def positive_int(self, key: str) -> int:
        value = self.get(self.document, key, key, "a positive integer (pixels)")
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise self.error(key, f"is {shorten(value)}", "a positive integer (pixels)")
        return value

    def name(self, key: str) -> str:
        value = self.document.get(key, "unknown")
        if isinstance(value, bool) or not isinstance(value, str | int | float):
            raise self.error(key, f"is {shorten(value)}", "a camera name (a string)")
        return str(value)

    def distortion_model(self, key: str) -> CameraModelName:
        value = self.document.get(key, "plumb_bob")
        if value not in MODELS_BY_ROS_NAME:
            raise self.error(key, f"is {shorten(value)}, which is not supported",
                             f"one of {sorted(MODELS_BY_ROS_NAME)}")
        return MODELS_BY_ROS_NAME[value]

    def matrix(self, key: str, rows: int | None, cols: int | None) -> np.ndarray:
        """A ``{rows, cols, data}`` matrix; ``rows``/``cols`` of None accept any positive size."""
        shape = f"{rows if rows is not None else 'R'}x{cols if cols is not None else 'C'}"
        expected = f"a mapping {{rows, cols, data}} holding a {shape} matrix, data row-major"
        node = self.get(self.document, key, key, expected)
        if not isinstance(node, dict):
            raise self.error(key, f"is {shorten(node)}", expected)
        size: dict[str, int] = {}
        for part, want in (("rows", rows), ("cols", cols)):
            value = self.get(node, part, f"{key}.{part}", expected)
            wrong_size = want is not None and value != want
            if isinstance(value, bool) or not isinstance(value, int) or value <= 0 or wrong_size:
                raise self.error(f"{key}.{part}", f"is {shorten(value)}", str(want) if want else "a positive integer")
            size[part] = value
        count = size["rows"] * size["cols"]
        data = self.get(node, "data", f"{key}.data", f"a list of {count} numbers")
        if not isinstance(data, list) or len(data) != count:
            found = f"has {len(data)} values" if isinstance(data, list) else f"is {shorten(data)}"
            raise self.error(
                f"{key}.data", f"{found} but rows*cols = {size['rows']}*{size['cols']}", f"a list of {count} numbers"
            )
        numbers = [self.number(value, f"{key}.data[{i}]") for i, value in enumerate(data)]
        return np.array(numbers, dtype=float).reshape(size["rows"], size["cols"])
