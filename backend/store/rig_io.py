"""Convert the numpy rig model to and from its validated on-disk form."""

from __future__ import annotations

from typing import Any

import numpy as np

from backend.core.camera import CameraIntrinsics
from backend.core.rig import Frame, Rig
from backend.store.schema import FrameModel, RigModel


def _frame_fields(f: Frame) -> dict[str, Any]:
    return {
        "name": f.name,
        "parent": f.parent,
        "kind": f.kind,
        "T_parent_child": f.T_parent_child.tolist(),
        "covariance": None if f.covariance is None else f.covariance.tolist(),
        "intrinsics": None if f.intrinsics is None else f.intrinsics.to_dict(),
        "device": f.device,
        "T_mount": f.T_mount.tolist(),
        "mount_sigma": f.mount_sigma,
        "not_connected": f.not_connected,
        "clock_offset_s": f.clock_offset_s,
        "clock_offset_std_s": f.clock_offset_std_s,
    }


def frame_to_model(frame: Frame) -> FrameModel:
    """One frame's on-disk form (raises pydantic's ``ValidationError``, e.g. for a NaN)."""
    return FrameModel.model_validate(_frame_fields(frame))


def frame_from_model(f: FrameModel) -> Frame:
    """The frame a :class:`FrameModel` describes."""
    return Frame(
        name=f.name,
        parent=f.parent,
        T_parent_child=np.array(f.T_parent_child),
        kind=f.kind,
        covariance=None if f.covariance is None else np.array(f.covariance),
        intrinsics=None if f.intrinsics is None else CameraIntrinsics.from_dict(f.intrinsics.model_dump()),
        device=f.device,
        T_mount=None if f.T_mount is None else np.array(f.T_mount),
        mount_sigma=f.mount_sigma,
        not_connected=f.not_connected,
        clock_offset_s=f.clock_offset_s,
        clock_offset_std_s=f.clock_offset_std_s,
    )


def rig_to_model(rig: Rig) -> RigModel:
    """The rig's on-disk form, validated as one document, so an error names its place
    (``frames.2.intrinsics.K.0.0``); raises pydantic's ``ValidationError`` (e.g. for a NaN)."""
    return RigModel.model_validate({"root": rig.root, "frames": [_frame_fields(f) for f in rig.frames.values()]})


def rig_from_model(model: RigModel) -> Rig:
    """Rebuild a rig; frames are stored parents-first, so adding in order keeps the tree valid."""
    rig = Rig(root=model.root, frames={})
    for f in model.frames:
        frame = frame_from_model(f)
        if f.parent is None:
            rig.frames[f.name] = frame
        else:
            rig.add(frame)
    return rig
