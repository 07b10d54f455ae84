"""The rig's frames as the tree exports write: parents first, in the optical or the body camera convention.

Every exported frame is ``T_parent_child`` of ``../shared/conventions.md`` (maps points in ``child`` into
``parent``, metres) with its 6x6 covariance (``TRANSFORM_PARAMETERS`` order: translation in m along the
parent's axes, rotation in rad about the child's axes) or None.

Conventions (:data:`~backend.exports.formats.Convention`):

- ``optical``: the frames as the rig stores them. Camera frames are optical frames (x right, y down,
  z forward); LiDAR and body frames x forward, y left, z up.
- ``body``: each camera ``CAM`` is written as a body frame named ``CAM`` (x forward = the optical z, y left,
  z up; same origin) and a fixed child ``CAM_optical_frame`` carrying the optical rotation
  (:data:`T_BODY_OPTICAL`, the ``-90, 0, -90`` deg yaw/pitch/roll of REP 103), as ROS camera drivers and
  URDFs name them (REP 103/105 practice). Frames mounted on a camera hang from ``CAM_optical_frame`` with
  their stored transform, so every point keeps its place. The body frame's covariance is the optical
  one with its rotation block turned into the body axes; the optical child is exact (zero covariance).
  LiDARs and every other frame are unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from backend.core.errors import InputError, shorten
from backend.core.rig import Frame, Rig, covariance_sigmas
from backend.core.transforms import R_BODY_OPTICAL, invert, make_T
from backend.exports.formats import CONVENTIONS, Convention

T_BODY_OPTICAL = make_T(R_BODY_OPTICAL, np.zeros(3))
"""``T_CAM_CAM_optical_frame`` of the body convention: same origin, optical axes."""
OPTICAL_SUFFIX = "_optical_frame"
"""The name of a camera's optical child in the body convention is the camera's name and this."""


@dataclass(frozen=True)
class ExportedFrame:
    """One edge of the exported tree."""

    parent: str
    child: str
    T_parent_child: np.ndarray
    """4x4, metres: maps points in ``child`` into ``parent``."""
    covariance: np.ndarray | None
    """6x6 over translation (m, parent axes) and rotation (rad, child axes), or None if unknown."""
    sensor: str
    """The rig frame it comes from (what messages name)."""

    @property
    def sigmas(self) -> tuple[np.ndarray, np.ndarray] | None:
        """1-sigma translation (m, per parent axis) and rotation (deg, about the child's x, y, z), or None."""
        return covariance_sigmas(self.covariance)


def export_frames(rig: Rig, convention: Convention = "optical") -> list[ExportedFrame]:
    """Every non-root frame of ``rig`` as an :class:`ExportedFrame`, parents before children (siblings in the
    rig's order), in ``convention``.

    Raises :class:`InputError` naming the frame when the tree cannot be written: a frame other than the root
    with no parent (nothing connects it to the root; 409), a parent that is not in the rig, a loop of
    parents, or (body convention) a frame already named like a camera's optical child.
    """
    if convention not in CONVENTIONS:
        raise InputError(f"unknown convention {shorten(convention)}; expected one of {list(CONVENTIONS)}",
                         "convention")
    for frame in rig.frames.values():
        ancestors(rig, frame.name)
    children: dict[str, list[Frame]] = {name: [] for name in rig.frames}
    for frame in rig.frames.values():
        if frame.parent is not None:
            children[frame.parent].append(frame)
    exported: list[ExportedFrame] = []
    pending = list(reversed(children[rig.root]))
    while pending:
        frame = pending.pop()
        exported.extend(_exported(rig, frame, convention))
        pending.extend(reversed(children[frame.name]))
    return exported


def ancestors(rig: Rig, name: str) -> list[str]:
    """``name`` and its parents up to the root, in that order. Raises :class:`InputError` naming the frame if
    the chain stops before the root (a frame with no parent, 409), names a parent the rig lacks, or loops."""
    chain = [rig.get(name).name]
    while chain[-1] != rig.root:
        frame = rig.frames[chain[-1]]
        if frame.parent is None:
            below = f" (above {chain[0]!r})" if len(chain) > 1 else ""
            raise InputError(
                f"frame {frame.name!r}{below} has no parent: nothing connects it to {rig.root!r}; give "
                f"{frame.name} a mounting guess or accept a calibration that links it to the rig", frame.name, 409)
        if frame.parent not in rig.frames:
            raise InputError(f"frame {frame.name!r} hangs from {frame.parent!r}, which is not in the rig; known: "
                             f"{shorten(sorted(rig.frames))}", frame.name)
        if frame.parent in chain:
            raise InputError(f"frame {chain[0]!r}: its parents loop ({' -> '.join([*chain, frame.parent])})",
                             chain[0])
        chain.append(frame.parent)
    return chain


def _exported(rig: Rig, frame: Frame, convention: Convention) -> list[ExportedFrame]:
    """The exported edge(s) of one rig frame: one, or a camera's body frame and its optical child."""
    assert frame.parent is not None  # export_frames checked every chain
    parent = frame.parent
    if convention == "body" and rig.frames[parent].kind == "camera":
        parent += OPTICAL_SUFFIX
    if convention == "optical" or frame.kind != "camera":
        return [ExportedFrame(parent, frame.name, frame.T_parent_child, frame.covariance, frame.name)]
    optical = frame.name + OPTICAL_SUFFIX
    if optical in rig.frames:
        raise InputError(f"frame {optical!r} is already in the rig: the body convention names camera "
                         f"{frame.name}'s optical frame so; rename {optical} or export in the optical convention",
                         optical)
    covariance = None
    if frame.covariance is not None:
        to_body = np.eye(6)
        to_body[3:, 3:] = R_BODY_OPTICAL
        covariance = to_body @ frame.covariance @ to_body.T
    return [
        ExportedFrame(parent, frame.name, frame.T_parent_child @ invert(T_BODY_OPTICAL), covariance, frame.name),
        ExportedFrame(frame.name, optical, T_BODY_OPTICAL, np.zeros((6, 6)), frame.name),
    ]
