"""A progress bar, a status line and a Cancel button that follow one background job."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from backend.core.result import ProgressCallback
from backend.services.jobs import Job
from backend.store.session import Session
from studio.context import StudioContext
from studio.marks import WARNING


class JobPanel:
    """Runs work through the studio's job runner and mirrors it in the panel, off the GUI thread.

    ``buttons`` are disabled while a job runs, so the same work cannot be started twice. A failure shows in the
    panel (placed under the button whose action it follows), named with the job's title, and as a toast; the job
    runner logs it. A job runs on in the session it was started in; if another session has been opened by the time
    it ends, its ``on_done`` is not run (it would show one session's result in another's panel). A session change
    clears an idle panel.
    """

    def __init__(self, ctx: StudioContext, buttons: list, cancel_label: str = "Cancel"):
        gui = ctx.server.gui
        self.ctx = ctx
        self.buttons = buttons
        self.cancel_button = gui.add_button(cancel_label, visible=False)
        self.progress = gui.add_progress_bar(0.0, animated=False)
        self.text = gui.add_markdown("")
        self.job: Job | None = None
        self.cancel_button.on_click(lambda _: self.job.cancel() if self.job else None)
        ctx.on_session_changed(lambda _: None if self.busy else self._clear())

    def also_disable(self, *buttons) -> None:
        """Disable ``buttons`` too while a job of this panel runs (a button made after the panel)."""
        self.buttons.extend(buttons)

    def _clear(self) -> None:
        self.progress.value = 0.0
        self.text.content = ""

    @property
    def busy(self) -> bool:
        return self.job is not None and self.job.state == "running"

    def run(self, title: str, work: Callable[[ProgressCallback], Any], on_done: Callable[[Any], None],
            done_message: str = "{title}: done in {seconds:.2f} s.") -> None:
        """Start ``work`` unless a job is running; ``on_done(result)`` runs once it succeeds."""
        if self.busy:
            return
        self.job = self.ctx.jobs.submit(title, work)
        for button in self.buttons:
            button.disabled = True
        self.cancel_button.visible = True
        threading.Thread(target=self._watch, args=(self.job, on_done, done_message, self.ctx.session),
                         daemon=True).start()

    def _watch(self, job: Job, on_done: Callable[[Any], None], done_message: str, session: Session | None) -> None:
        while not job.wait(0.1):
            self.progress.value = 100.0 * job.fraction
            self.text.content = job.message
        self.progress.value = 100.0 * job.fraction
        for button in self.buttons:
            button.disabled = False
        self.cancel_button.visible = False
        if job.state == "done" and self.ctx.session is not session:
            self.text.content = f"{job.title}: done in session {session.name}, which is no longer open."
        elif job.state == "done":
            self.text.content = done_message.format(title=job.title, seconds=job.finished - job.started)
            on_done(job.result)
        elif job.state == "cancelled":
            self.text.content = "Cancelled; nothing was changed."
        else:
            self.text.content = f"{WARNING} {job.title} failed: {job.message}"
            self.ctx.notify(f"{job.title} failed", job.message, error=True)
