"""OpenCV ``FileStorage`` YAML: the camera as OpenCV programs read it.

Written and read with :class:`cv2.FileStorage` only. Nodes:

- ``image_width``, ``image_height``: image size (px, integers);
- ``distortion_model``: the model name of ``../shared/conventions.md``;
- ``camera_matrix``: 3x3 ``!!opencv-matrix`` ``K`` (px);
- ``distortion_coefficients``: 1xN ``!!opencv-matrix`` (unitless), ``[k1, k2,
  p1, p2, k3]`` for ``pinhole-radtan``, ``[k1, k2, k3, k4]`` for
  ``fisheye-equidistant`` and ``[K1, K2, K3, P1, P2, A1, A2]`` (px units) for ``photogrammetric``, whose
  seven coefficients OpenCV's functions refuse rather than misread;
- any extras the caller passes, e.g. ``avg_reprojection_error`` (px).

OpenCV writes doubles with 17 significant digits, so values round-trip exactly.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from backend.core.camera import DIST_NAMES, CameraIntrinsics, CameraModelName
from backend.core.errors import InputError, shorten
from backend.core.finite import require_finite
from backend.exports.text_file import read_text

CAMERA_KEYS = ("image_width", "image_height", "distortion_model", "camera_matrix", "distortion_coefficients")
"""The nodes this module writes for the camera itself; extras may not reuse them."""

_MODEL_NAMES: dict[str, CameraModelName] = {
    "pinhole-radtan": "pinhole-radtan",
    "fisheye-equidistant": "fisheye-equidistant",
    "photogrammetric": "photogrammetric",
    "plumb_bob": "pinhole-radtan",
    "equidistant": "fisheye-equidistant",
}
"""Accepted ``distortion_model`` values: ours and the ROS names."""

_KEY_PATTERN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_EXPECTED_FILE = (
    "an OpenCV FileStorage file (starting with %YAML:1.0) with image_width, image_height, "
    "camera_matrix and distortion_coefficients"
)


def opencv_refusal(camera: CameraIntrinsics) -> str | None:
    """Why the OpenCV YAML cannot carry ``camera``'s model, or None when it can (every model but the splined one)."""
    if camera.spline is None:
        return None
    return ("the OpenCV YAML cannot carry the splined-stereographic model (its knots and field of view have no node); "
            "write the camera JSON (camera.json) or mrcal's .cameramodel instead")


def dump_opencv_yaml(camera: CameraIntrinsics, extra: dict[str, float | str] | None = None) -> str:
    """The camera as OpenCV FileStorage YAML text, with ``extra`` scalars appended.

    ``extra`` maps node names (letters, digits, ``_``) to numbers or strings, e.g.
    ``{"avg_reprojection_error": 0.21}``. Raises ``ValueError`` for an extra name
    that is not a valid node name or clashes with :data:`CAMERA_KEYS`, and if
    ``camera`` holds more distortion coefficients than its model has; :class:`InputError` for a NaN or infinity.
    """
    if (refusal := opencv_refusal(camera)) is not None:
        raise InputError(refusal, "model")
    expected = len(DIST_NAMES[camera.model])
    if camera.dist.size != expected:
        raise ValueError(f"{camera.model} has {expected} distortion coefficients, the camera holds {camera.dist.size}")
    require_finite({"camera_matrix": camera.K, "distortion_coefficients": camera.dist, "extra": extra},
                   "OpenCV YAML", "camera")
    extra = extra or {}
    for key in extra:
        if key in CAMERA_KEYS or not _KEY_PATTERN.fullmatch(key):
            raise ValueError(f"extra node name {key!r} must be letters, digits or '_' and not one of {CAMERA_KEYS}")
    storage = cv2.FileStorage("camera.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    storage.write("image_width", int(camera.width))
    storage.write("image_height", int(camera.height))
    # The model goes before the matrices, so a truncated file cannot lose it and
    # still hold complete matrices (a reader would then assume pinhole).
    storage.write("distortion_model", camera.model)
    storage.write("camera_matrix", np.ascontiguousarray(camera.K, dtype=np.float64))
    storage.write("distortion_coefficients", np.ascontiguousarray(camera.dist.reshape(1, -1), dtype=np.float64))
    for key, value in extra.items():
        storage.write(key, value if isinstance(value, str) else float(value))
    return storage.releaseAndGetString()


def write_opencv_yaml(path: Path, camera: CameraIntrinsics, extra: dict[str, float | str] | None = None) -> None:
    """Write :func:`dump_opencv_yaml` to ``path``."""
    Path(path).write_text(dump_opencv_yaml(camera, extra), encoding="utf-8")


def read_opencv_yaml(path: Path) -> CameraIntrinsics:
    """Read a camera from an OpenCV FileStorage file (YAML, or XML/JSON, by content).

    The model comes from ``distortion_model`` (ours or the ROS name); without it,
    from ``fisheye_model`` (as OpenCV's calibration sample writes), else OpenCV's
    default ``pinhole-radtan``. A pinhole camera may have 4 or 5 coefficients
    (``k3 = 0`` if absent), a fisheye exactly 4. Raises :class:`InputError` naming
    the file and the node for an unreadable file or a missing or malformed node.
    """
    path = Path(path)
    text = read_text(path, _EXPECTED_FILE)
    try:
        storage = cv2.FileStorage(text, cv2.FILE_STORAGE_READ | cv2.FILE_STORAGE_MEMORY)
    except (cv2.error, SystemError):
        # The Python binding reports OpenCV's parse error as a SystemError.
        storage = None
    if storage is None or not storage.isOpened() or not storage.root().isMap():
        raise InputError(
            f"{path}: OpenCV cannot parse the file; it may be truncated; expected {_EXPECTED_FILE}", str(path)
        )
    nodes = _Nodes(path, storage)
    width, height = nodes.size("image_width"), nodes.size("image_height")
    K = nodes.matrix("camera_matrix")
    if K.shape != (3, 3) or not (K[0, 0] > 0 and K[1, 1] > 0 and np.array_equal(K[2], [0.0, 0.0, 1.0])):
        expected = "a 3x3 [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0"
        raise nodes.error("camera_matrix", f"is {shorten(K.tolist())}", expected)
    model = nodes.model()
    dist = nodes.matrix("distortion_coefficients").ravel()
    counts = (4, 5) if model == "pinhole-radtan" else (len(DIST_NAMES[model]),)
    if dist.size not in counts:
        raise nodes.error(
            "distortion_coefficients",
            f"has {dist.size} values",
            f"{' or '.join(map(str, counts))} for {model}: [{', '.join(DIST_NAMES[model])}]",
        )
    return CameraIntrinsics(model, width, height, K, dist)


class _Nodes:
    """Typed, checked access to the nodes of one FileStorage document."""

    def __init__(self, path: Path, storage: cv2.FileStorage):
        self.path = path
        self.storage = storage

    def error(self, node: str, problem: str, expected: str) -> InputError:
        return InputError(f"{self.path}: node '{node}' {problem}; expected {expected}", str(self.path))

    def _get(self, node: str) -> cv2.FileNode | None:
        item = self.storage.getNode(node)
        return None if item.empty() or item.isNone() else item

    def size(self, node: str) -> int:
        item = self._get(node)
        if item is None:
            raise self.error(node, "is missing", "a positive integer (pixels)")
        if not item.isInt() or item.real() <= 0:
            raise self.error(node, "is not a positive integer", "a positive integer (pixels)")
        return int(item.real())

    def matrix(self, node: str) -> np.ndarray:
        expected = "an !!opencv-matrix with rows, cols, dt and rows*cols finite numbers in data"
        item = self._get(node)
        if item is None:
            raise self.error(node, "is missing", expected)
        try:
            value = item.mat()
        except cv2.error as exc:
            problem = f"is not a valid matrix (OpenCV: {exc.err}; the file may be truncated)"
            raise self.error(node, problem, expected) from None
        if value is None or value.size == 0:
            raise self.error(node, "is not an !!opencv-matrix", expected)
        value = np.asarray(value, dtype=np.float64)
        if not np.all(np.isfinite(value)):
            raise self.error(node, "holds non-finite values", expected)
        return value

    def model(self) -> CameraModelName:
        """The camera model: ``distortion_model``, else ``fisheye_model`` != 0, else pinhole."""
        item = self._get("distortion_model")
        if item is not None:
            name = item.string() if item.isString() else ""
            if name not in _MODEL_NAMES:
                raise self.error("distortion_model", f"is {shorten(name) if name else 'not a string'}",
                                 f"one of {sorted(_MODEL_NAMES)}")
            return _MODEL_NAMES[name]
        flag = self._get("fisheye_model")
        if flag is not None and flag.isInt() and flag.real() != 0:
            return "fisheye-equidistant"
        return "pinhole-radtan"
