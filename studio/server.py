"""One process: the FastAPI backend (uvicorn) and the viser studio, started by the CLI."""

from __future__ import annotations

import argparse
import logging
import sys

import uvicorn

from backend.api.app import create_app
from backend.api.auth import is_loopback, new_token
from backend.api.origin import OriginPolicy
from backend.api.viewer_guard import new_secret, origin_check, secret_check, start_viewer
from backend.api.viewer_proxy import MAX_MESSAGE_BYTES, mount_viewer_proxy
from backend.services.demo import start_demo_build
from backend.services.jobs import JobRunner
from backend.store.session import SessionStore
from studio.app import StudioApp


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def serve(args: argparse.Namespace) -> int:
    """Run until interrupted. The first stdout line is the URL to open."""
    store = SessionStore(args.sessions)
    loopback = is_loopback(args.host)
    token = args.token or (None if loopback else new_token())
    # With a token the viewer stays on 127.0.0.1 and answers only the API's token-checked proxy (its secret);
    # without one it answers only its own pages (Host and Origin checks).
    viewer_secret = new_secret()
    check = origin_check(args.host) if token is None else secret_check(viewer_secret)
    viewer = start_viewer(args.host if token is None else "127.0.0.1", args.viewer_port, check)
    viewer_port = viewer.get_port()
    if token is None:
        studio_url = f"http://{args.host}:{viewer_port}/"
    else:
        studio_url = f"http://{args.host}:{args.port}/studio/?token={token}"
    jobs = JobRunner()
    app = create_app(store, jobs, token=token, studio_url=studio_url if token is None else "/studio/",
                     origins=OriginPolicy.for_server(args.host, (args.port, viewer_port)))
    if token is not None:
        mount_viewer_proxy(app, viewer_port, token, viewer_secret)
    host = f"[{args.host}]" if ":" in args.host else args.host
    studio = StudioApp(viewer, store, jobs, api_url=f"http://{host}:{args.port}" if token is None else "")
    if args.command == "demo":  # the page serves while a missing demo is built; the studio opens it when ready
        _log(f"preparing the demo session in {store.root}/demo ...")
        studio.session_step.open_when_built(start_demo_build(store, jobs, fresh=args.fresh))
    print(studio_url, flush=True)
    _log(f"API and docs: http://{args.host}:{args.port}/docs")
    logging.getLogger("uvicorn.error").setLevel(logging.WARNING)
    try:
        uvicorn.run(app, host=args.host, port=args.port, log_level="warning", ws_max_size=MAX_MESSAGE_BYTES,
                    ws_per_message_deflate=False)
    finally:
        studio.close()
        jobs.shutdown()
        viewer.stop()
    return 0
