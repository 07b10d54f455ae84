"""A session: one folder holding a rig, its captures and every solve result.

Layout::

    <root>/<name>/session.json                    rig, board, accepted results (atomic rewrite)
    <root>/<name>/captures/<sensor>/<id>.png      captured image, <id>.npy for a cloud, <id>.npz for a depth image
                                                  and its amplitude (write-once)
    <root>/<name>/captures/<sensor>/<id>.json     capture metadata (write-once)
    <root>/<name>/results/<id>.json               one solve result each (write-once)
    <root>/<name>/depth_network.json              a depth cell's layout, guided state, verification (atomic)
    <root>/<name>/survey.csv                      the test field's survey, as uploaded (atomic)
    <root>/<name>/surveys/survey-<n>.csv          each survey it replaced (write-once)
    <root>/<name>/quarantine/<same path>          a broken capture or result, moved aside
    <root>/<name>/quarantine/<folder>/<id>.why.json   why it was moved: file, moved, to, reason, at
    <root>/<name>/removed/<sensor>-<n>/captures/  a removed sensor's captures, until it is restored

Nothing is ever overwritten but ``session.json`` (and the survey, whose previous version is kept), and that only
atomically, so
captures and results survive crashes, and accepting an older result (revert) is
just another entry in the acceptance log.

One broken file never breaks more than itself: a capture or result that cannot be read
is moved to ``quarantine/`` (never deleted, its id never reused), reported by name with
a 422, and left out of listings, which list it under :meth:`Session.quarantined`. A
session whose ``session.json`` cannot be read stays where it is and is listed as broken
with its reason (:meth:`SessionStore.listing`) so the user can repair it.

Removing a sensor deletes nothing either (:meth:`Session.remove_sensor`): ``session.json`` records the removal
(the frame as it was, the slots it emptied, the sensor's results) first, then the captures folder moves aside;
a move that a crash interrupted is finished when the session is next opened (:meth:`Session._settle_removals`).
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import logging
import os
import re
import threading
import time
import zipfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from backend.core.depth import stored_intrinsics
from backend.core.errors import InputError, NotFoundError
from backend.core.imu import ImuSamples
from backend.core.limits import MAX_IMAGE_PIXELS
from backend.core.rig import Frame, Rig
from backend.core.test_field import SESSION_SURVEY, parse_survey
from backend.core.verdict import Verdict
from backend.devices.image_io import encode_png, read_image
from backend.store.atomic import remove_stale_temp_files, write_bytes_atomic, write_json_atomic
from backend.store.rig_io import frame_from_model, frame_to_model, rig_from_model, rig_to_model
from backend.store.schema import (
    DEPTH_NETWORK_VERSION,
    FILE_NAME_PATTERN,
    NAME_PATTERN,
    SCHEMA_VERSION,
    Acceptance,
    CaptureRecord,
    DepthNetworkFile,
    Removal,
    SessionFile,
)

SESSION_FILE = "session.json"
DEPTH_NETWORK_FILE = "depth_network.json"
DEPTH_ARRAYS = ("depth", "amplitude")
"""The arrays of a depth capture's ``.npz``: depth along the optical axis (m, 0 = no return) and IR amplitude."""
QUARANTINE = "quarantine"
REMOVED = "removed"
_NOTE_SUFFIX = ".why.json"
IMU_SUFFIX = ".imu.npy"
"""An IMU capture's data file: an N x 7 float64 table (t, wx, wy, wz, ax, ay, az)."""


def _field_problem(error: ValidationError) -> str:
    """The first problem pydantic found, naming its field: ``field 'rig.frames.1.T_parent_child.0.3': ...``."""
    first = error.errors()[0]
    field = ".".join(str(p) for p in first["loc"]) or "(top level)"
    return f"field '{field}': {first['msg']}"


def _validation_message(shown: str, error: ValidationError) -> str:
    return f"{shown}: {_field_problem(error)}"


def check_file_name(name: str) -> str:
    """A file name kept inside a session folder: letters, digits, ``_``, ``-`` and one extension, no path."""
    if not re.fullmatch(FILE_NAME_PATTERN, name):
        raise InputError(f"invalid file name {name!r}: expected letters, digits, '_' or '-' and an extension such as "
                         "'.jpg'", "file")
    return name


def check_name(name: str, what: str) -> str:
    """Reject names that could escape a folder or break a file name."""
    if not re.match(NAME_PATTERN, name or ""):
        raise InputError(f"{what} {name!r} must be 1-64 letters, digits, '_' or '-', starting with a letter or digit",
                         what)
    return name


def read_bounded_npy(handle: Any, what: str, max_elements: int) -> np.ndarray:
    """One ``.npy`` array from an open binary file, its header checked before any data is read: a float or
    integer array of at most ``max_elements`` values, else :class:`ValueError` saying what it holds (so a
    crafted header cannot make the reader allocate gigabytes)."""
    version = np.lib.format.read_magic(handle)
    read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
    shape, _, dtype = read_header(handle)
    if dtype.kind not in "fiu" or dtype.hasobject:
        raise ValueError(f"{what} holds {dtype} values; expected numbers")
    if int(np.prod(shape, dtype=np.int64)) > max_elements:
        raise ValueError(f"{what} is an array of shape {shape}, more than {max_elements:,} values")
    handle.seek(0)
    return np.lib.format.read_array(handle, allow_pickle=False)


log = logging.getLogger(__name__)


class _ReleasingLock:
    """The session's re-entrant lock, which calls ``released()`` each time the thread holding it lets it go for
    good (its outermost ``with``), with the lock free: the session tells its change listeners then."""

    def __init__(self, released: Callable[[], None]):
        self.bare = threading.RLock()
        """The lock itself, without the call."""
        self._released = released
        self._depth = 0

    def acquire(self, blocking: bool = True, timeout: float = -1) -> bool:
        took = self.bare.acquire(blocking, timeout)
        self._depth += took
        return took

    def release(self) -> None:
        self._depth -= 1
        outermost = self._depth == 0
        self.bare.release()
        if outermost:
            self._released()

    def __enter__(self) -> _ReleasingLock:
        self.acquire()
        return self

    def __exit__(self, *_exc: object) -> None:
        self.release()


class Session:
    """An open session. Methods are thread-safe; the studio and the API share instances."""

    def __init__(self, path: Path, data: SessionFile, label: str | None = None):
        self.path = path
        self.label = str(path) if label is None else label
        """How messages name the session folder: the path a command was given, or the session's name for a server
        (whose messages never show where its sessions are kept)."""
        self._data = data
        self.rig: Rig = rig_from_model(data.rig)
        self.lock = _ReleasingLock(self._tell_listeners)
        self.revision = 0
        """Counts the changes saved since the session was opened (:meth:`on_change`)."""
        self._told_revision = 0
        self._change_listeners: list[Callable[[], None]] = []

    # -- the session file -------------------------------------------------------------
    @classmethod
    def load(cls, path: Path, label: str | None = None) -> Session:
        """Open a session folder, validating its schema and saying what is wrong (naming the folder as ``label``
        says, by default its path)."""
        label = str(path) if label is None else label
        file, shown = path / SESSION_FILE, f"{label}/{SESSION_FILE}"
        try:
            raw = json.loads(file.read_text())
        except FileNotFoundError:
            raise NotFoundError(f"no session at {label} (missing {SESSION_FILE})", label) from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{shown}: not valid JSON ({exc}); the file is corrupt", shown) from None
        except OSError as exc:
            raise InputError(f"{shown}: cannot read the file ({exc.strerror or exc})", shown) from None
        version = raw.get("schema_version") if isinstance(raw, dict) else None
        if version != SCHEMA_VERSION:
            raise InputError(f"{shown}: field 'schema_version' is {version!r}, expected {SCHEMA_VERSION}", shown)
        try:
            session = cls(path, SessionFile.model_validate(raw), label)
        except ValidationError as exc:
            raise InputError(_validation_message(shown, exc), shown) from None
        except InputError as exc:  # a rig that is valid JSON but not a tree (an unknown parent, a repeated name)
            raise InputError(f"{shown}: {exc.message}", shown) from None
        session._settle_removals()
        return session

    @classmethod
    def create(cls, path: Path, name: str, rig: Rig | None = None, board: str | None = None,
               title: str = "", label: str | None = None) -> Session:
        data = SessionFile(schema_version=SCHEMA_VERSION, name=name, title=title, created=time.time(),
                           board=board, rig=rig_to_model(rig or Rig()))
        path.mkdir(parents=True, exist_ok=False)
        session = cls(path, data, label)
        session.save()
        return session

    def save(self) -> None:
        """Write ``session.json`` atomically from the current rig and acceptance state."""
        with self.lock:
            try:
                self._data.rig = rig_to_model(self.rig)
            except ValidationError as exc:  # e.g. intrinsics holding a NaN: refused rather than written
                raise InputError(f"not saved: {_validation_message(self.shown(self.path / SESSION_FILE), exc)}",
                                 self.shown(self.path / SESSION_FILE)) from None
            write_json_atomic(self.path / SESSION_FILE, self._data.model_dump(mode="json"))

    def on_change(self, listener: Callable[[], None]) -> Callable[[], None]:
        """``listener()`` runs after changes to the rig or the accepted results are saved, whoever made them (the
        studio, the API): once the session's lock is let go by the thread that held it through them, on that
        thread, once for all the changes made while it held the lock. Returns what stops it."""
        self._change_listeners.append(listener)
        return lambda: self._change_listeners.remove(listener) if listener in self._change_listeners else None

    def _tell_listeners(self) -> None:
        """Run the :meth:`on_change` listeners if a change was saved since they last ran (the lock is free)."""
        with self.lock.bare:
            if self._told_revision == self.revision:
                return
            self._told_revision = self.revision
        for listener in list(self._change_listeners):
            try:
                listener()
            except Exception:  # noqa: BLE001 - a follower's failure must not undo or hide the saved change
                log.exception("a listener of session %s failed on its change", self.label)

    @contextlib.contextmanager
    def _change(self) -> Iterator[None]:
        """Apply a change and save it; if anything fails, memory goes back to what is on disk."""
        with self.lock:
            data, rig = self._data.model_copy(deep=True), copy.deepcopy(self.rig)
            try:
                yield
                self.save()
                self.revision += 1
            except BaseException:
                self._data, self.rig = data, rig
                raise

    @property
    def name(self) -> str:
        return self._data.name

    @property
    def title(self) -> str:
        return self._data.title

    @property
    def board(self) -> str | None:
        return self._data.board

    def set_board(self, spec: str) -> None:
        with self._change():
            self._data.board = spec

    @property
    def v_target(self) -> str | None:
        """The V-target's spec (:class:`~backend.core.v_target.VTarget`), or None."""
        return self._data.v_target

    def set_v_target(self, spec: str) -> None:
        with self._change():
            self._data.v_target = spec

    @property
    def test_field(self) -> str | None:
        """The spec of a wall test field beside the board (:class:`~backend.core.test_field.TestField`), or None."""
        return self._data.test_field

    def set_test_field(self, spec: str) -> None:
        with self._change():
            self._data.test_field = spec

    def set_survey(self, data: bytes, name: str) -> None:
        """Keep an uploaded test-field survey (``name`` for messages) as the session's :data:`SESSION_SURVEY`,
        after reading it (:func:`~backend.core.test_field.parse_survey`); a bad file changes nothing."""
        parse_survey(data, name)
        with self.lock:
            current = self.path / SESSION_SURVEY
            if current.exists():
                kept = self.path / "surveys"
                kept.mkdir(exist_ok=True)
                number = len(list(kept.glob("survey-*.csv"))) + 1
                write_bytes_atomic(kept / f"survey-{number}.csv", current.read_bytes(), exclusive=True)
            write_bytes_atomic(current, data)

    def info(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "title": self._data.title,
            "created": self._data.created,
            "board": self.board,
            "v_target": self.v_target,
            "test_field": self.test_field,
            "survey": (self.path / SESSION_SURVEY).exists(),
            "sensors": [f.name for f in self.rig.sensors()],
            "accepted": dict(self._data.accepted),
            "acceptance_log": [entry.model_dump() for entry in self._data.acceptance_log],
            "quarantined": self.quarantined(),
            "removed": self.removed(),
        }

    # -- quarantine -------------------------------------------------------------------
    def _note_path(self, file: Path) -> Path:
        """The note of the quarantined item ``file`` belongs to: the item is the session-relative path
        without extension (``results/r0003``, ``captures/cam/00002``), shared by its data and metadata."""
        return self.path / QUARANTINE / f"{file.relative_to(self.path).with_suffix('')}{_NOTE_SUFFIX}"

    def _quarantine(self, broken: Path, reason: str, *companions: Path) -> InputError:
        """Move ``broken`` and its ``companions`` (the item's other files or folder) to ``quarantine/`` at
        the same relative path, with a note saying why; return the 422 to raise. Nothing is deleted."""
        with self.lock:
            moves = [(f, self._quarantine_target(f)) for f in (broken, *companions) if f.exists()]
            if moves:
                write_json_atomic(self._note_path(broken), {
                    "file": str(broken.relative_to(self.path)),
                    "moved": [str(f.relative_to(self.path)) for f, _ in moves],
                    "to": [str(target.relative_to(self.path)) for _, target in moves],
                    "reason": reason, "at": time.time()})
                for file, target in moves:
                    target.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(file, target)
        return self._broken_error(broken, reason)

    def _quarantine_target(self, file: Path) -> Path:
        """Where ``file`` goes in ``quarantine/``: its own relative path, numbered if that is taken (an
        earlier quarantined copy is never overwritten)."""
        target = base = self.path / QUARANTINE / file.relative_to(self.path)
        number = 1
        while target.exists():
            target, number = base.with_name(f"{base.name}.{number}"), number + 1
        return target

    def shown(self, file: Path) -> str:
        """``file`` (in the session folder) as messages name it: ``<label>/<path in the session>``."""
        return f"{self.label}/{file.relative_to(self.path)}"

    def _broken_error(self, broken: Path, reason: str) -> InputError:
        return InputError(f"{self.shown(broken)}: {reason}; the file is broken and was moved to "
                          f"{self.shown(self.path / QUARANTINE / broken.relative_to(self.path))}", self.shown(broken))

    def _quarantined_error(self, file: Path) -> InputError | None:
        """The 422 for ``file``'s item if it was quarantined earlier, or None if it never was."""
        note = self._note_path(file)
        if not note.exists():
            return None
        try:
            record = json.loads(note.read_text())
            return self._broken_error(self.path / record["file"], record["reason"])
        except (OSError, ValueError, KeyError, TypeError):
            return self._broken_error(file, "unreadable (its quarantine note too)")

    def quarantined(self) -> list[dict[str, Any]]:
        """The notes of every quarantined item (``file``; ``moved`` from and ``to``, session-relative; ``reason``;
        ``at``, s since the epoch), oldest first."""
        notes = []
        for note in (self.path / QUARANTINE).rglob(f"*{_NOTE_SUFFIX}"):
            try:
                notes.append(json.loads(note.read_text()))
            except (OSError, ValueError):
                notes.append({"file": str(note.relative_to(self.path)), "moved": [], "to": [],
                              "reason": "unreadable note", "at": None})
        return sorted(notes, key=lambda n: (n.get("at") or 0.0, str(n.get("file"))))

    # -- sensors ----------------------------------------------------------------------
    def add_sensor(self, frame: Frame) -> Frame:
        check_name(frame.name, "sensor")
        with self._change():
            self.rig.add(frame)
        return frame

    def set_device(self, sensor: str, device: dict[str, Any]) -> None:
        """Replace a sensor's capture-device settings (a driver name and its options)."""
        with self._change():
            self.rig.get(sensor).device = copy.deepcopy(device)

    def device_answered(self, sensor: str) -> None:
        """The sensor's device answered (a stream opened it): one added as not connected is connected now."""
        with self.lock:
            frame = self.rig.frames.get(sensor)  # None if it was removed while its stream opened
            if frame is not None and frame.not_connected:
                with self._change():
                    frame.not_connected = False

    def edit_rig(self, apply: Callable[[Rig], None]) -> None:
        """Change the rig with ``apply(rig)`` in one saved change; if it raises, nothing changes."""
        with self._change():
            apply(self.rig)

    def remove_sensor(self, sensor: str, slots: Sequence[str], apply: Callable[[Rig], None]) -> Removal:
        """Take the leaf frame ``sensor`` out of the rig, empty its accepted ``slots`` and let ``apply(rig)`` re-fit
        the rest, in one saved change; then move its captures to ``removed/<id>/captures``.

        The removal is recorded first (the frame as it was, the emptied slots, the sensor's results, which its
        listings then leave out), so a crash before the move loses nothing: the next open finishes it.
        """
        with self.lock:
            frame = self.rig.get(sensor)
            with self._change():
                now = time.time()
                removal = Removal(id=self._new_removal_id(sensor), sensor=sensor, frame=frame_to_model(frame),
                                  slots={slot: self._data.accepted[slot] for slot in slots},
                                  results=[record["id"] for record in self.results(sensor)], at=now)
                self.rig.remove(sensor)
                for slot in slots:
                    self._empty(slot, now, note=f"{sensor} removed ({removal.id})")
                self._data.removals.append(removal)
                apply(self.rig)
            self._settle_removals()
            return removal.model_copy(deep=True)

    def restore_sensor(self, removal_id: str, slots: Sequence[str], apply: Callable[[Rig], None]) -> Removal:
        """Put a removed sensor back: its frame as it was, its captures, and those of its emptied ``slots`` the
        caller can restore (their results made current again); ``apply(rig)`` re-fits, all in one saved change.
        A name now taken or a parent no longer there is refused (409), naming it."""
        with self.lock:
            removal = self.restorable(removal_id)
            with self._change():
                now = time.time()
                self.rig.add(frame_from_model(removal.frame))
                for slot in slots:
                    result_id = removal.slots[slot]
                    self._data.accepted[slot] = result_id
                    verdict = Verdict.from_record(self.result(result_id)).level
                    self._data.acceptance_log.append(Acceptance(slot=slot, result_id=result_id, at=now, verdict=verdict,
                                                                note=f"{removal.sensor} restored ({removal.id})"))
                self._removal(removal_id).restored_at = now
                apply(self.rig)
            self._settle_removals()
            return self._removal(removal_id).model_copy(deep=True)

    def restorable(self, removal_id: str) -> Removal:
        """The removal ``removal_id`` (a copy) if its sensor can be restored now; else a 404 (no such removal) or a
        409 saying why not (restored already, its name taken, its parent gone)."""
        with self.lock:
            removal = self._removal(removal_id)
            if removal.restored_at is not None:
                raise InputError(f"removal {removal_id!r} was restored already", "removal", 409)
            if removal.sensor in self.rig.frames:
                raise InputError(f"cannot restore {removal.sensor!r}: a frame of that name is in the rig now; remove "
                                 "it first", "removal", 409)
            if removal.frame.parent not in self.rig.frames:
                raise InputError(f"cannot restore {removal.sensor!r}: its parent {removal.frame.parent!r} is not in "
                                 "the rig; restore or add it first", "removal", 409)
            return removal.model_copy(deep=True)

    def removed(self) -> list[dict[str, Any]]:
        """The sensors removed and not restored, oldest first: ``id``, ``sensor``, ``kind``, ``parent``, ``at``
        (s since the epoch), the ``slots`` they emptied, their ``results`` and how many ``captures`` were kept."""
        return [{"id": r.id, "sensor": r.sensor, "kind": r.frame.kind, "parent": r.frame.parent, "at": r.at,
                 "slots": dict(r.slots), "results": list(r.results),
                 "captures": len(list(self._removed_captures(r).glob("*.json")))}
                for r in self._data.removals if r.restored_at is None]

    def _removal(self, removal_id: str) -> Removal:
        for removal in self._data.removals:
            if removal.id == removal_id:
                return removal
        raise NotFoundError(f"no removal {removal_id!r} in session {self.name!r}; removals: "
                            f"{[r.id for r in self._data.removals]}", "removal")

    def _new_removal_id(self, sensor: str) -> str:
        number = sum(r.sensor == sensor for r in self._data.removals) + 1
        while (self.path / REMOVED / f"{sensor}-{number}").exists():
            number += 1
        return f"{sensor}-{number}"

    def _removed_captures(self, removal: Removal) -> Path:
        return self.path / REMOVED / removal.id / "captures"

    def _settle_removals(self) -> None:
        """Move each removed sensor's captures aside, and each restored one's back, where ``session.json`` says
        the move should have happened and it has not (it runs after every removal and restore, and on open)."""
        with self.lock:
            for removal in self._data.removals:
                live, aside = self.path / "captures" / removal.sensor, self._removed_captures(removal)
                in_rig = removal.sensor in self.rig.frames
                source, target = (aside, live) if removal.restored_at is not None else (live, aside)
                if source.is_dir() and not target.exists() and in_rig == (removal.restored_at is not None):
                    target.parent.mkdir(parents=True, exist_ok=True)
                    os.replace(source, target)

    # -- captures ---------------------------------------------------------------------
    def _capture_dir(self, sensor: str) -> Path:
        self.rig.get(sensor)
        return self.path / "captures" / sensor

    def _add_capture_file(self, sensor: str, suffix: str, data: bytes, record: dict[str, Any]) -> CaptureRecord:
        """Store one capture's data and metadata under a fresh, never-reused id."""
        with self.lock:
            folder = self._capture_dir(sensor)
            folder.mkdir(parents=True, exist_ok=True)
            number = len(list(folder.glob("*.json"))) + 1
            while True:
                capture_id = f"{number:05d}"
                if self._note_path(folder / capture_id).exists():  # a quarantined id is never reused
                    number += 1
                    continue
                try:
                    write_bytes_atomic(folder / f"{capture_id}{suffix}", data, exclusive=True)
                    break
                except FileExistsError:
                    number += 1
            capture = CaptureRecord(id=capture_id, sensor=sensor, **record)
            write_json_atomic(folder / f"{capture_id}.json", capture.model_dump(mode="json"), exclusive=True)
            return capture

    def add_capture(self, sensor: str, image: np.ndarray, record: dict[str, Any]) -> CaptureRecord:
        """Store an image (as PNG) and its metadata."""
        return self._add_capture_file(sensor, ".png", encode_png(image),
                                      {**record, "image_size": (image.shape[1], image.shape[0])})

    def add_cloud_capture(self, sensor: str, points: np.ndarray, intensity: np.ndarray | None,
                          record: dict[str, Any]) -> CaptureRecord:
        """Store a point cloud (sensor frame, m) as an N x 4 float32 ``.npy`` (x, y, z, intensity or NaN)."""
        columns = [np.asarray(points, np.float32).reshape(-1, 3),
                   np.full((len(points), 1), np.nan, np.float32) if intensity is None
                   else np.asarray(intensity, np.float32).reshape(-1, 1)]
        buffer = io.BytesIO()
        np.save(buffer, np.hstack(columns), allow_pickle=False)
        return self._add_capture_file(sensor, ".npy", buffer.getvalue(), {**record, "n_points": len(points)})

    def add_imu_capture(self, sensor: str, imu: ImuSamples, record: dict[str, Any]) -> CaptureRecord:
        """Store a stretch of an IMU's stream as an N x 7 float64 ``.imu.npy`` (t s, rates rad/s, forces m/s²)."""
        buffer = io.BytesIO()
        np.save(buffer, np.column_stack([imu.t_s, imu.gyro_rad_s, imu.accel_m_s2]), allow_pickle=False)
        return self._add_capture_file(sensor, IMU_SUFFIX, buffer.getvalue(), {**record, "n_imu_samples": len(imu.t_s)})

    def imu_capture(self, sensor: str, capture_id: str) -> ImuSamples:
        """The samples of an IMU capture (:meth:`add_imu_capture`)."""
        data = self._capture_table(sensor, capture_id, IMU_SUFFIX, 7, "IMU capture", "N x 7 IMU table")
        return ImuSamples(data[:, 0], data[:, 1:4], data[:, 4:7])

    def captures(self, sensor: str, limit: int | None = None) -> list[CaptureRecord]:
        """The sensor's capture records, oldest first (only the first ``limit`` good ones, if given).

        A metadata file that cannot be read is quarantined with its data and left out.
        """
        records: list[CaptureRecord] = []
        for meta in sorted(self._capture_dir(sensor).glob("*.json")):
            if limit is not None and len(records) >= limit:
                break
            try:
                record = CaptureRecord.model_validate_json(meta.read_bytes())
                problem = None if (record.id, record.sensor) == (meta.stem, sensor) else (
                    f"holds capture {record.id!r} of sensor {record.sensor!r}, expected {meta.stem!r} of {sensor!r}")
            except ValidationError as exc:
                problem = _field_problem(exc)
            if problem is None:
                records.append(record)
            else:
                self._quarantine(meta, problem, *self._capture_data(meta))
        return records

    @staticmethod
    def _capture_data(meta: Path) -> tuple[Path, Path, Path, Path]:
        """The data files a capture's metadata file may sit beside (an image, a cloud, a depth image or IMU
        samples)."""
        return tuple(meta.with_suffix(suffix) for suffix in (".png", ".npy", ".npz", IMU_SUFFIX))

    def add_depth_capture(self, sensor: str, depth_m: np.ndarray, amplitude: np.ndarray,
                          record: dict[str, Any]) -> CaptureRecord:
        """Store a depth image (H, W: m along the optical axis, 0 = no return; NaN stored as 0) and its IR
        amplitude (H, W) as one compressed ``.npz``, so the pixel structure survives for the solvers; the
        record gets ``image_size`` and ``n_points`` (pixels with a return). At most
        :data:`~backend.core.limits.MAX_IMAGE_PIXELS` pixels."""
        depth = np.nan_to_num(np.asarray(depth_m, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        amplitude = np.nan_to_num(np.asarray(amplitude, dtype=np.float32), nan=0.0, posinf=0.0, neginf=0.0)
        if depth.ndim != 2 or depth.size == 0:
            raise InputError(f"a depth image is H x W metres; got an array of shape {depth.shape}", "depth")
        if amplitude.shape != depth.shape:
            raise InputError(f"the amplitude image is {amplitude.shape}; expected the depth image's {depth.shape}",
                             "amplitude")
        if depth.size > MAX_IMAGE_PIXELS.value():
            raise InputError(f"the depth image has {depth.size:,} px, more than {MAX_IMAGE_PIXELS.describe()}",
                             "depth", 413)
        buffer = io.BytesIO()
        np.savez_compressed(buffer, depth=depth, amplitude=amplitude)
        return self._add_capture_file(sensor, ".npz", buffer.getvalue(), {
            **record, "image_size": (depth.shape[1], depth.shape[0]), "n_points": int(np.count_nonzero(depth > 0))})

    def depth_capture(self, sensor: str, capture_id: str) -> tuple[np.ndarray, np.ndarray]:
        """Depth (H, W, float32 m along the optical axis, 0 = no return) and IR amplitude (H, W, float32) of a
        depth capture; one that cannot be read is quarantined with its metadata (422)."""
        check_name(capture_id, "capture")
        path = self._capture_dir(sensor) / f"{capture_id}.npz"
        if not path.exists():
            raise (self._quarantined_error(path)
                   or NotFoundError(f"no depth capture {capture_id!r} for sensor {sensor!r}", "capture"))
        try:
            with zipfile.ZipFile(path) as archive:
                arrays = []
                for name in DEPTH_ARRAYS:
                    with archive.open(f"{name}.npy") as handle:
                        arrays.append(read_bounded_npy(io.BytesIO(handle.read(64 << 20)), name,
                                                       MAX_IMAGE_PIXELS.value()))
            depth, amplitude = arrays
            if depth.ndim != 2 or amplitude.shape != depth.shape:
                raise ValueError(f"depth {depth.shape} and amplitude {amplitude.shape} are not one H x W image")
        except (ValueError, OSError, EOFError, KeyError, zipfile.BadZipFile) as exc:
            raise self._quarantine(path, f"not a readable depth + amplitude capture ({exc}); it may be truncated",
                                   path.with_suffix(".json")) from None
        return depth.astype(np.float32), amplitude.astype(np.float32)

    # -- the depth network ------------------------------------------------------------
    def depth_network(self) -> DepthNetworkFile:
        """The session's ``depth_network.json`` (a fresh, empty one if there is none). A file that cannot be
        read is quarantined (422 naming it, once): the rest of the session stays as it is, and the next read
        starts afresh."""
        path = self.path / DEPTH_NETWORK_FILE
        with self.lock:
            if not path.exists():
                return DepthNetworkFile()
            try:
                raw = json.loads(path.read_bytes())
                version = raw.get("schema_version") if isinstance(raw, dict) else None
                if version != DEPTH_NETWORK_VERSION:
                    raise self._quarantine(path, f"field 'schema_version' is {version!r}, expected "
                                                 f"{DEPTH_NETWORK_VERSION}")
                return DepthNetworkFile.model_validate(raw)
            except (OSError, ValueError) as exc:  # JSON and pydantic errors are ValueErrors
                if isinstance(exc, InputError):
                    raise
                reason = _field_problem(exc) if isinstance(exc, ValidationError) else f"not valid JSON ({exc})"
                raise self._quarantine(path, reason) from None

    def save_depth_network(self, state: DepthNetworkFile) -> None:
        """Write ``depth_network.json`` atomically."""
        with self.lock:
            write_json_atomic(self.path / DEPTH_NETWORK_FILE, state.model_dump(mode="json"))

    def set_root(self, root: str) -> None:
        """Rename the root of a rig that holds no other frame yet (a depth cell's rig is rooted at ``world``)."""
        check_name(root, "root")
        with self._change():
            if len(self.rig.frames) > 1:
                raise InputError(f"the rig already holds {sorted(set(self.rig.frames) - {self.rig.root})} under "
                                 f"{self.rig.root!r}; its root can only be renamed while it is empty", "root", 409)
            self.rig = Rig(root=root)

    def capture_cloud(self, sensor: str, capture_id: str) -> tuple[np.ndarray, np.ndarray | None]:
        """Points (N, 3) float64 in the sensor frame (m) and intensity (N,) (None if never recorded); a depth
        capture gives its valid pixels through the pinhole it was taken with, and their IR amplitude."""
        check_name(capture_id, "capture")
        path = self._capture_dir(sensor) / f"{capture_id}.npy"
        if not path.exists() and path.with_suffix(".npz").exists():
            record = CaptureRecord.model_validate_json(path.with_suffix(".json").read_bytes())
            depth, amplitude = self.depth_capture(sensor, capture_id)
            points, index = stored_intrinsics(record.meta).unproject(depth)
            return points, amplitude.ravel()[index]
        data = self._capture_table(sensor, capture_id, ".npy", 4, "cloud capture", "N x 4 float cloud")
        intensity = data[:, 3]
        return data[:, :3].astype(np.float64), None if np.all(np.isnan(intensity)) else intensity

    def _capture_table(self, sensor: str, capture_id: str, suffix: str, columns: int, what: str, shape: str
                       ) -> np.ndarray:
        """A capture's float table (N x ``columns``) from its ``suffix`` file; a missing one is a 404 naming it, a
        broken one is quarantined with its metadata and named."""
        check_name(capture_id, "capture")
        path = self._capture_dir(sensor) / f"{capture_id}{suffix}"
        if not path.exists():
            raise (self._quarantined_error(path)
                   or NotFoundError(f"no {what} {capture_id!r} for sensor {sensor!r}", "capture"))
        try:
            data = np.load(path, allow_pickle=False)
            if data.ndim != 2 or data.shape[1] != columns or data.dtype.kind != "f":
                raise ValueError(f"it holds a {data.dtype} array of shape {data.shape}")
        except (ValueError, OSError, EOFError) as exc:
            raise self._quarantine(path, f"not a readable {shape} ({exc}); it may be truncated",
                                   self._capture_dir(sensor) / f"{capture_id}.json") from None
        return data

    def capture_image(self, sensor: str, capture_id: str) -> np.ndarray:
        check_name(capture_id, "capture")
        path = self._capture_dir(sensor) / f"{capture_id}.png"
        if not path.exists():
            raise self._quarantined_error(path) or NotFoundError(f"no capture {capture_id!r} for sensor {sensor!r}",
                                                                 "capture")
        try:
            return read_image(path)
        except InputError as exc:
            raise self._quarantine(path, exc.message, path.with_suffix(".json")) from None

    # -- results ----------------------------------------------------------------------
    def add_result(self, sensor: str, record: dict[str, Any], inputs: list[str],
                   files: dict[str, bytes] | None = None) -> str:
        """Store a solve result as a new versioned record and return its id.

        ``files`` (name -> bytes, e.g. before/after overlay images) are kept beside it in
        ``results/<id>/`` and listed in the record's ``files``; they are written before the
        record, so a record never names a file that is not there.
        """
        files = files or {}
        for file_name in files:
            check_file_name(file_name)
        with self.lock:
            folder = self.path / "results"
            folder.mkdir(exist_ok=True)
            number = len(list(folder.glob("*.json"))) + 1
            while any(p.exists() for p in (folder / f"r{number:04d}.json", folder / f"r{number:04d}",
                                            self._note_path(folder / f"r{number:04d}"))):  # never reuse an id
                number += 1
            result_id = f"r{number:04d}"
            for file_name, data in files.items():
                (folder / result_id).mkdir(exist_ok=True)
                write_bytes_atomic(folder / result_id / file_name, data)
            full = {"id": result_id, "sensor": sensor, "created": time.time(), "inputs": inputs, **record}
            if files:
                full["files"] = sorted(files)
            write_json_atomic(folder / f"{result_id}.json", full, exclusive=True)
            return result_id

    def result_file(self, result_id: str, file_name: str) -> Path:
        """Path of a file stored with a result (:meth:`add_result`'s ``files``)."""
        check_file_name(file_name)
        if file_name not in self.result(result_id).get("files", []):
            raise NotFoundError(f"result {result_id!r} has no file {file_name!r}", "file")
        return self.path / "results" / result_id / file_name

    def results(self, sensor: str | None = None, kind: str | None = None) -> list[dict[str, Any]]:
        """All stored results, oldest first, optionally for one sensor and kind (broken ones quarantined and those
        of a removed sensor left out; :meth:`result` still reads both kinds' ids)."""
        removed = {result_id for r in self._data.removals if r.restored_at is None for result_id in r.results}
        out = []
        for path in sorted((self.path / "results").glob("r*.json")):
            if path.stem in removed:
                continue
            try:
                record = self._read_result(path)
            except InputError:
                continue
            if (sensor is None or record["sensor"] == sensor) and (kind is None or record.get("kind") == kind):
                out.append(record)
        return out

    def result(self, result_id: str) -> dict[str, Any]:
        check_name(result_id, "result")
        path = self.path / "results" / f"{result_id}.json"
        if not path.exists():
            raise (self._quarantined_error(path)
                   or NotFoundError(f"no result {result_id!r} in session {self.name!r}", "result"))
        return self._read_result(path)

    def _read_result(self, path: Path) -> dict[str, Any]:
        """One stored record; one that is not a JSON record of its own id and a sensor is quarantined (422)."""
        try:
            record = json.loads(path.read_bytes())
        except (OSError, ValueError) as exc:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
            raise self._quarantine(path, f"not valid JSON ({exc})", path.with_suffix("")) from None
        if not isinstance(record, dict) or record.get("id") != path.stem or not isinstance(record.get("sensor"), str):
            raise self._quarantine(path, f"not a result record (expected a JSON object with 'id': {path.stem!r} "
                                         "and a 'sensor')", path.with_suffix(""))
        return record

    def accepted(self, slot: str) -> str | None:
        return self._data.accepted.get(slot)

    def accepted_slots(self) -> dict[str, str]:
        """Every slot's current result id, the longest-standing acceptance first."""
        return dict(sorted(self._data.accepted.items(), key=lambda item: self.accepted_at(item[0])))

    def accepted_at(self, slot: str) -> float:
        """When the slot's current result was accepted (s since the epoch; 0 when the log does not say)."""
        times = [entry.at for entry in self._data.acceptance_log if entry.slot == slot and entry.result_id is not None]
        return times[-1] if times else 0.0

    @property
    def acceptance_log(self) -> list[Acceptance]:
        return list(self._data.acceptance_log)

    def accept(self, slot: str, result_id: str, apply: Callable[[Rig, dict[str, Any]], None],
               confirm: bool = False, revert: Sequence[str] = ()) -> bool:
        """Make ``result_id`` current for ``slot`` and empty the slots in ``revert`` in one change; then
        ``apply(rig, record)`` writes it into the rig (it sees the slots as they now are).

        The result's verdict decides (:mod:`backend.core.verdict`): a ``reject`` is refused, a ``check``
        is taken only with ``confirm`` (the user saw its reasons), and the log records the verdict and the
        confirmation. Accepting an older result is how a user reverts; the log keeps every step. Accepting the
        result the slot already holds (two clicks, two tabs) changes nothing and logs nothing: False.
        """
        record = self.result(result_id)
        verdict = Verdict.from_record(record)
        reasons = "; ".join(verdict.reasons) or "no reason given"
        if verdict.level == "reject":
            raise InputError(f"result {result_id} was judged 'reject' and cannot be accepted: {reasons}",
                             "result", 409)
        if verdict.level == "check" and not confirm:
            raise InputError(f"result {result_id} was judged 'check' ({reasons}); confirm to accept it as it is",
                             "confirm", 409)
        with self.lock:
            if self._data.accepted.get(slot) == result_id and not revert:
                return False
            with self._change():
                now = time.time()
                for other in revert:
                    self._empty(other, now)
                self._data.accepted[slot] = result_id
                self._data.acceptance_log.append(Acceptance(slot=slot, result_id=result_id, at=now,
                                                            verdict=verdict.level,
                                                            confirmed=verdict.level == "check"))
                apply(self.rig, record)
        return True

    def revert(self, slot: str, apply: Callable[[Rig], None]) -> None:
        """Empty ``slot`` (its result stays in the history) and let ``apply(rig)`` bring the rig up to date."""
        with self._change():
            self._empty(slot, time.time())
            apply(self.rig)

    def _empty(self, slot: str, at: float, note: str | None = None) -> None:
        if slot not in self._data.accepted:
            raise NotFoundError(f"nothing is accepted for {slot!r}; accepted: {sorted(self._data.accepted)}", "slot")
        del self._data.accepted[slot]
        self._data.acceptance_log.append(Acceptance(slot=slot, result_id=None, at=at, note=note))


class SessionStore:
    """All sessions under one root folder, opened once and shared."""

    def __init__(self, root: Path):
        """Open the store at ``root`` (created if missing), clearing temp files that killed writes left."""
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        remove_stale_temp_files(self.root)
        self._open: dict[str, Session] = {}
        self._lock = threading.Lock()

    def names(self) -> list[str]:
        return sorted(p.name for p in self.root.iterdir() if (p / SESSION_FILE).exists())

    def listing(self) -> list[dict[str, Any]]:
        """Every session: its :meth:`Session.info` with ``"broken": None``, or, for one that cannot be opened,
        ``{"name", "broken": {"message", "input"}}``. One broken session never hides the others."""
        entries = []
        for name in self.names():
            try:
                entries.append({**self.get(name).info(), "broken": None})
            except InputError as exc:
                entries.append({"name": name, "broken": exc.to_dict()})
        return entries

    def get(self, name: str) -> Session:
        check_name(name, "session")
        with self._lock:
            if name not in self._open:
                self._open[name] = Session.load(self.root / name, label=name)
            return self._open[name]

    def create(self, name: str, rig: Rig | None = None, board: str | None = None, title: str = "") -> Session:
        check_name(name, "session")
        with self._lock:
            if (self.root / name).exists():
                raise InputError(f"a session named {name!r} already exists", "name", 409)
            session = Session.create(self.root / name, name, rig, board, title, label=name)
            self._open[name] = session
            return session
