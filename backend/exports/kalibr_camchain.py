"""A camera rig as Kalibr's ``camchain.yaml`` (what ``kalibr_calibrate_cameras`` writes), or with an IMU as its
``camchain-imucam.yaml`` (what ``kalibr_calibrate_imu_camera`` writes, and visual-inertial stacks read).

Layout (one ``camN`` mapping per camera, ``cam0`` first, in the rig's order)::

    cam0:
      cam_overlaps: [1, 2]
      camera_model: pinhole
      distortion_coeffs: [k1, k2, r1, r2]      # radtan; equidistant: [k1, k2, k3, k4]
      distortion_model: radtan                 # or equidistant
      intrinsics: [fu, fv, pu, pv]             # px
      resolution: [width, height]              # px
      rostopic: /cam_front/image_raw
      T_cam_imu: [...]                         # camchain-imucam only: 4x4, maps IMU points into cam0
      timeshift_cam_imu: 0.0                   # camchain-imucam only: s, t_imu = t_cam + timeshift
    cam1:
      T_cn_cnm1:                               # 4x4, rows, translation in metres
      - [r11, r12, r13, tx]
      - [r21, r22, r23, ty]
      - [r31, r32, r33, tz]
      - [0.0, 0.0, 0.0, 1.0]
      cam_overlaps: [0, 2]
      ...

Fields and their checks follow ethz-asl/kalibr
``aslam_offline_calibration/kalibr/python/kalibr_common/ConfigReader.py``
(``CameraParameters``, ``CameraChainParameters``); within a camera the keys are
in the alphabetical order Kalibr's own writer (``yaml.dump``) produces. Kalibr
does not read ``camN`` keys in file order but by name, so cam0, cam1, ... must
be contiguous.

Frames: every camera frame is an optical frame (x right, y down, z forward).
``T_cn_cnm1`` of ``camN`` (N >= 1) is ``T_{camN, camN-1}`` in the ``T_a_b`` sense
of ``../shared/conventions.md``: it maps points in camera N-1 into camera N
(Kalibr's wiki: "cam1: T_cn_cnm1 = T_c1_c0, takes cam0 to cam1 coordinates";
``plotCameraRig`` in ``kalibr_camera_calibration/CameraUtils.py`` chains
``T_c0_cn = T_c0_cnm1 @ inv(T_cn_cnm1)``). From our ``T_ref_cam`` (maps points
in a camera into the reference camera) it is ``inv(T_ref_cam[N]) @
T_ref_cam[N-1]``; reading the chain back gives ``T_ref_cam`` relative to cam0.

Models: our ``pinhole-radtan`` is Kalibr ``pinhole`` + ``radtan`` and our
``fisheye-equidistant`` is Kalibr ``pinhole`` + ``equidistant`` (``pinhole-equi``
on Kalibr's command line): aslam_cv's ``RadialTangentialDistortion`` and
``EquidistantDistortion`` are OpenCV's formulas with the same coefficients.
Kalibr's radtan has no ``k3`` and no skew: a camera whose ``k3`` moves the
farthest image corner by more than :data:`K3_TOLERANCE_PX`, or whose ``K`` has a
skew term, is refused with :class:`InputError` naming the camera (recalibrate it
with ``k3`` fixed at 0, the intrinsics solver's default) rather than exported as
a different camera. Read back, radtan gives ``k3 = 0``; Kalibr's ``none``
distortion is read as ``pinhole-radtan`` with zero coefficients.

Floats are written at full precision (Python ``repr``); intrinsics are always
written as floats and the resolution as integers, as Kalibr's reader checks.
``T_cam_imu`` (Kalibr's "imu0 to cam0": the ``T_a_b`` of the conventions,
mapping points in the IMU's frame into the camera's) and ``timeshift_cam_imu``
(Kalibr's ``t_imu = t_cam + shift``, s) are written for each camera when an IMU
is given. They, and any other key of a camera, are ignored on load;
``cam_overlaps`` is checked but not returned.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from backend.core.camera import DIST_NAMES, SPLINED_HINT, CameraIntrinsics, CameraModelName
from backend.core.errors import InputError, shorten
from backend.core.finite import require_finite
from backend.core.transforms import invert
from backend.exports.text_file import read_text
from backend.exports.yaml_fields import YamlFields, dump_yaml, floats, parse_yaml

K3_TOLERANCE_PX = 1e-3
"""Largest shift (px) ``k3`` may cause at the farthest image corner for a camera to be written as Kalibr radtan."""
_RIGID_TOLERANCE = 1e-6
"""How far ``R^T R`` may be from the identity, and the last row from ``[0, 0, 0, 1]``, in a ``T_cn_cnm1``."""
DISTORTION_MODELS: dict[CameraModelName, str] = {"pinhole-radtan": "radtan", "fisheye-equidistant": "equidistant"}
"""Kalibr's ``distortion_model`` for each of our camera models (``camera_model`` is always ``pinhole``)."""
_MODELS_BY_KALIBR_NAME: dict[str, CameraModelName] = {
    "radtan": "pinhole-radtan",
    "none": "pinhole-radtan",
    "equidistant": "fisheye-equidistant",
}
_COEFF_COUNTS = {"radtan": 4, "none": 0, "equidistant": 4}
_NAME = re.compile(r"^[A-Za-z0-9_-]+$")
_EXPECTED_FILE = "a Kalibr camchain YAML mapping cam0, cam1, ... to cameras"


def default_topic(name: str) -> str:
    """The ``rostopic`` written for camera ``name`` when none is given: ``/<name>/image_raw``."""
    return f"/{name}/image_raw"


def dump_kalibr_camchain(
    cameras: Sequence[tuple[str, CameraIntrinsics]],
    T_ref_cam: Mapping[str, np.ndarray],
    topics: Mapping[str, str] | None = None,
    overlaps: Mapping[str, Sequence[str]] | None = None,
    imu: tuple[Mapping[str, np.ndarray], Mapping[str, float]] | None = None,
) -> str:
    """Kalibr camchain YAML text of ``cameras`` (cam0, cam1, ... in the given order).

    ``T_ref_cam[name]`` (4x4, metres) maps points in camera ``name``'s optical
    frame into a common reference frame (usually the first camera's); only the
    relative poses are written, as ``T_cn_cnm1 = inv(T_ref_cam[N]) @
    T_ref_cam[N-1]``. ``topics`` gives the ``rostopic`` per name (default
    :func:`default_topic`); ``overlaps`` the names each camera shares views with
    (default: every other camera). ``imu`` is ``(T_cam_imu, timeshift_cam_imu)`` by camera name (4x4 in m; s):
    a camchain-imucam. Raises :class:`InputError` naming the camera
    for a repeated name, a missing or non-rigid ``T_ref_cam``, a NaN or infinity in ``K`` or the
    distortion, a skewed ``K`` or a
    ``k3`` Kalibr's radtan cannot hold (see :data:`K3_TOLERANCE_PX`), and
    ``ValueError`` if a camera holds more coefficients than its model has.
    """
    names = [name for name, _ in cameras]
    if not names:
        raise InputError("a Kalibr camchain needs at least one camera", "cameras")
    index = {}
    for i, name in enumerate(names):
        if name in index:
            raise InputError(f"camera {shorten(name)} is listed twice; camera names must be unique", name)
        index[name] = i
    topics = topics or {}
    poses = [_rigid(T_ref_cam, name) for name in names]
    document: dict[str, dict[str, Any]] = {}
    for i, (name, camera) in enumerate(cameras):
        require_finite({"K": camera.K, "dist": camera.dist}, f"camera {shorten(name)}", name)
        others = [n for n in names if n != name] if overlaps is None else list(overlaps.get(name, []))
        for other in others:
            if other not in index or other == name:
                raise InputError(
                    f"overlaps of {shorten(name)} name {shorten(other)}; expected other cameras of the chain: "
                    f"{names}", name
                )
        entry: dict[str, Any] = {}
        if imu is not None:
            entry["T_cam_imu"] = [floats(row) for row in _rigid(imu[0], name, "T_cam_imu")]
        if i > 0:
            entry["T_cn_cnm1"] = [floats(row) for row in invert(poses[i]) @ poses[i - 1]]
        entry |= {
            "cam_overlaps": sorted(index[n] for n in others),
            "camera_model": "pinhole",
            "distortion_coeffs": _kalibr_coeffs(name, camera),
            "distortion_model": DISTORTION_MODELS[camera.model],
            "intrinsics": floats([camera.K[0, 0], camera.K[1, 1], camera.K[0, 2], camera.K[1, 2]]),
            "resolution": [int(camera.width), int(camera.height)],
            "rostopic": str(topics.get(name, default_topic(name))),
        }
        if imu is not None:
            entry["timeshift_cam_imu"] = float(imu[1][name])
        document[f"cam{i}"] = entry
    return dump_yaml(document)


def load_kalibr_camchain(
    source: str | Path,
) -> tuple[list[tuple[str, CameraIntrinsics]], dict[str, np.ndarray]]:
    """Read a Kalibr camchain: a :class:`~pathlib.Path` is read as a file, a ``str`` is the YAML text.

    Returns the cameras as ``(name, intrinsics)`` in chain order and
    ``T_ref_cam`` (4x4, metres) per name with cam0 as the reference (``T_ref_cam``
    of cam0 is the identity). A camera's name is its ``rostopic`` without the
    leading ``/`` and the last part (``/cam_front/image_raw`` gives ``cam_front``,
    ``/stereo/left/image_raw`` gives ``stereo_left``; a one-part topic is the name
    itself), or ``camN`` when there is no topic, the result is not a valid frame
    name (letters, digits, ``_``, ``-``) or it repeats an earlier name. Raises
    :class:`InputError` naming the file (or "Kalibr camchain text") and the field
    for anything malformed: invalid YAML (e.g. a truncated file), missing or
    non-contiguous ``camN``, unsupported models, wrong counts, non-finite
    numbers, a ``T_cn_cnm1`` that is not a rigid 4x4, ``cam_overlaps`` out of range.
    """
    if isinstance(source, Path):
        origin, text = str(source), read_text(source, _EXPECTED_FILE)
    else:
        origin, text = "Kalibr camchain text", source
    document = parse_yaml(text, origin, _EXPECTED_FILE)
    fields = _Fields(origin)
    if not isinstance(document, dict) or not document:
        found = "empty" if document is None else shorten(document, 80)
        raise InputError(f"{origin}: the document is {found}; expected {_EXPECTED_FILE}", origin)
    keys = [str(k) for k in document]
    count = len(keys)
    for i in range(count):
        if f"cam{i}" not in document:
            extra = sorted(set(keys) - {f"cam{j}" for j in range(count)})
            raise fields.error(f"cam{i}", f"is missing (keys: {shorten(keys)}; unexpected: {shorten(extra)})",
                               f"cameras named cam0 ... cam{count - 1}, one per key")
    cameras: list[tuple[str, CameraIntrinsics]] = []
    T_ref_cam: dict[str, np.ndarray] = {}
    T_cam0_prev = np.eye(4)
    for i in range(count):
        key = f"cam{i}"
        entry = fields.mapping(document[key], key, "a mapping with camera_model, intrinsics, distortion_model, "
                                                   "distortion_coeffs, resolution and rostopic")
        camera = fields.camera(entry, key)
        name = _name(entry.get("rostopic"), i, {n for n, _ in cameras})
        if name is None:
            raise fields.error(f"{key}.rostopic", f"is {shorten(entry.get('rostopic'))}: its name and "
                               f"{shorten(key)} are both taken by earlier cameras",
                               "a rostopic naming a camera not yet in the chain")
        fields.overlaps(entry, key, count, i)
        if i == 0:
            T_cam0_cam = np.eye(4)
        else:
            T_cam0_cam = T_cam0_prev @ invert(fields.transform(entry, key))
        cameras.append((name, camera))
        T_ref_cam[name] = T_cam0_cam
        T_cam0_prev = T_cam0_cam
    return cameras, T_ref_cam


def _name(topic: Any, index: int, taken: set[str]) -> str | None:
    """The camera name read from ``topic`` (see :func:`load_kalibr_camchain`); None if even ``camN`` is taken."""
    fallback = f"cam{index}"
    if isinstance(topic, str):
        parts = [p for p in topic.split("/") if p]
        name = "_".join(parts[:-1] if len(parts) > 1 else parts)
        if _NAME.match(name) and name not in taken:
            return name
    return None if fallback in taken else fallback


def _rigid(transforms: Mapping[str, np.ndarray], name: str, what: str = "T_ref_cam") -> np.ndarray:
    """Camera ``name``'s transform of ``transforms`` (``what`` names them), refused unless a rigid 4x4."""
    if name not in transforms:
        raise InputError(f"no {what} for camera {shorten(name)}; known: {sorted(transforms)}", name)
    T = np.asarray(transforms[name], dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not _is_rigid(T):
        raise InputError(f"{what} of {name!r} is not a rigid 4x4 transform: {T.tolist()}", name)
    return T


def _is_rigid(T: np.ndarray) -> bool:
    R = T[:3, :3]
    return bool(
        np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], rtol=0, atol=_RIGID_TOLERANCE)
        and np.allclose(R.T @ R, np.eye(3), rtol=0, atol=_RIGID_TOLERANCE)
        and np.linalg.det(R) > 0
    )


def kalibr_refusal(name: str, camera: CameraIntrinsics) -> str | None:
    """Why Kalibr's ``pinhole`` + ``radtan``/``equidistant`` cannot describe ``camera`` (a message naming
    ``name``: a model it has no name for, a skewed ``K``, or a ``k3`` above :data:`K3_TOLERANCE_PX`), or None if
    it can."""
    if camera.model not in DISTORTION_MODELS:
        return (f"{name}: Kalibr's camchain cannot carry the {camera.model} model (it holds pinhole-radtan and "
                f"pinhole-equi); export {name}'s camera JSON{SPLINED_HINT if camera.spline else ' or OpenCV YAML'}, "
                "or solve it with pinhole-radtan")
    if abs(camera.K[0, 1]) > 1e-12 * abs(camera.K[0, 0]):
        return (f"{name}: K has skew {camera.K[0, 1]!r} px, which Kalibr's pinhole [fu, fv, pu, pv] cannot hold; "
                "recalibrate without skew")
    if camera.is_fisheye or float(camera.dist[4]) == 0.0:
        return None
    shift_px = _k3_shift_px(camera)
    if shift_px <= K3_TOLERANCE_PX:
        return None
    return (f"{name}: k3 = {float(camera.dist[4])!r} moves the farthest image corner by {shift_px:.3g} px, but "
            f"Kalibr's radtan holds only [k1, k2, r1, r2] (no k3; at most {K3_TOLERANCE_PX} px is dropped); "
            f"recalibrate {name} with k3 fixed at 0 or export another format")


def _kalibr_coeffs(name: str, camera: CameraIntrinsics) -> list[float]:
    """Kalibr's 4 coefficients of ``camera``, refusing what Kalibr cannot represent (:func:`kalibr_refusal`)."""
    expected = len(camera.dist_names)
    if camera.dist.size != expected:
        raise ValueError(f"{camera.model} has {expected} distortion coefficients, {name} holds {camera.dist.size}")
    refusal = kalibr_refusal(name, camera)
    if refusal is not None:
        raise InputError(refusal, name)
    return floats(camera.dist if camera.is_fisheye else camera.dist[:4])


def _k3_shift_px(camera: CameraIntrinsics) -> float:
    """Shift (px) of the farthest image corner due to ``k3`` alone: ``|k3| r^6 * r * max(fx, fy)``."""
    corners = np.array([[0, 0], [camera.width - 1, 0], [0, camera.height - 1], [camera.width - 1, camera.height - 1]])
    xy = camera.undistort_points(corners.astype(float))
    r = float(np.max(np.hypot(xy[:, 0], xy[:, 1])))
    return abs(float(camera.dist[4])) * r**7 * float(max(camera.K[0, 0], camera.K[1, 1]))


class _Fields(YamlFields):
    """Typed, checked access to the fields of one camchain document."""

    def numbers(self, entry: dict[str, Any], key: str, field: str, count: int, expected: str) -> np.ndarray:
        values = self.get(entry, key, field, expected)
        if not isinstance(values, list) or len(values) != count:
            found = f"has {len(values)} values" if isinstance(values, list) else f"is {shorten(values)}"
            raise self.error(field, found, expected)
        return np.array([self.number(v, f"{field}[{i}]") for i, v in enumerate(values)])

    def camera(self, entry: dict[str, Any], key: str) -> CameraIntrinsics:
        model = self.get(entry, "camera_model", f"{key}.camera_model", "pinhole")
        if model != "pinhole":
            raise self.error(f"{key}.camera_model", f"is {shorten(model)}, which is not supported",
                             "pinhole (omni, ds and eucm have no OpenCV counterpart here)")
        fu, fv, pu, pv = self.numbers(entry, "intrinsics", f"{key}.intrinsics", 4, "[fu, fv, pu, pv] (px)")
        if not (fu > 0 and fv > 0):
            raise self.error(f"{key}.intrinsics", f"is {[fu, fv, pu, pv]}", "[fu, fv, pu, pv] with fu, fv > 0 (px)")
        dist_model = self.get(entry, "distortion_model", f"{key}.distortion_model", "radtan or equidistant")
        if dist_model not in _MODELS_BY_KALIBR_NAME:
            raise self.error(f"{key}.distortion_model", f"is {shorten(dist_model)}, which is not supported",
                             f"one of {sorted(_MODELS_BY_KALIBR_NAME)}")
        n = _COEFF_COUNTS[dist_model]
        names = {"radtan": "[k1, k2, r1, r2]", "none": "[]", "equidistant": "[k1, k2, k3, k4]"}[dist_model]
        coeffs = self.numbers(entry, "distortion_coeffs", f"{key}.distortion_coeffs", n,
                              f"{n} coefficients for {dist_model}: {names}")
        resolution = self.get(entry, "resolution", f"{key}.resolution", "[width, height] (px)")
        if (not isinstance(resolution, list) or len(resolution) != 2
                or any(isinstance(v, bool) or not isinstance(v, int) or v <= 0 for v in resolution)):
            raise self.error(f"{key}.resolution", f"is {shorten(resolution)}",
                             "[width, height]: two positive integers (px)")
        K = np.array([[fu, 0.0, pu], [0.0, fv, pv], [0.0, 0.0, 1.0]])
        model_name = _MODELS_BY_KALIBR_NAME[dist_model]
        dist = np.zeros(len(DIST_NAMES[model_name]))
        dist[: coeffs.size] = coeffs
        return CameraIntrinsics(model_name, resolution[0], resolution[1], K, dist)

    def overlaps(self, entry: dict[str, Any], key: str, count: int, index: int) -> None:
        """Check ``cam_overlaps`` (optional): camera indices of the chain other than this one."""
        if "cam_overlaps" not in entry:
            return
        values = entry["cam_overlaps"]
        expected = f"a list of other camera indices in 0..{count - 1}"
        if not isinstance(values, list):
            raise self.error(f"{key}.cam_overlaps", f"is {shorten(values)}", expected)
        for j, value in enumerate(values):
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < count or value == index:
                raise self.error(f"{key}.cam_overlaps[{j}]", f"is {shorten(value)}", expected)

    def transform(self, entry: dict[str, Any], key: str) -> np.ndarray:
        """``T_cn_cnm1``: 4 rows of 4 finite numbers forming a rigid transform (translation in metres)."""
        field = f"{key}.T_cn_cnm1"
        expected = f"4 rows of 4 numbers: the rigid transform mapping points in cam{int(key[3:]) - 1} into {key} (m)"
        rows = self.get(entry, "T_cn_cnm1", field, expected)
        if not isinstance(rows, list) or len(rows) != 4:
            found = f"has {len(rows)} rows" if isinstance(rows, list) else f"is {shorten(rows)}"
            raise self.error(field, found, expected)
        T = np.zeros((4, 4))
        for r, row in enumerate(rows):
            if not isinstance(row, list) or len(row) != 4:
                found = f"has {len(row)} values" if isinstance(row, list) else f"is {shorten(row)}"
                raise self.error(f"{field}[{r}]", found, expected)
            T[r] = [self.number(v, f"{field}[{r}][{c}]") for c, v in enumerate(row)]
        if not _is_rigid(T):
            raise self.error(field, f"is {T.tolist()}, which is not rigid",
                             "an orthonormal rotation with determinant 1 and last row [0, 0, 0, 1]")
        return T
