"""One accept service for every result, and the session's rig as one fused tree.

Accepting any result goes through :func:`accept`: intrinsics become the camera's, a swept
scanner's geometry becomes its device's, and every transform result (LiDAR-LiDAR,
LiDAR-camera, each camera of a multi-camera solve, a depth node) becomes an edge of the rig's
pose graph (:mod:`backend.calib.rig.graph`), beside the mounting guesses as weak priors.
After every accept or revert the whole tree is re-fitted and written into the rig's frames
(``T_parent_child`` and its covariance), so ``session.rig`` is always the current tree and no
accepted result silently stops holding: each one's residual, its disagreement with the rest
and every loop's closure are in :func:`solve_rig`. :func:`preview` shows what an accept would
move before anything is written.

Editing a sensor (:func:`edit_sensor`: its mounting guess, parent, mount sigma, device), removing one
(:func:`remove_sensor`: its slots are emptied, its captures moved aside) and restoring one
(:func:`restore_sensor`) re-fit the tree the same way, and each can be previewed first.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from backend.calib.intrinsics import service as intrinsics_service
from backend.calib.multicam import service as multicam_service
from backend.calib.rig.graph import FLAG_SIGMA as FLAG_SIGMA  # re-exported: the studio names the limit
from backend.calib.rig.graph import EdgeResidual, RigEdge, RigTree, solve_rig_graph
from backend.calib.rig.sensor_edits import KEEP as KEEP  # re-exported: the API and the studio build edits
from backend.calib.rig.sensor_edits import SensorEdit as SensorEdit
from backend.calib.rig.sensor_edits import apply_edit, frames_missing, slots_involving
from backend.calib.sweep import service as sweep_service
from backend.calib.time_offset import service as time_offset_service
from backend.core.errors import InputError
from backend.core.result import EDGE_KINDS, StoredResult, TransformResult
from backend.core.rig import Frame, Rig, edge_slot
from backend.core.transforms import params_between
from backend.core.uncertainty import sigmas
from backend.devices.base import check_device, check_settings
from backend.store.rig_io import frame_from_model
from backend.store.session import Session

MANUAL_SIGMA = (0.005, 0.3)
"""1-sigma (m, deg) assumed for a transform set by hand, which carries none of its own."""
MOVE_THRESHOLD = (1e-6, 1e-5)
"""A frame moving less than this (m, deg) does not count as moved."""

Effect = Callable[[Rig, dict[str, Any]], None]


def _imu_clock(rig: Rig, record: dict[str, Any]) -> None:
    """A camera-IMU or LiDAR-IMU result's time offset becomes the IMU's clock offset."""
    time_offset_service.apply_clock_offset(rig, time_offset_service.transform_clock_record(record))


EFFECTS: dict[str, Effect] = {
    "intrinsics": lambda rig, record: intrinsics_service.apply_intrinsics(rig, record),
    "sweep": lambda rig, record: sweep_service.apply_sweep_geometry(rig, record),
    "multicam": lambda rig, record: multicam_service.apply_refined_intrinsics(rig, record),
    "time_offset": lambda rig, record: time_offset_service.apply_clock_offset(rig, record),
    "camera_imu": lambda rig, record: _imu_clock(rig, record),
    "lidar_imu": lambda rig, record: _imu_clock(rig, record),
}
"""What accepting a result does to the rig beside its edges (the camera's intrinsics, a scanner's geometry, a sensor's
clock offset)."""


# ---------------------------------------------------------------------------------------------
# Results as edges


def slot_of(record: dict[str, Any]) -> str:
    """The acceptance slot a result fills: ``CAM/intrinsics``, ``SENSOR/sweep``, ``multicam:A+B`` or
    ``CHILD/T_PARENT_CHILD`` for a transform between two frames."""
    kind = record.get("kind")
    if kind == "intrinsics":
        return f"{record['sensor']}/intrinsics"
    if kind == "sweep":
        return f"{record['sensor']}/sweep"
    if kind == "multicam":
        return multicam_service.slot(record["camera_order"])
    if kind == "time_offset":
        return time_offset_service.slot(record["sensor_b"])
    if kind in EDGE_KINDS:
        transform = StoredResult(record).edges[0]
        return edge_slot(transform.parent, transform.child)
    raise InputError(f"result {record.get('id')} is a {kind!r} result, which cannot be accepted", "result")


def manual_covariance() -> tuple[np.ndarray, str]:
    """The 6x6 covariance assumed for a transform set by hand (:data:`MANUAL_SIGMA` on every axis, m and rad) and
    the words that say so."""
    sigma_m, sigma_deg = MANUAL_SIGMA
    return (np.diag([sigma_m**2] * 3 + [np.radians(sigma_deg) ** 2] * 3),
            f"sigma assumed {sigma_m * 1000:g} mm, {sigma_deg:g} deg")


def _edge(transform: TransformResult, record: dict[str, Any], slot: str) -> RigEdge:
    covariance, note = transform.covariance, ""
    if transform.method == "manual" or not np.isfinite(covariance).any():
        covariance, assumed = manual_covariance()
        note = f"set by hand: {assumed}"
    return RigEdge(transform.parent, transform.child, transform.T_parent_child, covariance, record["kind"],
                   record["id"], slot, transform.method, note)


def prior_edges(rig: Rig) -> list[RigEdge]:
    """The mounting guesses as weak edges from each frame's parent (frames whose mounting is unknown have none)."""
    return [RigEdge(f.parent, f.name, f.T_mount, f.mount_covariance, "prior", note=f"mounting guess, sigma "
                    f"{f.mount_sigma[0] * 1000:g} mm, {f.mount_sigma[1]:g} deg")
            for f in rig.frames.values() if f.parent is not None and f.mount_sigma is not None]


def _graph_edges(session: Session, accepted: dict[str, str], rig: Rig) -> list[RigEdge]:
    """Priors, then every accepted slot's edges, the longest-standing first."""
    edges = prior_edges(rig)
    for slot, result_id in accepted.items():
        record = session.result(result_id)
        edges += [_edge(t, record, slot) for t in StoredResult(record).edges]
    return edges


def _fit(session: Session, accepted: dict[str, str], rig: Rig) -> RigTree:
    parents = {name: frame.parent for name, frame in rig.frames.items()}
    return solve_rig_graph(rig.root, parents, _graph_edges(session, accepted, rig))


def solve_rig(session: Session) -> RigTree:
    """The fused tree of everything accepted in the session (nothing is written)."""
    return _fit(session, session.accepted_slots(), session.rig)


def _write_tree(rig: Rig, tree: RigTree) -> None:
    """Give every fitted frame its fused ``T_parent_child`` and covariance (a frame left unconnected keeps its own)."""
    for name, estimate in tree.frames.items():
        frame = rig.get(name)
        frame.T_parent_child = estimate.T_parent_child.copy()
        frame.covariance = estimate.covariance.copy() if np.isfinite(estimate.covariance).all() else None


# ---------------------------------------------------------------------------------------------
# Accept, preview, revert


@dataclass
class FrameMove:
    """How far a change moves one frame's ``T_parent_child``."""

    frame: str
    trans_m: float
    rot_deg: float
    sigma_ratio: float | None
    """The worst axis's move over that axis's sigma after the change (None when the sigma is unknown)."""


@dataclass
class RigUpdate:
    """What an accept or revert does (or would do) to the rig."""

    tree: RigTree
    """The tree after the change."""
    moves: list[FrameMove]
    """Frames that move, the largest move (in sigma) first."""
    result_id: str | None
    slot: str

    @property
    def conflicts(self) -> list[EdgeResidual]:
        """Edges flagged in the tree after the change."""
        return self.tree.flagged

    def to_dict(self) -> dict[str, Any]:
        return {"result_id": self.result_id, "slot": self.slot} | _fit_dict(self.tree, self.moves)


def _fit_dict(tree: RigTree, moves: list[FrameMove]) -> dict[str, Any]:
    """``moves``, ``conflicts``, ``problems`` and the ``rig`` summary of a change's tree, as the API sends them."""
    return {"moves": [vars(move) for move in moves], "conflicts": [c.to_dict() for c in tree.flagged],
            "problems": tree.problems(), "rig": tree.summary()}


def _moves(before: RigTree, after: RigTree) -> list[FrameMove]:
    moves = []
    for name, new in after.frames.items():
        old = before.frames.get(name)
        if old is None:
            continue
        step = params_between(old.T_parent_child, new.T_parent_child)
        trans_m, rot_deg = float(np.linalg.norm(step[:3])), float(np.degrees(np.linalg.norm(step[3:])))
        if trans_m < MOVE_THRESHOLD[0] and rot_deg < MOVE_THRESHOLD[1]:
            continue
        sigma = sigmas(new.covariance)
        ratio = float(np.max(np.abs(step) / sigma)) if np.all(sigma > 0) and np.isfinite(sigma).all() else None
        moves.append(FrameMove(name, trans_m, rot_deg, ratio))
    return sorted(moves, key=lambda m: -(m.sigma_ratio or 0.0))


def _check_acceptable(record: dict[str, Any]) -> None:
    if record.get("kind") in EDGE_KINDS and not record.get("converged", False):
        raise InputError(f"result {record['id']} did not converge and cannot be accepted: "
                         + ("; ".join(record.get("warnings", [])) or "no reason given"), "result", 409)


def _check_revert(session: Session, revert: Sequence[str]) -> None:
    for other in revert:
        if other not in session.accepted_slots():
            raise InputError(f"cannot revert {other!r}: nothing is accepted for it; accepted: "
                             f"{sorted(session.accepted_slots())}", "revert")


def _accepted_after(session: Session, slot: str, result_id: str, revert: Sequence[str]) -> dict[str, str]:
    _check_revert(session, revert)
    return {s: r for s, r in session.accepted_slots().items() if s not in revert and s != slot} | {slot: result_id}


def preview(session: Session, result_id: str, revert: Sequence[str] = ()) -> RigUpdate:
    """What accepting ``result_id`` (and emptying the ``revert`` slots) would do to the tree; nothing is written."""
    record = session.result(result_id)
    _check_acceptable(record)
    slot = slot_of(record)
    with session.lock:
        before = solve_rig(session)
        after = _fit(session, _accepted_after(session, slot, result_id, revert), session.rig)
    return RigUpdate(after, _moves(before, after), result_id, slot)


def accept(session: Session, result_id: str, *, confirm: bool = False, revert: Sequence[str] = ()) -> RigUpdate:
    """Make ``result_id`` current (any kind), empty the ``revert`` slots (the user keeps this result over
    theirs), re-fit the tree and write it into the rig, all in one saved change (also how a user goes back
    to an older result). A ``check`` verdict needs ``confirm``; a ``reject`` or an unconverged solve is refused."""
    record = session.result(result_id)
    _check_acceptable(record)
    slot = slot_of(record)
    effect = EFFECTS.get(record.get("kind"))
    with session.lock:
        _check_revert(session, revert)
        before = solve_rig(session)
        after: list[RigTree] = []

        def apply(rig: Rig, stored: dict[str, Any]) -> None:
            if effect is not None:
                effect(rig, stored)
            after.append(_fit(session, session.accepted_slots(), rig))
            _write_tree(rig, after[0])

        if not session.accept(slot, result_id, apply, confirm, revert):
            after.append(before)  # the slot held it already: nothing moves
    return RigUpdate(after[0], _moves(before, after[0]), result_id, slot)


def preview_many(session: Session, result_ids: Sequence[str]) -> RigUpdate:
    """What accepting every one of ``result_ids`` together would do to the tree (each checked as
    :func:`preview` checks one); nothing is written. Its ``slot`` lists their slots."""
    records = [session.result(result_id) for result_id in result_ids]
    for record in records:
        _check_acceptable(record)
    chosen = {slot_of(record): record["id"] for record in records}
    with session.lock:
        before = solve_rig(session)
        accepted = {s: r for s, r in session.accepted_slots().items() if s not in chosen} | chosen
        after = _fit(session, accepted, session.rig)
    return RigUpdate(after, _moves(before, after), None, ", ".join(chosen))


def accept_many(session: Session, result_ids: Sequence[str]) -> RigUpdate:
    """Accept each of ``result_ids`` in turn (as :func:`accept`, none confirmed: a ``check`` among them stops the
    run there, naming it, with those before it accepted); the update from before the first to after the last."""
    with session.lock:
        before = solve_rig(session)
        updates = [accept(session, result_id) for result_id in result_ids]
    after = updates[-1].tree if updates else before
    return RigUpdate(after, _moves(before, after), None, ", ".join(update.slot for update in updates))


def revert(session: Session, slot: str) -> RigUpdate:
    """Empty ``slot`` (its result stays in the history), re-fit the tree without its edges and write it.

    Only transform slots can be emptied; intrinsics and a scanner's geometry are reverted by accepting an
    older result.
    """
    with session.lock:
        result_id = session.accepted(slot)
        if result_id is not None and not StoredResult(session.result(result_id)).edges:
            raise InputError(f"{slot} holds no rig edge; accept an older result to go back", "slot", 409)
        before = solve_rig(session)
        after: list[RigTree] = []

        def apply(rig: Rig) -> None:
            after.append(_fit(session, session.accepted_slots(), rig))
            _write_tree(rig, after[0])

        session.revert(slot, apply)
    return RigUpdate(after[0], _moves(before, after[0]), None, slot)


# ---------------------------------------------------------------------------------------------
# Editing, removing and restoring sensors


@dataclass
class SensorChange:
    """What an edit, removal or restore of one sensor does (or, previewed, would do) to the rig."""

    sensor: str
    action: str
    """``edit``, ``remove`` or ``restore``."""
    applied: bool
    """False for a preview: nothing was written."""
    tree: RigTree
    moves: list[FrameMove]
    emptied: list[str]
    """Accepted slots the change empties (a removal takes its sensor's slots with it)."""
    restored: list[str]
    """Slots a restore makes current again."""
    not_restored: dict[str, str]
    """Slots a restore leaves empty, and why."""
    removal: dict[str, Any] | None
    """The removal's record (``id``, ``sensor``, ``at``, ...) for a removal or restore."""

    def to_dict(self) -> dict[str, Any]:
        return {"sensor": self.sensor, "action": self.action, "applied": self.applied, "emptied": self.emptied,
                "restored": self.restored, "not_restored": self.not_restored,
                "removal": self.removal} | _fit_dict(self.tree, self.moves)


def _sensor_change(session: Session, sensor: str, action: str, rig: Rig, accepted: dict[str, str],
                   write: Callable[[Callable[[Rig], None]], Any] | None, **details: Any) -> SensorChange:
    """Fit ``rig`` (the rig after the change) with ``accepted`` (the slots after it); unless previewing (``write``
    None), ``write(apply)`` makes the change in the session, where ``apply`` writes that fit into the rig."""
    before, after = solve_rig(session), _fit(session, accepted, rig)
    written = None if write is None else write(lambda live: _write_tree(live, after))
    if written is not None:
        details["removal"] = written.model_dump(mode="json")
    return SensorChange(sensor, action, write is not None, after, _moves(before, after),
                        **({"emptied": [], "restored": [], "not_restored": {}, "removal": None} | details))


def add_sensor(session: Session, frame: Frame, *, connected: bool = True) -> Frame:
    """Add a sensor (or a plain frame) to the rig. Its device is opened first, and one that does not answer is
    refused naming ``device`` and why; ``connected=False`` adds it as not connected (the rig defined before the
    hardware is plugged in): only its settings are checked, and it is listed as not connected until it answers."""
    if frame.device:
        if connected:
            check_device(frame.device)
        else:
            check_settings(frame.device)
    frame.not_connected = bool(frame.device) and not connected
    return session.add_sensor(frame)


def edit_sensor(session: Session, sensor: str, edit: SensorEdit, *, preview: bool = False) -> SensorChange:
    """Change a sensor's mounting guess, parent, mount sigma or device and re-fit the tree (``preview``: only say
    what would move). A new parent without a pose keeps the sensor where it is now."""
    if edit.device is not None:
        check_device(edit.device)
    with session.lock:
        rig = copy.deepcopy(session.rig)
        apply_edit(rig, sensor, edit)

        def write(fitted: Callable[[Rig], None]) -> None:
            def apply(live: Rig) -> None:
                apply_edit(live, sensor, edit)
                fitted(live)
            session.edit_rig(apply)

        return _sensor_change(session, sensor, "edit", rig, session.accepted_slots(), None if preview else write)


def remove_sensor(session: Session, sensor: str, *, preview: bool = False) -> SensorChange:
    """Take a sensor out of the rig: the slots that hold it are emptied (their results stay in the history), the
    tree is re-fitted without its edges and its captures are moved aside, restorable (:func:`restore_sensor`).
    A sensor other frames hang from is refused, naming them. ``preview``: only say what would move."""
    with session.lock:
        accepted = session.accepted_slots()
        emptied = slots_involving(sensor, accepted, {r: session.result(r) for r in accepted.values()})
        rig = copy.deepcopy(session.rig)
        rig.remove(sensor)
        return _sensor_change(session, sensor, "remove", rig,
                              {s: r for s, r in accepted.items() if s not in emptied},
                              None if preview else lambda fitted: session.remove_sensor(sensor, emptied, fitted),
                              emptied=emptied)


def restore_sensor(session: Session, removal_id: str, *, preview: bool = False) -> SensorChange:
    """Put a removed sensor back with its captures, and make current again each slot it emptied whose frames are
    all in the rig and which nothing else has filled since (the others are named in ``not_restored``)."""
    with session.lock:
        removal = session.restorable(removal_id)
        rig = copy.deepcopy(session.rig)
        rig.add(frame_from_model(removal.frame))
        accepted = session.accepted_slots()
        restored, not_restored = [], {}
        for slot, result_id in removal.slots.items():
            missing = frames_missing(session.result(result_id), rig)
            if slot in accepted:
                not_restored[slot] = f"{accepted[slot]} has been accepted for it since"
            elif missing:
                not_restored[slot] = f"the rig no longer holds {', '.join(missing)}"
            else:
                restored.append(slot)
        return _sensor_change(session, removal.sensor, "restore", rig,
                              accepted | {slot: removal.slots[slot] for slot in restored},
                              None if preview else lambda fitted: session.restore_sensor(removal_id, restored, fitted),
                              restored=restored, not_restored=not_restored, removal=removal.model_dump(mode="json"))
