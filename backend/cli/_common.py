"""What every ``calib-studio`` command shares: the parser, the output contract, the arguments two groups take.

The contract (``../shared/conventions.md``, "CLI output"): a solving command prints exactly one JSON object on stdout
with ``--json``, progress and logs go to stderr. On failure (bad arguments, bad input, a file that cannot be read or
written, a bug) a command exits non-zero with a one-line error on stderr and, with ``--json``,
``{"error": {"message", "input"}}`` on stdout (:func:`fail`). Output files are checked before the solve starts
(:func:`check_outputs`); if one still cannot be written after it, the result is kept in a folder of the system's
temp dir that the error names (:func:`write_outputs`).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, NoReturn

from backend.core.errors import InputError, shorten
from backend.exports.text_file import check_writable, write_text

EXIT_INPUT_ERROR = 2
EXIT_INTERNAL_ERROR = 1
EXIT_CANCELLED = 130

Handler = Callable[[argparse.Namespace], int | None]
"""What a command runs (``set_defaults(handler=...)``): its exit code, None for 0."""


class Parser(argparse.ArgumentParser):
    """argparse whose errors (a missing or unknown option) raise :class:`InputError`, so they reach the user as every
    other error does: the usage, then the one-line error and, with ``--json``, the JSON error."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        raise InputError(message, self.prog)


def prints_summary(run: Callable[[argparse.Namespace], dict[str, Any]]) -> Handler:
    """The handler of a solving command: ``run`` returns the summary, printed as one JSON object with ``--json``."""

    def handler(args: argparse.Namespace) -> int:
        summary = run(args)
        if getattr(args, "json", False):
            print(json.dumps(summary))
        return 0

    return handler


def fail(error: InputError, want_json: bool, code: int) -> int:
    """Print ``error`` as the contract says (the line on stderr, the JSON on stdout) and return the exit code."""
    print(error.one_line(), file=sys.stderr, flush=True)
    if want_json:
        try:
            print(json.dumps({"error": error.to_dict()}), flush=True)
        except OSError:  # stdout itself is gone (a closed pipe): the line on stderr has said it
            pass
    return code


def progress_to_stderr(quiet: bool) -> Callable[[float, str], None]:
    def report(fraction: float, message: str) -> None:
        if not quiet:
            print(f"[{fraction * 100:5.1f}%] {message}", file=sys.stderr, flush=True)

    return report


def warn(message: str) -> None:
    """``warning: MESSAGE`` on stderr."""
    print(f"warning: {message}", file=sys.stderr)


def check_outputs(*paths: Path | None) -> None:
    """Refuse, before any work, an output file that cannot be written (see :func:`check_writable`)."""
    for path in paths:
        if path is not None:
            check_writable(path)


def write_outputs(command: str, outputs: list[tuple[Path, str]], summary: dict[str, Any]) -> None:
    """Write each ``(path, text)`` of a solved ``command``. If one fails, the result is not lost: ``summary`` (what
    ``--json`` prints) and the files not yet written are kept by :func:`keep_result`, and the error names both."""
    for k, (path, text) in enumerate(outputs):
        try:
            write_text(path, text)
        except InputError as exc:
            raise InputError(f"{exc.message}; {keep_result(command, summary, outputs[k:])}", exc.input) from None
        print(f"wrote {path}", file=sys.stderr)


def keep_result(command: str, summary: dict[str, Any], unwritten: list[tuple[Path, str]]) -> str:
    """Keep a solved result whose output could not be written, in a new folder of the system's temp dir (``TMPDIR``):
    ``result.json`` and each unwritten file under its own name. Says where, for the error message; if even that
    fails, the result goes to stderr as one ``result: {...}`` line."""
    try:
        folder = Path(tempfile.mkdtemp(prefix=f"calib-studio-{command}-"))
        files = {"result.json": json.dumps(summary, indent=1)}
        for path, text in unwritten:
            files.setdefault(path.name, text)
        for name, text in files.items():
            write_text(folder / name, text)
    except (OSError, InputError):
        print(f"result: {json.dumps(summary)}", file=sys.stderr)
        return "the result could not be kept on disk either: it is the 'result:' line above on stderr"
    return f"the result is kept in {folder} ({', '.join(files)})"


def add_camera_corners_arguments(parser: argparse.ArgumentParser) -> None:
    """``--camera camera.yaml`` and the mutually exclusive ``--detections corners.csv | --images DIR`` of a command
    that reads a board's corners over time (``camera-imu``, ``time-offset``)."""
    parser.add_argument("--camera", type=Path, required=True, help="the camera's intrinsics (ROS camera_info YAML)")
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--detections", type=Path,
                        help="detected corners: CSV t_ns,u_px,v_px,x_m,y_m,z_m,tag_id,corner (one corner a row)")
    source.add_argument("--images", type=Path,
                        help="a folder of images named by their time stamp in ns (the board is detected in each)")


def add_init_arguments(parser: argparse.ArgumentParser, transform: str, default: str = "") -> None:
    """The mutually exclusive ``--init T.txt`` and ``--init-xyzypr x,y,z,yaw,pitch,roll`` of a solving command,
    both the starting ``transform`` (e.g. "initial T_camera_lidar"); ``default`` says what applies without them."""
    init = parser.add_mutually_exclusive_group()
    init.add_argument("--init", type=Path, metavar="T.txt",
                      help=f"{transform}: a 4x4 in a text file, four whitespace-separated rows")
    init.add_argument("--init-xyzypr", metavar="x,y,z,yaw,pitch,roll",
                      help=f"{transform}: metres and degrees (ROS order){default}")


def read_init(args: argparse.Namespace):
    """The initial transform (``T_target_source``, ``T_camera_lidar``) from ``--init`` or ``--init-xyzypr``, or None."""
    import numpy as np

    if args.init is not None:
        expected = "a 4x4 transform as four rows of four whitespace-separated numbers"
        try:
            rows = [line.split() for line in args.init.read_text().splitlines() if line.strip()
                    and not line.lstrip().startswith("#")]
            T = np.array([[float(v) for v in row] for row in rows])
        except OSError as exc:
            raise InputError(f"cannot read the file ({exc.strerror}); expected {expected}", str(args.init)) from None
        except ValueError:
            raise InputError(f"not numbers; expected {expected}", str(args.init)) from None
        if T.shape != (4, 4):
            raise InputError(f"found {len(rows)} row(s) of {sorted({len(r) for r in rows})} value(s); "
                             f"expected {expected}", str(args.init))
        return T
    if args.init_xyzypr is not None:
        return parse_xyzypr(args.init_xyzypr, "--init-xyzypr")
    return None


def parse_floats(text: str) -> list[float]:
    """The comma-separated numbers of ``text``; an empty list when one is not a number."""
    try:
        return [float(v) for v in text.split(",")]
    except ValueError:
        return []


def parse_xyzypr(text: str, option: str):
    """The 4x4 transform (m) of ``x,y,z,yaw,pitch,roll`` (m, then ROS yaw, pitch, roll in degrees); an
    :class:`InputError` naming ``option`` for anything else."""
    import numpy as np

    from backend.core.transforms import from_xyz_ypr

    values = parse_floats(text)
    if len(values) != 6 or not np.isfinite(values).all():
        raise InputError(f"expected six comma-separated numbers x,y,z (m),yaw,pitch,roll (deg), got {shorten(text)}",
                         option)
    return from_xyz_ypr(np.array(values[:3]), np.radians(values[3:]))


def pose_text(T) -> str:
    """``x y z  yaw pitch roll`` of a 4x4 transform: metres to 4 decimals, degrees (ROS order) to 3."""
    import numpy as np

    from backend.core.transforms import to_xyz_ypr

    xyz, ypr = to_xyz_ypr(T)
    return f"{' '.join(f'{v:.4f}' for v in xyz)}  {' '.join(f'{v:.3f}' for v in np.degrees(ypr))}"


def init_name(args: argparse.Namespace) -> str:
    """Where the initial transform came from, for an error about it: the file, or ``--init-xyzypr``."""
    return str(args.init) if args.init is not None else "--init-xyzypr"


def parse_pairs(values: list[str], form: str = "IMAGE:CLOUD", option: str = "--pair") -> list[tuple[Path, Path]]:
    """``A:B`` arguments of ``option`` (``form`` names them) as path pairs (split at the last colon: paths may hold
    one)."""
    pairs = []
    for value in values:
        first, sep, second = value.rpartition(":")
        if not sep or not first or not second:
            raise InputError(f"expected {form}, got {shorten(value)}", option)
        pairs.append((Path(first), Path(second)))
    return pairs


NEGATIVE_VALUE = re.compile(r"^-\.?\d")
"""A value that starts like a negative number (``-0.07,0.63,...``, ``-5``)."""


def _value_options(parser: argparse.ArgumentParser) -> set[str]:
    """Every option string, in the parser and its subcommands, that takes a value."""
    options = set()
    for action in parser._actions:  # argparse has no public listing of its actions
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                options |= _value_options(sub)
        elif action.option_strings and action.nargs != 0:
            options.update(action.option_strings)
    return options


def join_negative_values(parser: argparse.ArgumentParser, argv: list[str]) -> list[str]:
    """``--opt -0.07,...`` as ``--opt=-0.07,...`` for every option that takes a value: argparse reads a value
    after a space that starts with ``-`` (and is not one plain number) as an unknown option."""
    options = _value_options(parser)
    joined: list[str] = []
    for arg in argv:
        if joined and joined[-1] in options and NEGATIVE_VALUE.match(arg):
            joined[-1] = f"{joined[-1]}={arg}"
        else:
            joined.append(arg)
    return joined
