"""Editing a rig's sensors: a changed mounting guess, parent, mount sigma or device, and which accepted slots a
sensor takes with it when it is removed. Plain rig operations; :mod:`backend.calib.rig.service` re-fits the tree
around them and stores them.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Final

import numpy as np

from backend.core.errors import InputError
from backend.core.result import StoredResult
from backend.core.rig import Rig


class _Keep:
    """The type of :data:`KEEP`."""

    def __repr__(self) -> str:
        return "KEEP"


KEEP: Final = _Keep()
"""An edit's field left as it is (``None`` means something for ``mount_sigma``: the mounting is unknown)."""


@dataclass(frozen=True)
class SensorEdit:
    """What to change about one frame; every field left at its default stays as it is."""

    parent: str | None = None
    """The frame to hang from; None keeps the parent."""
    T_mount: np.ndarray | None = None
    """The new mounting guess ``T_parent_child`` (4x4, m) under the (new) parent. None keeps the guess; with a new
    parent it keeps the frame where it is now (the guess becomes its current pose under the new parent)."""
    mount_sigma: tuple[float, float] | None | _Keep = KEEP
    """1-sigma of the mounting guess (m, deg); None: unknown."""
    device: dict[str, Any] | None = None
    """New capture-device settings (``{"driver": ..., **settings}``); None keeps them."""

    def is_empty(self) -> bool:
        return (self.parent is None and self.T_mount is None and isinstance(self.mount_sigma, _Keep)
                and self.device is None)


def apply_edit(rig: Rig, name: str, edit: SensorEdit) -> None:
    """Change frame ``name`` of ``rig`` as ``edit`` says. The frame is rebuilt, so its values are checked as when it
    was added (:class:`InputError` naming the field); a parent that would make a cycle is refused, naming it."""
    frame = rig.get(name)
    if frame.parent is None:
        raise InputError(f"{name!r} is the rig's root: it has no mounting to edit", "sensor", 409)
    if edit.is_empty():
        raise InputError(f"nothing to change for {name!r}: give a parent, a pose, a mount sigma or a device",
                         "body")
    if edit.parent is not None and edit.parent != frame.parent:
        rig.reparent(name, edit.parent, edit.T_mount)
        changes: dict[str, Any] = {"T_mount": rig.frames[name].T_parent_child}
    elif edit.T_mount is not None:
        changes = {"T_mount": edit.T_mount, "T_parent_child": edit.T_mount}
    else:
        changes = {}
    if not isinstance(edit.mount_sigma, _Keep):
        changes["mount_sigma"] = None if edit.mount_sigma is None else tuple(map(float, edit.mount_sigma))
    if edit.device is not None:
        changes["device"] = copy.deepcopy(edit.device)
    rig.frames[name] = dataclasses.replace(rig.frames[name], **changes)


def slots_involving(sensor: str, accepted: Mapping[str, str], records: Mapping[str, dict[str, Any]]) -> list[str]:
    """The accepted slots that hold ``sensor``: results of the sensor (its intrinsics, its geometry) and results
    with an edge to or from it (a multi-camera solve with it among its cameras). ``records`` maps each accepted
    result id to its record."""
    involved = []
    for slot, result_id in accepted.items():
        record = records[result_id]
        edges = StoredResult(record).edges
        if record.get("sensor") == sensor or any(sensor in (e.parent, e.child) for e in edges):
            involved.append(slot)
    return involved


def frames_missing(record: dict[str, Any], rig: Rig) -> list[str]:
    """The frames a result's edges name that ``rig`` does not hold (its slot cannot come back without them)."""
    return sorted({name for e in StoredResult(record).edges for name in (e.parent, e.child)} - set(rig.frames))
