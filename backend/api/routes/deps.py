"""Shared route dependencies."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request

from backend.services.jobs import JobRunner
from backend.store.session import Session, SessionStore


def store(request: Request) -> SessionStore:
    return request.app.state.studio.store


def jobs(request: Request) -> JobRunner:
    return request.app.state.studio.jobs


def session(name: str, request: Request) -> Session:
    return store(request).get(name)


StoreDep = Annotated[SessionStore, Depends(store)]
JobsDep = Annotated[JobRunner, Depends(jobs)]
SessionDep = Annotated[Session, Depends(session)]
