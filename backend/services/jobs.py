"""Long work (solves, imports) in background threads, with progress and cancel.

A job function takes a :data:`ProgressCallback`; calling it after the user asked to
cancel raises :class:`CancelledError`, so cancelling is cooperative and lands at
the next progress report, leaving the session as it was.
"""

from __future__ import annotations

import itertools
import logging
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Literal

from backend.core.errors import CancelledError, InputError, NotFoundError, shorten
from backend.core.result import ProgressCallback

log = logging.getLogger(__name__)

JobState = Literal["running", "done", "failed", "cancelled"]


@dataclass
class Job:
    id: str
    title: str
    state: JobState = "running"
    fraction: float = 0.0
    message: str = "starting"
    result: Any = None
    error: dict[str, Any] | None = None
    started: float = field(default_factory=time.time)
    finished: float | None = None
    _cancel: threading.Event = field(default_factory=threading.Event, repr=False)
    _done: threading.Event = field(default_factory=threading.Event, repr=False)

    def report(self, fraction: float, message: str) -> None:
        """The :data:`ProgressCallback` handed to the job function."""
        if self._cancel.is_set():
            raise CancelledError(f"{self.title} cancelled")
        self.fraction, self.message = float(fraction), message

    def cancel(self) -> None:
        self._cancel.set()

    def wait(self, timeout: float | None = None) -> bool:
        return self._done.wait(timeout)

    def status(self) -> dict[str, Any]:
        return {"id": self.id, "title": self.title, "state": self.state, "fraction": self.fraction,
                "message": self.message, "error": self.error, "started": self.started, "finished": self.finished}


class JobRunner:
    """Runs jobs on a small thread pool and keeps their status for polling."""

    def __init__(self, workers: int = 2):
        self._pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="calib-job")
        self._jobs: dict[str, Job] = {}
        self._ids = itertools.count(1)

    def submit(self, title: str, work: Callable[[ProgressCallback], Any],
               on_done: Callable[[Job], None] | None = None) -> Job:
        job = Job(id=f"j{next(self._ids):05d}", title=title)
        self._jobs[job.id] = job

        def run() -> None:
            try:
                job.result = work(job.report)
                job.state, job.fraction, job.message = "done", 1.0, "done"
            except CancelledError as exc:
                job.state, job.message = "cancelled", str(exc)
            except InputError as exc:
                job.state, job.error, job.message = "failed", exc.to_dict(), exc.message
                log.warning("job %s (%s) failed: %s", job.id, title, exc.message)
            except Exception as exc:  # noqa: BLE001 - a job must always end with a status the user can read
                job.state, job.message = "failed", f"internal error: {shorten(exc)}"
                job.error = {"message": job.message, "input": None}
                log.exception("job %s (%s) failed with an internal error", job.id, title)
            finally:
                job.finished = time.time()
                job._done.set()
                if on_done is not None:
                    on_done(job)

        self._pool.submit(run)
        return job

    def get(self, job_id: str) -> Job:
        try:
            return self._jobs[job_id]
        except KeyError:
            raise NotFoundError(f"no job {job_id!r}", "job") from None

    def shutdown(self) -> None:
        for job in self._jobs.values():
            job.cancel()
        self._pool.shutdown(wait=False, cancel_futures=True)
