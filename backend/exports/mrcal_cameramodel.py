"""mrcal's ``.cameramodel`` file: the one format outside the studio that carries the splined model.

mrcal reads a ``.cameramodel`` as a Python literal dict (``mrcal.cameramodel(path)``): ``lensmodel`` (mrcal's model
name), ``intrinsics`` (``[fx, fy, cx, cy, ...]`` in that model's order), ``extrinsics`` (the camera's pose as
``rt_cam_ref``: Rodrigues rotation, then translation in m; a lone camera is the identity) and ``imagersize`` (width,
height px). ``splined-stereographic`` is ``LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=.._Ny=.._fov_x_deg=..`` with the
control points in mrcal's order (:mod:`backend.core.splined`); ``pinhole-radtan`` is ``LENSMODEL_OPENCV5`` (mrcal's
order is OpenCV's ``k1, k2, p1, p2, k3``). mrcal 2.2 has no model of OpenCV's fisheye or of the photogrammetric model:
those are refused (:func:`mrcal_refusal`). Written without mrcal, which has no wheel for this Python; the file is
read back with :func:`ast.literal_eval`, as mrcal's own reader does.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError, shorten
from backend.core.finite import require_finite
from backend.core.splined import SplineGrid
from backend.exports.text_file import read_text

OPENCV5 = "LENSMODEL_OPENCV5"


def mrcal_refusal(camera: CameraIntrinsics) -> str | None:
    """Why mrcal's ``.cameramodel`` cannot carry ``camera``'s model, or None when it can."""
    if camera.model in ("pinhole-radtan", "splined-stereographic"):
        return None
    return (f"mrcal's .cameramodel cannot carry the {camera.model} model (mrcal has no model of it; it takes "
            "pinhole-radtan as LENSMODEL_OPENCV5 and the splined model); write the camera JSON instead")


def dump_mrcal_cameramodel(camera: CameraIntrinsics, camera_name: str) -> str:
    """``camera`` as a ``.cameramodel`` file's text; :class:`InputError` for a model mrcal has no name for or a NaN."""
    refusal = mrcal_refusal(camera)
    if refusal is not None:
        raise InputError(refusal, "model")
    require_finite({"K": camera.K, "dist": camera.dist}, f"cameramodel of {camera_name}", camera_name)
    lensmodel = camera.spline.mrcal_name if camera.spline is not None else OPENCV5
    intrinsics = ", ".join(repr(float(v)) for v in camera.parameters)
    return (f"# {camera_name}: written by Calibration Studio; mrcal.cameramodel() reads it\n"
            "{\n"
            f"    'lensmodel':  {lensmodel!r},\n"
            f"    'intrinsics': [ {intrinsics} ],\n"
            "    'extrinsics': [ 0.0, 0.0, 0.0, 0.0, 0.0, 0.0 ],\n"
            f"    'imagersize': [ {int(camera.width)}, {int(camera.height)} ],\n"
            "}\n")


def load_mrcal_cameramodel(path: Path) -> CameraIntrinsics:
    """A ``.cameramodel`` file of ``LENSMODEL_OPENCV5`` or the order-3 splined model as a camera; :class:`InputError`
    naming the file and the field for anything else."""
    path = Path(path)
    expected = "mrcal's .cameramodel: a dict with lensmodel, intrinsics and imagersize"
    text = "\n".join(line for line in read_text(path, expected).splitlines() if not line.lstrip().startswith("#"))
    try:
        document = ast.literal_eval(text)
    except (SyntaxError, ValueError):
        raise InputError(f"{path}: not a Python literal dict; expected {expected}", str(path)) from None
    if not isinstance(document, dict):
        raise InputError(f"{path}: not a dict; expected {expected}", str(path))
    lensmodel = document.get("lensmodel")
    try:
        spline = None if lensmodel == OPENCV5 else SplineGrid.from_mrcal_name(str(lensmodel))
    except ValueError:
        raise InputError(f"{path}: field 'lensmodel' is {lensmodel!r}; expected {OPENCV5} or "
                         "LENSMODEL_SPLINED_STEREOGRAPHIC_order=3_Nx=.._Ny=.._fov_x_deg=..", str(path)) from None
    count = 9 if spline is None else 4 + spline.n_control
    values = document.get("intrinsics")
    try:
        intrinsics = np.asarray(values, float).ravel()
    except (TypeError, ValueError):  # a string, a dict, a ragged list
        intrinsics = np.full(1, np.nan)
    size = document.get("imagersize")
    if not isinstance(values, list | tuple) or intrinsics.size != count or not np.all(np.isfinite(intrinsics)):
        raise InputError(f"{path}: field 'intrinsics' is {shorten(values)}; expected a list of {count} finite numbers "
                         f"for {lensmodel}", str(path))
    if not (isinstance(size, list | tuple) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)):
        raise InputError(f"{path}: field 'imagersize' is {size!r}; expected [width, height] in pixels", str(path))
    fx, fy, cx, cy = intrinsics[:4]
    return CameraIntrinsics("splined-stereographic" if spline else "pinhole-radtan", size[0], size[1],
                            [[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], intrinsics[4:], spline)
