"""The live-frame pacer: one batch per page round trip, the newest frame of each key, the rest dropped."""

from __future__ import annotations

import threading
from types import SimpleNamespace

from studio.frame_pacer import ACK_KEY, FramePacer
from tests.conftest import poll


class SlowPage:
    """A page whose answers to the pacer's round trip wait until the test lets one through."""

    def __init__(self) -> None:
        self.asked = threading.Semaphore(0)
        self.answer = threading.Semaphore(0)
        self.local_storage = SimpleNamespace(get_item=self.get_item)

    def get_item(self, key: str, timeout: float | None = None) -> str | None:
        assert key == ACK_KEY
        self.asked.release()
        assert self.answer.acquire(timeout=30), "the test never answered"
        return None


def test_frames_wait_for_the_page_and_only_the_newest_is_sent() -> None:
    page = SlowPage()
    server = SimpleNamespace(get_clients=lambda: {1: page})
    drawn: list[tuple[str, int]] = []
    pacer: FramePacer[int] = FramePacer(server, lambda key, frame: drawn.append((key, frame)), "test")
    pacer.offer("a", 0)  # before start: ignored
    pacer.start()
    pacer.offer("a", 1)
    assert page.asked.acquire(timeout=30)  # batch 1 sent, its round trip waits on the page
    assert drawn == [("a", 1)]
    for frame in (2, 3, 4):  # the page is behind: each replaces the last
        pacer.offer("a", frame)
    pacer.offer("b", 10)
    assert drawn == [("a", 1)] and pacer.dropped == 2
    page.answer.release()  # the page caught up: the newest of each key goes, once
    assert page.asked.acquire(timeout=30)
    assert drawn == [("a", 1), ("a", 4), ("b", 10)]
    assert pacer.rate_hz("a") > 0 and pacer.rate_hz("c") == 0
    pacer.stop()
    pacer.offer("a", 5)  # after stop: dropped, never drawn
    page.answer.release()
    poll(lambda: not pacer._thread.is_alive(), "the pacer's thread did not end after stop")
    assert drawn == [("a", 1), ("a", 4), ("b", 10)]


def test_a_page_that_left_or_blocks_storage_does_not_stall_the_frames() -> None:
    def gone(key: str, timeout: float | None = None) -> str | None:
        raise RuntimeError("localStorage request failed: the client disconnected before returning a response.")

    server = SimpleNamespace(get_clients=lambda: {1: SimpleNamespace(local_storage=SimpleNamespace(get_item=gone))})
    drawn: list[int] = []
    pacer: FramePacer[int] = FramePacer(server, lambda key, frame: drawn.append(frame), "test")
    pacer.start()
    for frame in range(3):
        poll(lambda: not pacer._pending, "the pacer did not send what waited")
        pacer.offer("a", frame)
    poll(lambda: drawn == [0, 1, 2], lambda: f"drawn {drawn}")
    pacer.stop()
