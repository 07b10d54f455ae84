"""``calib-studio``: the entry point. The commands are :mod:`backend.cli`'s, one module per command group; the two
that start the studio, ``demo`` and ``serve``, are here (they run :func:`studio.server.serve`, and ``backend``
never imports ``studio``).

Output contract, exit codes and error handling: see :mod:`backend.cli` and ``../shared/conventions.md``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import backend.cli
from backend.cli import EXIT_CANCELLED, EXIT_INPUT_ERROR, EXIT_INTERNAL_ERROR

__all__ = ["EXIT_CANCELLED", "EXIT_INPUT_ERROR", "EXIT_INTERNAL_ERROR", "add_parser", "main"]


def _add_serve_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    parser.add_argument("--port", type=int, default=8000, help="API port (default 8000)")
    parser.add_argument("--viewer-port", type=int, default=8080, help="3D studio port (default 8080)")
    parser.add_argument("--token", default=None, help="access token (generated when binding beyond loopback)")


def add_parser(sub: argparse._SubParsersAction) -> None:
    """``demo`` and ``serve``: start the studio."""
    demo = sub.add_parser("demo", help="open the studio on a demo session of the simulated rig")
    demo.add_argument("--sessions", type=Path, default=Path("sessions"), help="where the demo session is kept")
    demo.add_argument("--fresh", action="store_true", help="rebuild the demo session from scratch")
    demo.add_argument("--rig", choices=["default", "depth-cell", "disaster-response", "servo-scanner"],
                      default="default",
                      help="default: the simulated robot rig; depth-cell: six simulated Kinect v2 nodes over a "
                           "10 x 15 x 5 m cell, each its own node-agent process; disaster-response: a Blackfly and "
                           "a Livox with a wall test field and V-targets; servo-scanner: a Hokuyo swept by a "
                           "Dynamixel servo, a camera on a pan head, a board in the sweep's intensity")
    _add_serve_args(demo)
    demo.set_defaults(handler=run_serve)

    serve = sub.add_parser("serve", help="serve the studio on a folder of sessions")
    serve.add_argument("--sessions", type=Path, required=True, help="folder of sessions")
    _add_serve_args(serve)
    serve.set_defaults(handler=run_serve)


def run_serve(args: argparse.Namespace) -> int:
    """Run the studio (``demo`` or ``serve``) until interrupted."""
    from studio.server import serve

    return serve(args)


def main(argv: list[str] | None = None) -> int:
    """Run one ``calib-studio`` command (see :func:`backend.cli.main`)."""
    return backend.cli.main(argv, extra_commands=[add_parser])


if __name__ == "__main__":
    sys.exit(main())
