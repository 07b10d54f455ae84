"""The live Start / Stop pair (studio.live_toggle) against streams that end on their own, in any order."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from studio.live_toggle import WATCH_PERIOD_S, LiveToggle


@dataclass
class FakeButton:
    visible: bool


class FakeStream:
    """Stands in for a SensorStream: ``running`` until :meth:`end`."""

    def __init__(self, running: bool = True):
        self.running = running

    def end(self) -> None:
        self.running = False


def _toggle() -> tuple[LiveToggle, FakeButton, FakeButton, list]:
    ended: list = []
    start, stop = FakeButton(True), FakeButton(False)
    return LiveToggle(start, stop, on_ended=ended.append), start, stop, ended


def _settle() -> None:
    time.sleep(3 * WATCH_PERIOD_S)


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
    _settle()
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
    _settle()
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
