"""A studio in this process, on a session, for the steps' tests: no browser, its toasts collected."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

import viser

from backend.services.jobs import JobRunner
from backend.store.session import Session, SessionStore
from studio.app import StudioApp


@contextlib.contextmanager
def in_process_studio(store: SessionStore, session: Session, free_port: Callable[[], int]
                      ) -> Iterator[tuple[StudioApp, list[tuple[str, str]]]]:
    """A :class:`StudioApp` on ``session`` (its viser server on a free port, stopped after) and the list its toasts
    (title, body) are appended to."""
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    notes: list[tuple[str, str]] = []
    try:
        app = StudioApp(server, store, JobRunner(), session=session)
        app.ctx.notify = lambda title, body, error=False: notes.append((title, body))
        yield app, notes
    finally:
        server.stop()
