"""One process: the FastAPI backend (uvicorn) and the viser studio, started by the CLI."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

import uvicorn

from backend.api.app import create_app
from backend.api.auth import is_loopback, new_token
from backend.api.origin import OriginPolicy
from backend.api.viewer_guard import new_secret, origin_check, secret_check, start_viewer
from backend.api.viewer_proxy import MAX_MESSAGE_BYTES, mount_viewer_proxy
from backend.services.demo import DEMO_NAME, start_demo_build
from backend.services.jobs import Job, JobRunner
from backend.store.session import SessionStore
from studio.app import StudioApp

if TYPE_CHECKING:
    from backend.services.demo_depth_cell import DepthCellNodes


def _log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _demo_builder(rig: str) -> tuple[str, Callable[..., Job]]:
    """The session name and the build starter (``start(store, jobs, fresh=...) -> Job``) of ``demo --rig RIG``
    (all but the depth cell, which also starts its nodes' processes)."""
    if rig == "disaster-response":
        from backend.services import demo_disaster_response as demo

        return demo.DISASTER_RESPONSE_NAME, demo.start_disaster_response_build
    if rig == "servo-scanner":
        from backend.services import demo_servo_scanner as demo

        return demo.SERVO_SCANNER_NAME, demo.start_servo_scanner_build
    return DEMO_NAME, start_demo_build


def _start_depth_cell(args: argparse.Namespace, store: SessionStore, jobs: JobRunner,
                      studio: StudioApp) -> DepthCellNodes:
    """``demo --rig depth-cell``: the six simulated nodes' agent processes, connected to the studio's network (the
    process's open one, which the API's live captures use too), and the session's build; the studio opens the
    session when it is ready.

    Run on the main thread: the agents are told to stop when the thread that started them ends (so a studio
    killed outright leaves none behind).
    """
    from backend.services import demo_depth_cell as cell  # zenoh and the simulator only for this demo

    nodes = cell.start_depth_cell_nodes(store.root / cell.NODE_LOG_DIR, store.root / cell.NODE_KEYS_DIR,
                                        lambda name, why: _log(f"node agent {name} {why}"))
    studio.attach_node_network(nodes.network)
    _log(f"node agents {', '.join(nodes.agents.agents)} connect to {nodes.endpoint} (logs in {nodes.agents.log_dir})")
    _log(f"preparing the depth-cell session in {store.root}/{cell.DEPTH_CELL_NAME} ...")
    studio.session_step.open_when_built(cell.start_depth_cell_build(store, jobs, fresh=args.fresh))
    return nodes


def _exit_on_sigterm(signum: int, frame: object) -> None:
    """SIGTERM ends the server as Ctrl-C does. Uvicorn shuts down on it and then raises it again under the handler
    it found; with this one that is :class:`SystemExit`, so :func:`serve`'s cleanup (the studio's streams, the
    jobs, a demo's node agents) runs and the exit code is 0 (without it the process died of the signal)."""
    sys.exit(0)


def serve(args: argparse.Namespace) -> int:
    """Run until interrupted (Ctrl-C or SIGTERM). The first stdout line is the URL to open."""
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
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
    print(studio_url, flush=True)  # the first line a user sees (stdout), before any log line (stderr)
    _log(f"API and docs: http://{args.host}:{args.port}/docs")
    nodes = None
    if args.command == "demo" and args.rig == "depth-cell":
        nodes = _start_depth_cell(args, store, jobs, studio)
    elif args.command == "demo":  # the page serves while a missing demo is built; the studio opens it when ready
        name, start_build = _demo_builder(args.rig)
        _log(f"preparing the {name} session in {store.root}/{name} ...")
        studio.session_step.open_when_built(start_build(store, jobs, fresh=args.fresh))
    logging.getLogger("uvicorn.error").setLevel(logging.WARNING)
    try:
        uvicorn.run(app, host=args.host, port=args.port, log_level="warning", ws_max_size=MAX_MESSAGE_BYTES,
                    ws_per_message_deflate=False)
    finally:
        studio.close()
        if nodes is not None:
            nodes.close()
        jobs.shutdown()
        viewer.stop()
    return 0
