"""``calib-studio``: serve the studio, solve from the command line, export.

The command line, one module per command group; each has ``add_parser(subparsers)``, which registers its commands
with their handler (``set_defaults(handler=...)``). The commands that start the studio (``demo``, ``serve``) are
``studio.cli``'s, given to :func:`main` as ``extra_commands``: ``backend`` never imports ``studio``.

Solving commands print exactly one JSON object on stdout with ``--json`` (the contract in
``../shared/conventions.md``); progress and logs go to stderr. On failure (bad arguments, bad input, a file that
cannot be read or written, a bug) they exit non-zero with a one-line error on stderr and, with ``--json``,
``{"error": {"message", "input"}}`` on stdout (see :mod:`backend.cli._common`).
"""

from __future__ import annotations

import argparse
import sys
import traceback
from collections.abc import Callable, Sequence

from backend.cli import (
    camera_imu,
    depth,
    intrinsics,
    lidar_camera,
    lidar_lidar,
    multicam,
    rig,
    sensors,
    sweep_corners,
    targets,
    test_field,
    time_offset,
)
from backend.cli._common import (
    EXIT_CANCELLED,
    EXIT_INPUT_ERROR,
    EXIT_INTERNAL_ERROR,
    Parser,
    fail,
    join_negative_values,
)
from backend.core.errors import InputError, clip

__all__ = ["EXIT_CANCELLED", "EXIT_INPUT_ERROR", "EXIT_INTERNAL_ERROR", "build_parser", "main"]

AddParser = Callable[[argparse._SubParsersAction], None]
"""A command group's ``add_parser(subparsers)``."""

GROUPS: tuple[AddParser, ...] = (intrinsics.add_parser, test_field.add_parser, lidar_lidar.add_parser,
                                 lidar_camera.add_parser, multicam.add_parser, targets.add_parser, sensors.add_parser,
                                 rig.add_parser, depth.add_parser, sweep_corners.add_parser,
                                 camera_imu.add_parser, time_offset.add_parser)
"""The backend's command groups, in the order ``--help`` lists their commands."""


def build_parser(extra_commands: Sequence[AddParser] = ()) -> argparse.ArgumentParser:
    """The ``calib-studio`` parser: ``extra_commands`` (each an ``add_parser(subparsers)``) first, then
    :data:`GROUPS`."""
    parser = Parser(prog="calib-studio", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for add_parser in (*extra_commands, *GROUPS):
        add_parser(sub)
    return parser


def main(argv: list[str] | None = None, extra_commands: Sequence[AddParser] = ()) -> int:
    """Run one command; every failure ends here as the one-line error (and the JSON error with ``--json``)."""
    argv = sys.argv[1:] if argv is None else argv
    want_json = "--json" in argv  # until the arguments are parsed
    try:
        parser = build_parser(extra_commands)
        args = parser.parse_args(join_negative_values(parser, argv))
        want_json = getattr(args, "json", False)
        code = args.handler(args)
        return 0 if code is None else code
    except InputError as exc:
        return fail(exc, want_json, EXIT_INPUT_ERROR)
    except OSError as exc:  # a file or device the commands' own checks did not cover
        name = None if exc.filename is None else str(exc.filename)
        return fail(InputError(exc.strerror or str(exc) or type(exc).__name__, name), want_json, EXIT_INPUT_ERROR)
    except KeyboardInterrupt:
        return fail(InputError("cancelled"), want_json, EXIT_CANCELLED)
    except Exception as exc:  # a bug: its traceback for the report, then the error line as for any other failure
        traceback.print_exc()
        message = f"internal error ({type(exc).__name__}: {clip(str(exc))}); please report it with the traceback above"
        return fail(InputError(message), want_json, EXIT_INTERNAL_ERROR)
