"""A step's Start / Stop pair for live streams, in one state whichever thread changes it.

Stop shows while any stream handed to :meth:`LiveToggle.started` runs, Start otherwise. A
stream that fails to open, or ends by itself (an unplugged device, the end of a recording),
gives Start back: a watcher thread sees every stream of the run end. Every change of the two
buttons happens under one lock, so a failure reported by a stream's own thread can never
interleave with the click that started it (interleaved, the page and the server could each
believe the other button was showing, and no reload would bring either back).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import viser

from backend.services.sensor_stream import SensorStream

WATCH_PERIOD_S = 0.2
"""How often the watcher looks whether the run's streams still run (s)."""


class LiveToggle:
    """Shows ``start_button`` or ``stop_button``; ``on_ended(streams)`` runs once a run has ended by itself."""

    def __init__(self, start_button: viser.GuiButtonHandle, stop_button: viser.GuiButtonHandle,
                 on_ended: Callable[[tuple[SensorStream, ...]], None] | None = None):
        self.start_button = start_button
        self.stop_button = stop_button
        self.on_ended = on_ended
        self._lock = threading.Lock()
        self._run: tuple[SensorStream, ...] = ()

    @property
    def live(self) -> bool:
        """True from :meth:`started` until :meth:`stopped` or the run's end."""
        return bool(self._run)

    def started(self, streams: Sequence[SensorStream]) -> None:
        """Show Stop for these (already started) streams, and watch them end."""
        run = tuple(streams)
        with self._lock:
            self._run = run
            self._show(live=True)
        threading.Thread(target=self._watch, args=(run,), name="live-watch", daemon=True).start()

    def stopped(self) -> None:
        """The step stopped its streams (or has none): show Start."""
        with self._lock:
            self._run = ()
            self._show(live=False)

    def _watch(self, run: tuple[SensorStream, ...]) -> None:
        while self._run is run and any(stream.running for stream in run):
            time.sleep(WATCH_PERIOD_S)
        with self._lock:
            if self._run is not run:  # stopped by the step, or another run started since
                return
            self._run = ()
            self._show(live=False)
        if self.on_ended is not None:
            self.on_ended(run)

    def _show(self, live: bool) -> None:
        self.start_button.visible = not live
        self.stop_button.visible = live
