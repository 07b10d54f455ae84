"""Live frames at the rate the page keeps up with: the newest frame waits, older ones are dropped.

A page drawing point clouds with WebGL in software paints a few frames a second. Frames sent faster than that
queue in its message handler, and a click's answer (the button that turns into *Start live*, a capture's count)
waits behind them: *Stop live* once took 50 s on a loaded machine. The pacer holds at most one frame per key (a
sensor) that is not yet sent, a newer frame replacing it, and sends the next batch only when every open page has
answered a round trip queued after the previous batch. The round trip is a localStorage read, which the page
handles in order with the scene's messages, so no page is ever more than one batch behind. After each round trip
the page is left alone for as long as the round trip took (up to :data:`MAX_REST_S`), so it spends at least half
its time free for clicks: a page that takes 300 ms over a batch gets about 1.7 batches a second, a page on a GPU
every frame the sensors give.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

import viser

log = logging.getLogger(__name__)

Frame = TypeVar("Frame")

ACK_KEY = "calib-studio-frame-ack"
"""The localStorage key the round trip reads (never written: the answer is ``None``)."""
ACK_TIMEOUT_S = 5.0
"""Longest wait for one page's answer; a page that stays connected but never answers is drawn for at this pace."""
MAX_REST_S = 1.0
"""Longest pause after a batch (s), however slow the page was over it."""
RATE_WINDOW_S = 2.0
"""The draw rate is counted over the last this many seconds."""


class FramePacer(Generic[Frame]):
    """Hands the newest frame of each key to ``draw`` (on the pacer's thread), one batch per page round trip."""

    def __init__(self, server: viser.ViserServer, draw: Callable[[str, Frame], None], name: str = "frames"):
        self.server = server
        self.draw = draw
        self.name = name
        self._pending: dict[str, Frame] = {}
        self._drawn_at: dict[str, list[float]] = {}
        self.dropped = 0
        """Frames replaced by a newer one before they were sent."""
        self._wake = threading.Condition()
        self._running = False
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        """Start drawing offered frames (a no-op while running)."""
        with self._wake:
            if self._running:
                return
            self._running = True
            self._pending.clear()
            self._drawn_at.clear()
            self.dropped = 0
        self._thread = threading.Thread(target=self._run, name=f"pace-{self.name}", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Drop what waits and end the thread (it ends after the batch being sent, if any; never waits for it)."""
        with self._wake:
            self._running = False
            self._pending.clear()
            self._wake.notify_all()

    def offer(self, key: str, frame: Frame) -> None:
        """The newest frame of ``key``: sent with the next batch, replacing one of its own still waiting."""
        with self._wake:
            if not self._running:
                return
            if key in self._pending:
                self.dropped += 1
            self._pending[key] = frame
            self._wake.notify_all()

    def rate_hz(self, key: str) -> float:
        """Frames of ``key`` sent per second over the last :data:`RATE_WINDOW_S`."""
        now = time.monotonic()
        with self._wake:
            recent = [t for t in self._drawn_at.get(key, []) if now - t <= RATE_WINDOW_S]
        return len(recent) / RATE_WINDOW_S

    def _run(self) -> None:
        while True:
            with self._wake:
                while self._running and not self._pending:
                    self._wake.wait()
                if not self._running:
                    return
                batch, self._pending = self._pending, {}
            started = time.monotonic()
            for key, frame in batch.items():
                self.draw(key, frame)
            self._record(batch)
            self._wait_for_pages()
            rest_s = min(time.monotonic() - started, MAX_REST_S)
            with self._wake:  # the page's free time; newer frames replace the waiting ones meanwhile
                self._wake.wait_for(lambda: not self._running, timeout=rest_s)

    def _record(self, batch: dict[str, Frame]) -> None:
        now = time.monotonic()
        with self._wake:
            for key in batch:
                times = self._drawn_at.setdefault(key, [])
                times.append(now)
                del times[:-int(4 * RATE_WINDOW_S * 60)]  # bounded: at most 60 Hz is ever counted

    def _wait_for_pages(self) -> None:
        """Return once every connected page has handled what was sent before (or its wait timed out)."""
        for client in list(self.server.get_clients().values()):
            try:
                client.local_storage.get_item(ACK_KEY, timeout=ACK_TIMEOUT_S)
            except TimeoutError:
                log.warning("%s: a page did not answer within %.0f s; drawing on", self.name, ACK_TIMEOUT_S)
            except RuntimeError:  # the page left, or its browser blocks localStorage: nothing to wait for
                pass
