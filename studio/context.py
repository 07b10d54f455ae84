"""What the wizard steps share: the viser server, the backend services and the open session.

A session change runs in two phases, so that nothing of one session leaks into the next:
every step's *closing* hook first lets go of what it holds of the open session (live
streams, scene handles, timers), the scene is then redrawn for the new rig, and every
step's *changed* listener fills its panel from the new session. One step that fails in
either phase is logged and reported; the others are told all the same.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import viser

from backend.core.errors import InputError
from backend.services.exports import ExportFormat, export_text
from backend.services.jobs import JobRunner
from backend.store.session import Session, SessionStore
from studio.scene import RigScene

log = logging.getLogger(__name__)


@dataclass
class StudioContext:
    server: viser.ViserServer
    store: SessionStore
    jobs: JobRunner
    scene: RigScene
    session: Session | None = None
    api_url: str = ""
    """Where the browser reaches the REST API (``http://host:port``; empty when the studio page is served by it)."""
    _closing: list[Callable[[], None]] = field(default_factory=list)
    _listeners: list[Callable[[Session], None]] = field(default_factory=list)
    _rig_listeners: list[Callable[[Session], None]] = field(default_factory=list)
    _step_listeners: list[Callable[[str], None]] = field(default_factory=list)
    _switching: threading.RLock = field(default_factory=threading.RLock)
    """Held through a session change: two clicks on *Open session* change it one after the other."""
    _shown_revision: int = 0
    """The open session's :attr:`~backend.store.session.Session.revision` the steps last followed."""
    _shown_frames: frozenset[str] = frozenset()
    """The frames of the rig the steps last followed (:meth:`follow`)."""
    _stop_following: Callable[[], None] = lambda: None

    def on_session_closing(self, hook: Callable[[], None]) -> None:
        """``hook()`` runs before the open session is left (another opens, or the studio stops): stop what streams
        and drop the scene handles held for it (the scene is redrawn right after)."""
        self._closing.append(hook)

    def on_session_changed(self, listener: Callable[[Session], None]) -> None:
        """``listener(session)`` runs once ``session`` is current and the scene shows its rig."""
        self._listeners.append(listener)

    def on_rig_changed(self, listener: Callable[[Session], None]) -> None:
        """``listener(session)`` runs after an accept or a revert changed the open session's rig."""
        self._rig_listeners.append(listener)

    def rig_changed(self) -> None:
        """An accept, a revert or an edit changed the open session's rig: redraw the rig's frames and tell every
        :meth:`on_rig_changed` listener, once per saved change (nothing when the steps already follow the session's
        latest revision: the session's own change listener usually got there first)."""
        if self.session is None or self.session.revision == self._shown_revision:
            return
        self._shown_revision, self._shown_frames = self.session.revision, frozenset(self.session.rig.frames)
        self.scene.update_rig(self.session.rig)
        for listener in self._rig_listeners:
            self._call(listener, self.session, during="the rig change")

    def _changed_elsewhere(self) -> None:
        """The open session saved a change (an accept, a revert or an edit, through the API or a step): :meth:`follow`
        it, so an open page never shows a rig the session no longer has. While a session switch is under way it
        does nothing (the switch draws the rig afresh), and never waits for it: the changing thread may be one the
        switch is stopping."""
        if not self._switching.acquire(blocking=False):
            return
        try:
            self.follow()
        finally:
            self._switching.release()

    def follow(self) -> None:
        """Every step follows the open session's latest saved change: with a sensor added or removed the session
        is opened again (as after *Open session*), else :meth:`rig_changed`; nothing when they already follow it."""
        if self.session is None or self.session.revision == self._shown_revision:
            return
        if frozenset(self.session.rig.frames) != self._shown_frames:
            self.open_session(self.session)
        else:
            self.rig_changed()

    def on_step_shown(self, listener: Callable[[str], None]) -> None:
        """``listener(step)`` runs when :meth:`show_step` is called (the layers panel follows it)."""
        self._step_listeners.append(listener)

    def show_step(self, step: str) -> None:
        """Make ``step`` (``intrinsics``, ``lidar``, ``sweep``, ``lidar_camera``, ``multicam``, ``rig``, ...) the one
        whose layers the 3D view shows: a step calls this when the user starts working in it."""
        for listener in self._step_listeners:
            self._call(listener, step, during="the step change")

    def after_switch(self, action: Callable[[], None]) -> Callable[[viser.GuiEvent], None]:
        """A click handler running ``action()`` once any session switch in progress has finished: a Start clicked
        while the steps still follow a new session acts on that session, and the switch's own stop of the old one's
        streams cannot undo it."""

        def handler(_event: viser.GuiEvent) -> None:
            with self._switching:
                action()

        return handler

    def open_session(self, session: Session) -> None:
        """Leave the open session, make ``session`` current, draw its rig and tell every step."""
        with self._switching:
            self.close_session()
            self.session = session
            self._shown_revision, self._shown_frames = session.revision, frozenset(session.rig.frames)
            self._stop_following = session.on_change(self._changed_elsewhere)
            self.scene.show_rig(session.rig)
            for listener in self._listeners:
                self._call(listener, session)

    def close_session(self) -> None:
        """Run every step's closing hook (the session stays current until another is opened)."""
        with self._switching:
            self._stop_following()
            for hook in self._closing:
                self._call(hook)

    def _call(self, callback: Callable, *args, during: str = "the session change") -> None:
        """Run one step's hook; a failure is logged with its traceback and shown, and never stops the next step."""
        try:
            callback(*args)
        except Exception as exc:  # noqa: BLE001 - one broken step must not leave the others on the old session
            log.exception("a studio step failed on %s", during)
            self.notify("Studio", f"a step could not follow {during}: {exc}", error=True)

    def download(self, event: viser.GuiEvent, fmt: ExportFormat, sensor: str | None = None, **options) -> None:
        """Send one export of the open session to the page that clicked (a toast says why when there is none);
        ``options`` are :func:`~backend.services.exports.export_text`'s (``convention``, ``cameras``)."""
        self.send_file(event, lambda: export_text(self.session, fmt, sensor, **options))

    def send_file(self, event: viser.GuiEvent, make: Callable[[], tuple[str, str]]) -> None:
        """Send the ``(file name, text)`` that ``make()`` returns to the page that clicked; an
        :class:`InputError` from it is shown as a toast instead."""
        try:
            filename, text = make()
        except InputError as exc:
            self.notify("Nothing to export", exc.message, error=True)
            return
        event.client.send_file_download(filename, text.encode())

    def notify(self, title: str, body: str, error: bool = False) -> None:
        """Show a toast on every connected page."""
        for client in self.server.get_clients().values():
            client.add_notification(title, body, color="red" if error else "blue", auto_close_seconds=8.0 if not error
                                    else 15.0)
