"""What the wizard steps share: the viser server, the backend services and the open session."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import viser

from backend.core.errors import InputError
from backend.services.exports import ExportFormat, export_text
from backend.services.jobs import JobRunner
from backend.store.session import Session, SessionStore
from studio.scene import RigScene


@dataclass
class StudioContext:
    server: viser.ViserServer
    store: SessionStore
    jobs: JobRunner
    scene: RigScene
    session: Session | None = None
    api_url: str = ""
    """Where the browser reaches the REST API (``http://host:port``; empty when the studio page is served by it)."""
    _listeners: list[Callable[[Session], None]] = field(default_factory=list)

    def on_session_changed(self, listener: Callable[[Session], None]) -> None:
        self._listeners.append(listener)

    def open_session(self, session: Session) -> None:
        """Make ``session`` current and tell every step."""
        self.session = session
        self.scene.show_rig(session.rig)
        for listener in self._listeners:
            listener(session)

    def download(self, event: viser.GuiEvent, fmt: ExportFormat, sensor: str | None = None) -> None:
        """Send one export of the open session to the page that clicked (a toast says why when there is none)."""
        try:
            filename, text = export_text(self.session, fmt, sensor)
        except InputError as exc:
            self.notify("Nothing to export", exc.message, error=True)
            return
        event.client.send_file_download(filename, text.encode())

    def notify(self, title: str, body: str, error: bool = False) -> None:
        """Show a toast on every connected page."""
        for client in self.server.get_clients().values():
            client.add_notification(title, body, color="red" if error else "blue", auto_close_seconds=8.0 if not error
                                    else 15.0)
