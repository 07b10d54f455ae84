"""``calib-studio sensor``: list, edit, remove and restore a session's sensors (the rig service's edits).

A session a running studio has open is changed under it: stop the studio, or edit in the studio (step 2).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from backend.cli._common import parse_xyzypr, prints_summary
from backend.core.errors import InputError, shorten


def add_parser(sub: argparse._SubParsersAction) -> None:
    sensor = sub.add_parser("sensor", help="list, edit, remove or restore a session's sensors")
    commands = sensor.add_subparsers(dest="sensor_command", required=True)

    def command(name: str, help_text: str, run) -> argparse.ArgumentParser:
        parser = commands.add_parser(name, help=help_text)
        parser.add_argument("session_dir", type=Path, help="the session folder, e.g. sessions/demo")
        parser.set_defaults(handler=prints_summary(run))
        return parser

    listing = command("list", "the rig's sensors and the removed ones", run_list)
    listing.add_argument("--json", action="store_true", help="print them as one JSON object")

    edit = command("edit", "change a sensor's parent, mounting guess, mount sigma or device; the rig is re-fitted",
                   run_edit)
    edit.add_argument("name", help="the sensor")
    edit.add_argument("--parent", help="the frame to hang from (without --xyzypr the sensor keeps its place)")
    edit.add_argument("--xyzypr", metavar="x,y,z,yaw,pitch,roll",
                      help="the new mounting guess T_parent_sensor: m, then ROS yaw, pitch, roll in degrees")
    sigma = edit.add_mutually_exclusive_group()
    sigma.add_argument("--mount-sigma", metavar="M,DEG", help="1-sigma of the mounting guess: m, deg")
    sigma.add_argument("--mount-unknown", action="store_true", help="the mounting is unknown: only calibrations "
                       "place the sensor")
    edit.add_argument("--device", metavar="SPEC", help="the capture device, as 'calib-studio node --device' takes it: "
                      "a short form (sim-lidar:lidar_top, kinect2:SERIAL, ...) or a driver's JSON settings, e.g. "
                      "'{\"driver\": \"uvc\", \"device\": 1}'")
    _preview_and_json(edit)

    remove = command("remove", "remove a sensor: its accepted results leave the rig, its captures are kept aside",
                     run_remove)
    remove.add_argument("name", help="the sensor")
    _preview_and_json(remove)

    restore = command("restore", "put a removed sensor back with its captures and accepted results", run_restore)
    restore.add_argument("removal", help="the removal's id, as 'sensor list' shows it (e.g. lidar_top-1)")
    _preview_and_json(restore)


def _preview_and_json(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--preview", action="store_true", help="only say what would change and move")
    parser.add_argument("--json", action="store_true", help="print the change as one JSON object")


def _session(args: argparse.Namespace):
    from backend.store.session import Session

    return Session.load(args.session_dir)


def run_list(args: argparse.Namespace) -> dict[str, Any]:
    """``{"sensors": [{"name", "kind", "parent", "driver"}], "removed": [...]}`` (the API's removed listing)."""
    session = _session(args)
    sensors = [{"name": f.name, "kind": f.kind, "parent": f.parent, "driver": f.device.get("driver")}
               for f in session.rig.sensors()]
    removed = session.removed()
    if not args.json:
        for s in sensors:
            print(f"{s['name']} ({s['kind']}) under {s['parent']}{' · ' + s['driver'] if s['driver'] else ''}")
        for r in removed:
            print(f"removed: {r['sensor']} ({r['kind']}) as {r['id']}: {r['captures']} capture(s), "
                  f"{len(r['results'])} result(s) kept")
    return {"sensors": sensors, "removed": removed}


def _mount_sigma(args: argparse.Namespace):
    from backend.calib.rig.service import KEEP

    if args.mount_unknown:
        return None
    if args.mount_sigma is None:
        return KEEP
    try:
        sigma_m, sigma_deg = (float(v) for v in args.mount_sigma.split(","))
    except ValueError:
        raise InputError(f"expected two comma-separated numbers M,DEG, got {shorten(args.mount_sigma)}",
                         "--mount-sigma") from None
    return sigma_m, sigma_deg


def run_edit(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.rig.service import SensorEdit, edit_sensor
    from backend.devices.device_spec import parse_device_spec

    T_mount = None if args.xyzypr is None else parse_xyzypr(args.xyzypr, "--xyzypr")
    device = None if args.device is None else parse_device_spec(args.device)
    edit = SensorEdit(parent=args.parent, T_mount=T_mount, mount_sigma=_mount_sigma(args), device=device)
    return _report(edit_sensor(_session(args), args.name, edit, preview=args.preview).to_dict(), args.json)


def run_remove(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.rig.service import remove_sensor

    return _report(remove_sensor(_session(args), args.name, preview=args.preview).to_dict(), args.json)


def run_restore(args: argparse.Namespace) -> dict[str, Any]:
    from backend.calib.rig.service import restore_sensor

    return _report(restore_sensor(_session(args), args.removal, preview=args.preview).to_dict(), args.json)


def _report(change: dict[str, Any], as_json: bool) -> dict[str, Any]:
    """Say what the change did (or would do) on stdout unless ``as_json``; problems go to stderr either way."""
    for problem in change["problems"]:
        print(f"warning: {problem}", file=sys.stderr)
    if as_json:
        return change
    would = "" if change["applied"] else "would be "
    print(f"{change['sensor']}: {change['action']} {'' if change['applied'] else '(preview, nothing written)'}")
    if change["removal"] and change["action"] == "remove":
        print(f"  kept aside as {change['removal']['id']}: restore with 'calib-studio sensor restore "
              f"SESSION_DIR {change['removal']['id']}'")
    for slot in change["emptied"]:
        print(f"  {slot}: {would}emptied")
    for slot in change["restored"]:
        print(f"  {slot}: {would}restored")
    for slot, why in change["not_restored"].items():
        print(f"  {slot}: not restored ({why})")
    for move in change["moves"]:
        ratio = "" if move["sigma_ratio"] is None else f", {move['sigma_ratio']:.1f} sigma"
        print(f"  {move['frame']} {'moves' if change['applied'] else 'would move'} {1000 * move['trans_m']:.1f} mm, "
              f"{move['rot_deg']:.2f} deg{ratio}")
    return change
