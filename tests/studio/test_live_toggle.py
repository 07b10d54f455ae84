"""The live Start / Stop pair (studio.live_toggle) against streams that end on their own, in any order."""

from __future__ import annotations

import threading
from dataclasses import dataclass

from studio.live_toggle import WATCH_PERIOD_S, LiveToggle
from tests.conftest import poll


@dataclass
class FakeButton:
    visible: bool


class FakeStream:
    """Stands in for a SensorStream: ``running`` until :meth:`end`; counts how often the watcher looked."""

    def __init__(self, running: bool = True):
        self._running, self.looks = running, 0

    @property
    def running(self) -> bool:
        self.looks += 1
        return self._running

    def end(self) -> None:
        self._running = False


def _toggle() -> tuple[LiveToggle, FakeButton, FakeButton, list]:
    ended: list = []
    start, stop = FakeButton(True), FakeButton(False)
    return LiveToggle(start, stop, on_ended=ended.append), start, stop, ended


def _watchers() -> int:
    return sum(thread.name == "live-watch" and thread.is_alive() for thread in threading.enumerate())


def _settle(*running: FakeStream) -> None:
    """Wait until the watchers have acted on every change so far: each stream of ``running`` (one per run still
    watched) looked at twice more, and no other watcher left."""
    looks = [stream.looks + 2 for stream in running]
    poll(lambda: all(s.looks >= n for s, n in zip(running, looks, strict=True)) and _watchers() == len(running),
         lambda: f"{_watchers()} watchers left, {len(running)} expected", interval_s=WATCH_PERIOD_S / 4)


def test_a_stream_that_failed_before_the_click_returned_gives_start_back() -> None:
    toggle, start, stop, ended = _toggle()
    failed = FakeStream(running=False)  # its thread already ended, reporting the failure, before started()
    toggle.started([failed])
    _settle()
    assert (start.visible, stop.visible) == (True, False)
    assert ended == [(failed,)] and not toggle.live


def test_stop_shows_while_any_stream_runs() -> None:
    toggle, start, stop, ended = _toggle()
    a, b = FakeStream(), FakeStream()
    toggle.started([a, b])
    assert (start.visible, stop.visible) == (False, True) and toggle.live
    a.end()
    _settle(b)
    assert (start.visible, stop.visible) == (False, True) and ended == []
    b.end()
    _settle()
    assert (start.visible, stop.visible) == (True, False) and ended == [(a, b)]


def test_an_old_run_ending_late_leaves_the_new_run_alone() -> None:
    toggle, start, stop, ended = _toggle()
    old, new = FakeStream(), FakeStream()
    toggle.started([old])
    toggle.stopped()
    toggle.started([new])
    old.end()
    _settle(new)
    assert (start.visible, stop.visible) == (False, True) and ended == []
    toggle.stopped()
    new.end()
    _settle()
    assert (start.visible, stop.visible) == (True, False) and ended == [], "a stopped run is not reported as ended"


def test_the_buttons_agree_whichever_thread_moves_them() -> None:
    """Many runs ending on their own while the step starts and stops others: one of the two always shows."""
    toggle, start, stop, _ = _toggle()
    streams = [FakeStream() for _ in range(40)]
    enders = [threading.Timer(0.001 * i, s.end) for i, s in enumerate(streams)]
    for timer in enders:
        timer.start()
    for stream in streams:
        toggle.started([stream])
    for timer in enders:
        timer.join()
    _settle()
    assert (start.visible, stop.visible) == (True, False)
