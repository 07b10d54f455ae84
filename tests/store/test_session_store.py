"""The session store: safe names, write-once captures and results, acceptance, schema checks, atomic saves."""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import numpy as np
import pytest

from backend.calib.intrinsics import service
from backend.calib.rig import service as rig_service
from backend.core.errors import InputError, NotFoundError
from backend.core.rig import Frame
from backend.store.schema import SCHEMA_VERSION
from backend.store.session import SESSION_FILE, Session, SessionStore

BOARD = "checkerboard:9x6:0.025"


def camera_record(fx: float) -> dict:
    """A stored intrinsics result as the solver would write it (only what accept() reads)."""
    return {
        "kind": "intrinsics",
        "camera": {"model": "pinhole-radtan", "width": 640, "height": 480,
                   "K": [[fx, 0.0, 320.0], [0.0, fx, 240.0], [0.0, 0.0, 1.0]],
                   "dist": [-0.3, 0.1, 0.001, 0.0005, 0.0]},
        "rms_px": 0.25,
        "verdict": {"level": "trusted", "reasons": ["a test record"]},
    }


def image(value: int) -> np.ndarray:
    img = np.full((48, 64, 3), value, np.uint8)
    img[10:20, 10:30] = 255 - value
    return img


@pytest.fixture
def store(tmp_path: Path) -> SessionStore:
    return SessionStore(tmp_path / "sessions")


@pytest.fixture
def session(store: SessionStore) -> Session:
    s = store.create("rig1", board=BOARD, title="bench")
    s.add_sensor(Frame("cam", "base_link", kind="camera"))
    return s


# -- create / get / names -------------------------------------------------------------------


def test_create_and_get(store: SessionStore):
    created = store.create("robot-2026_a", board=BOARD, title="t")
    assert (store.root / "robot-2026_a" / SESSION_FILE).is_file()
    assert store.get("robot-2026_a") is created
    assert store.names() == ["robot-2026_a"]
    info = created.info()
    assert info["name"] == "robot-2026_a" and info["board"] == BOARD and info["title"] == "t"
    # a fresh store reads it back from disk
    reopened = SessionStore(store.root).get("robot-2026_a")
    assert reopened is not created and reopened.info()["board"] == BOARD


def test_duplicate_session_is_409(store: SessionStore):
    store.create("dup")
    with pytest.raises(InputError) as err:
        store.create("dup")
    assert err.value.status_code == 409 and "dup" in err.value.message


def test_unknown_session_is_not_found(store: SessionStore):
    with pytest.raises(NotFoundError) as err:
        store.get("nothing-here")
    assert err.value.status_code == 404


@pytest.mark.parametrize("name", ["../x", "a/b", "..", "", "a" * 65, ".hidden", "x\\y", "/abs"])
def test_escaping_or_bad_names_rejected(store: SessionStore, tmp_path: Path, name: str):
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    with pytest.raises(InputError) as err:
        store.create(name)
    assert err.value.input == "session"
    with pytest.raises(InputError):
        store.get(name)
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before


def test_sixty_four_char_name_is_fine(store: SessionStore):
    name = "a" * 64
    store.create(name)
    assert store.names() == [name]


def test_bad_sensor_name_rejected(session: Session):
    with pytest.raises(InputError):
        session.add_sensor(Frame("../cam", "base_link", kind="camera"))
    assert "../cam" not in session.rig.frames


# -- captures -------------------------------------------------------------------------------


def capture(session: Session, value: int):
    return session.add_capture("cam", image(value), {"timestamp_s": float(value), "device": "test"})


def test_captures_are_write_once(session: Session):
    folder = session.path / "captures" / "cam"
    first, second = capture(session, 10), capture(session, 20)
    assert first.id != second.id
    for c in (first, second):
        assert (folder / f"{c.id}.png").is_file() and (folder / f"{c.id}.json").is_file()
    first_png = (folder / f"{first.id}.png").read_bytes()
    np.testing.assert_array_equal(session.capture_image("cam", first.id), image(10))
    np.testing.assert_array_equal(session.capture_image("cam", second.id), image(20))

    # losing a metadata file must not make the store reuse that id and overwrite the image
    (folder / f"{first.id}.json").unlink()
    third = capture(session, 30)
    assert third.id not in (first.id, second.id)
    assert (folder / f"{first.id}.png").read_bytes() == first_png
    np.testing.assert_array_equal(session.capture_image("cam", second.id), image(20))
    np.testing.assert_array_equal(session.capture_image("cam", third.id), image(30))

    # even with every metadata file gone, no existing image is replaced
    for meta in folder.glob("*.json"):
        meta.unlink()
    pngs = {p.name: p.read_bytes() for p in folder.glob("*.png")}
    fourth = capture(session, 40)
    assert f"{fourth.id}.png" not in pngs
    for name, data in pngs.items():
        assert (folder / name).read_bytes() == data
    assert not list(folder.glob(".*.tmp"))


def test_capture_records_round_trip(session: Session):
    c = capture(session, 50)
    records = session.captures("cam")
    assert [r.id for r in records] == [c.id]
    assert records[0].image_size == (64, 48) and records[0].device == "test"


def test_capture_for_unknown_sensor(session: Session):
    with pytest.raises(NotFoundError):
        session.add_capture("nope", image(1), {"timestamp_s": 0.0, "device": "x"})
    assert not (session.path / "captures" / "nope").exists()


def test_capture_id_cannot_escape(session: Session):
    with pytest.raises(InputError):
        session.capture_image("cam", "../../session")


# -- results and acceptance -----------------------------------------------------------------


def test_result_ids_increase(session: Session):
    r1 = session.add_result("cam", camera_record(500.0), inputs=["00001"])
    r2 = session.add_result("cam", camera_record(510.0), inputs=["00001", "00002"])
    assert (r1, r2) == ("r0001", "r0002")
    assert session.result("r0001")["camera"]["K"][0][0] == 500.0
    assert session.result("r0002")["inputs"] == ["00001", "00002"]
    assert [r["id"] for r in session.results(sensor="cam", kind="intrinsics")] == ["r0001", "r0002"]
    assert session.results(sensor="other") == []
    with pytest.raises(NotFoundError):
        session.result("r0003")


def test_accept_revert_and_reload(session: Session):
    r1 = session.add_result("cam", camera_record(500.0), inputs=[])
    r2 = session.add_result("cam", camera_record(520.0), inputs=[])

    rig_service.accept(session, r2)
    assert session.rig.get("cam").intrinsics.K[0, 0] == 520.0
    on_disk = json.loads((session.path / SESSION_FILE).read_text())
    assert on_disk["accepted"] == {"cam/intrinsics": r2}
    assert [e["result_id"] for e in on_disk["acceptance_log"]] == [r2]
    cam = next(f for f in on_disk["rig"]["frames"] if f["name"] == "cam")
    assert cam["intrinsics"]["K"][0][0] == 520.0

    # revert: accept the earlier one; the log keeps both steps
    rig_service.accept(session, r1)
    assert session.rig.get("cam").intrinsics.K[0, 0] == 500.0
    assert session.accepted("cam/intrinsics") == r1
    on_disk = json.loads((session.path / SESSION_FILE).read_text())
    assert on_disk["accepted"] == {"cam/intrinsics": r1}
    assert [(e["slot"], e["result_id"]) for e in on_disk["acceptance_log"]] == [
        ("cam/intrinsics", r2), ("cam/intrinsics", r1)]
    assert on_disk["acceptance_log"][0]["at"] <= on_disk["acceptance_log"][1]["at"]
    # both results are still there, unchanged
    assert session.result(r2)["camera"]["K"][0][0] == 520.0

    reopened = Session.load(session.path)
    assert reopened.rig.get("cam").kind == "camera"
    np.testing.assert_allclose(reopened.rig.get("cam").intrinsics.K, session.rig.get("cam").intrinsics.K)
    np.testing.assert_allclose(reopened.rig.get("cam").intrinsics.dist, [-0.3, 0.1, 0.001, 0.0005, 0.0])
    assert reopened.accepted("cam/intrinsics") == r1
    assert [(a.slot, a.result_id) for a in reopened.acceptance_log] == [("cam/intrinsics", r2),
                                                                         ("cam/intrinsics", r1)]
    assert reopened.board == BOARD


def test_accept_result_of_another_sensor_rejected(session: Session):
    session.add_sensor(Frame("cam2", "base_link", kind="camera"))
    rid = session.add_result("cam2", camera_record(500.0), inputs=[])
    with pytest.raises(InputError) as err:
        service.intrinsics_result(session, "cam", rid)  # what the accept route checks first
    assert "cam2" in err.value.message
    assert session.rig.get("cam").intrinsics is None and session.accepted("cam/intrinsics") is None


# -- loading damaged or foreign session files -----------------------------------------------


def test_corrupt_session_json(session: Session):
    file = session.path / SESSION_FILE
    text = file.read_text()
    file.write_text(text[: len(text) // 2])
    with pytest.raises(InputError) as err:
        Session.load(session.path)
    assert err.value.input == str(file)
    assert str(file) in err.value.message and "corrupt" in err.value.message


def test_missing_session_json_is_not_found(tmp_path: Path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(NotFoundError) as err:
        Session.load(tmp_path / "empty")
    assert SESSION_FILE in err.value.message


def test_wrong_schema_version(session: Session):
    file = session.path / SESSION_FILE
    raw = json.loads(file.read_text())
    raw["schema_version"] = SCHEMA_VERSION + 1
    file.write_text(json.dumps(raw))
    with pytest.raises(InputError) as err:
        Session.load(session.path)
    assert "schema_version" in err.value.message and str(SCHEMA_VERSION + 1) in err.value.message
    assert err.value.input == str(file)


def test_three_by_three_transform_names_the_field(session: Session):
    file = session.path / SESSION_FILE
    raw = json.loads(file.read_text())
    index = next(i for i, f in enumerate(raw["rig"]["frames"]) if f["name"] == "cam")
    raw["rig"]["frames"][index]["T_parent_child"] = np.eye(3).tolist()
    file.write_text(json.dumps(raw))
    with pytest.raises(InputError) as err:
        Session.load(session.path)
    assert f"rig.frames.{index}.T_parent_child" in err.value.message
    assert "4x4" in err.value.message and str(file) in err.value.message


# -- atomic save ----------------------------------------------------------------------------


def test_crash_during_save_keeps_old_file(session: Session, monkeypatch: pytest.MonkeyPatch):
    file = session.path / SESSION_FILE
    before = file.read_bytes()

    def crash(src, dst):
        raise OSError("simulated crash during rename")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError, match="simulated crash"):
        session.set_board("checkerboard:7x5:0.03")
    monkeypatch.undo()

    assert file.read_bytes() == before
    assert json.loads(before)["board"] == BOARD
    assert sorted(p.name for p in session.path.iterdir()) == [SESSION_FILE]
    assert Session.load(session.path).board == BOARD


def test_failed_accept_leaves_memory_as_on_disk(tmp_path, monkeypatch):
    """A save that fails must not leave the open session believing the change happened."""
    from backend.core.camera import CameraIntrinsics

    session = SessionStore(tmp_path).create("s")
    session.add_sensor(Frame("cam", "base_link", kind="camera"))
    camera = CameraIntrinsics("pinhole-radtan", 640, 480, np.diag([500.0, 500.0, 1.0]))
    result_id = session.add_result("cam", {"kind": "intrinsics", "camera": camera.to_dict()}, inputs=[])

    def broken_replace(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        session.accept("cam/intrinsics", result_id, service.apply_intrinsics, confirm=True)
    with pytest.raises(OSError, match="disk full"):
        session.set_board("checkerboard:9x6:0.025")
    assert session.accepted("cam/intrinsics") is None
    assert session.rig.get("cam").intrinsics is None
    assert session.board is None
    assert session.acceptance_log == []


def test_a_removal_a_crash_interrupted_is_finished_when_the_session_opens(tmp_path):
    """The removal is in session.json before the captures move; a crash between the two loses nothing, and the
    next open moves them. The same for a restore."""
    store = SessionStore(tmp_path)
    session = store.create("s", board=BOARD)
    session.add_sensor(Frame("cam", "base_link", kind="camera"))
    capture = session.add_capture("cam", image(40), {"timestamp_s": 1.0, "device": "test"})
    removal = rig_service.remove_sensor(session, "cam").removal["id"]
    live, aside = tmp_path / "s" / "captures" / "cam", tmp_path / "s" / "removed" / removal / "captures"
    assert aside.is_dir() and not live.exists()

    os.replace(aside, live)  # as if the process died after writing session.json, before moving the folder
    reopened = Session.load(tmp_path / "s")
    assert aside.is_dir() and not live.exists()
    assert reopened.removed()[0]["captures"] == 1

    rig_service.restore_sensor(reopened, removal)
    assert live.is_dir() and not aside.exists()
    os.replace(live, aside)  # died after the restore was written, before the folder came back
    again = Session.load(tmp_path / "s")
    assert [c.id for c in again.captures("cam")] == [capture.id]


def test_two_accepts_of_one_result_at_once_record_one(session: Session):
    """Two tabs (or a double click) accept the same result together: both answer, one accept is logged."""
    from concurrent.futures import ThreadPoolExecutor

    result_id = session.add_result("cam", camera_record(500.0), inputs=[])
    with ThreadPoolExecutor(max_workers=2) as pool:
        updates = list(pool.map(lambda _: rig_service.accept(session, result_id), range(2)))
    assert [u.result_id for u in updates] == [result_id, result_id]
    assert [(e.slot, e.result_id) for e in session.acceptance_log] == [("cam/intrinsics", result_id)]
    other = session.add_result("cam", camera_record(510.0), inputs=[])
    rig_service.accept(session, other)
    rig_service.accept(session, result_id)  # going back to it is a new accept
    assert [e.result_id for e in session.acceptance_log] == [result_id, other, result_id]


def test_change_listeners_hear_every_saved_change_once_with_the_lock_released(tmp_path):
    """What lets an open studio page follow an edit made through the API: each saved change (an edit, an accept,
    a nested one counted once) calls the session's listeners after its lock is released; a failed one does not."""
    session = SessionStore(tmp_path).create("s")
    heard: list[tuple[int, bool]] = []

    def elsewhere() -> None:  # another thread (a page's handler, a request) can take the session meanwhile
        took = session.lock.acquire(timeout=5)
        heard.append((session.revision, took))
        if took:
            session.lock.release()

    def listener() -> None:
        thread = threading.Thread(target=elsewhere)
        thread.start()
        thread.join()

    stop = session.on_change(listener)
    session.add_sensor(Frame("cam", "base_link", kind="camera"))
    session.edit_rig(lambda rig: session.set_device("cam", {"driver": "folder", "path": "x"}))  # nested: once
    with pytest.raises(InputError):
        session.add_sensor(Frame("cam", "base_link", kind="camera"))  # a repeated name: nothing saved
    assert heard == [(1, True), (3, True)]
    stop()
    session.add_sensor(Frame("cam2", "base_link", kind="camera"))
    assert len(heard) == 2 and session.revision == 4
