"""A failed job (a device error in a capture) shows in the panel under the button that started it, named with its
title, and goes to the server's log; the other buttons of the step come back enabled."""

from __future__ import annotations

import logging

import viser

from backend.core.errors import InputError
from backend.services.jobs import JobRunner
from backend.store.session import SessionStore
from studio.context import StudioContext
from studio.job_panel import JobPanel
from studio.scene import RigScene
from tests.conftest import poll


def test_a_failed_capture_is_shown_under_its_button_and_logged(tmp_path, free_port, caplog):
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    jobs = JobRunner()
    try:
        ctx = StudioContext(server, SessionStore(tmp_path), jobs, RigScene(server))
        capture_button = server.gui.add_button("Capture sweep")
        capture_jobs = JobPanel(ctx, [capture_button])
        solve_button = server.gui.add_button("Calibrate")
        solve_jobs = JobPanel(ctx, [capture_button, solve_button])
        capture_jobs.also_disable(solve_button)

        def capture(progress):
            raise InputError("There is no status packet!", "scanner")

        with caplog.at_level(logging.WARNING, logger="backend.services.jobs"):
            capture_jobs.run("Sweep of scanner", capture, lambda _: None)
            poll(lambda: not capture_jobs.busy and not capture_button.disabled, "the capture job never ended")
            poll(lambda: capture_jobs.text.content.endswith("There is no status packet!"), "no failure shown")
        assert capture_jobs.text.content.endswith("Sweep of scanner failed: There is no status packet!")
        assert solve_jobs.text.content == "" and not solve_button.disabled
        (record,) = [r for r in caplog.records if r.name == "backend.services.jobs"]
        assert record.levelno == logging.WARNING and record.getMessage().endswith(
            "(Sweep of scanner) failed: There is no status packet!")
    finally:
        jobs.shutdown()
        server.stop()
