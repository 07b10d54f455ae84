"""``calib-studio depth-network``, ``node``: a depth-camera network's poses, and the node agent a sensor's computer
runs."""

from __future__ import annotations

import argparse
import os
import threading
from pathlib import Path
from typing import Any

from backend.cli._common import prints_summary, progress_to_stderr


def add_parser(sub: argparse._SubParsersAction) -> None:
    network = sub.add_parser("depth-network", help="a depth-camera network: every node's pose in the world with "
                                                   "its uncertainty, and the laser-distance verification")
    network.add_argument("session_dir", type=Path, help="the session folder, e.g. sessions/depth-cell")
    network.add_argument("--solve", action="store_true",
                         help="solve every node from its captures first (and accept the results into the rig)")
    network.add_argument("--json", action="store_true", help="print the network as one JSON object")
    network.set_defaults(handler=prints_summary(run_depth_network))

    node = sub.add_parser("node", help="run a node agent on a sensor's computer: publish its frames over Zenoh "
                                       "and answer the studio's capture requests")
    node.add_argument("--name", required=True, help="the node's name in the rig, e.g. sn1")
    node.add_argument("--device", required=True,
                      help="what to capture from: sim-cell:NODE, kinect2[:SERIAL], realsense[:SERIAL], "
                           "depth-files:DIR, or a driver's JSON settings")
    node.add_argument("--connect", action="append", default=[], metavar="tls/HOST:7447",
                      help="a Zenoh endpoint to connect to (the studio's or a router's); repeatable")
    node.add_argument("--listen", action="append", default=[], metavar="tls/0.0.0.0:7448",
                      help="a Zenoh endpoint to listen on; repeatable")
    node.add_argument("--keys", type=Path, default=None, metavar="FILE",
                      help="this node's key bundle from the studio (NAME.keys.pem); default: the file the "
                           "environment variable CALIB_NODE_KEYS names; without either the node joins only a "
                           "network without keys (tcp/ endpoints)")
    node.add_argument("--rate", type=float, default=None, metavar="HZ",
                      help="frames published per second (default: the device's own rate)")
    node.add_argument("--voxel", type=float, default=0.02, metavar="M",
                      help="voxel size (m) of the published, compressed clouds (default 0.02; captures are full)")
    node.set_defaults(handler=run_node)

    keys = sub.add_parser("node-keys", help="make a node network's keys: the folder the studio listens with, and "
                                            "one file per node to copy to its computer")
    keys.add_argument("keys_dir", type=Path, help="a new folder for the keys, e.g. sessions/depth-cell/network-keys")
    keys.add_argument("--nodes", required=True, metavar="sn1,sn2",
                      help="the node names (comma-separated), each the --name its agent runs with")
    keys.add_argument("--add", action="store_true",
                      help="issue keys for more nodes of the network already in keys_dir (signed by its CA)")
    keys.add_argument("--json", action="store_true", help="print the folder and each node's key file as JSON")
    keys.set_defaults(handler=prints_summary(run_node_keys))


def run_depth_network(args: argparse.Namespace) -> dict[str, Any]:
    """Every node's ``T_world_node`` with its sigma and verdict, and the verification table (solving first with
    ``--solve``); the pose table on stdout without ``--json``."""
    from backend.calib.depth.service import network_summary, pose_table_text
    from backend.store.session import Session

    session = Session.load(args.session_dir)
    summary = network_summary(session, solve=args.solve, progress=progress_to_stderr(False))
    if not args.json:
        print(pose_table_text(summary))
    return summary


def run_node(args: argparse.Namespace) -> int:
    """Serve one sensor over Zenoh until interrupted (or, started by a studio, until that studio ends)."""
    import backend.sim.devices  # noqa: F401  (the node reaches devices without services: register the simulated ones)
    from backend.devices.node_agent import KEYS_ENV, PARENT_PID_ENV, run_agent, stop_with_parent
    from backend.devices.node_keys import read_bundle

    keys_file = args.keys or (Path(os.environ[KEYS_ENV]) if os.environ.get(KEYS_ENV, "").strip() else None)
    keys = None if keys_file is None else read_bundle(keys_file)
    stop = threading.Event()
    if os.environ.get(PARENT_PID_ENV, "").isdigit():
        stop_with_parent(int(os.environ[PARENT_PID_ENV]), stop)
    return run_agent(name=args.name, device=args.device, connect=args.connect, listen=args.listen,
                     rate_hz=args.rate, voxel_m=args.voxel, stop=stop, keys=keys)


def run_node_keys(args: argparse.Namespace) -> dict[str, Any]:
    """Make (or, with ``--add``, extend) a network's keys; the summary names the file each node takes."""
    from backend.services.network_keys import add_node_keys, create_network_keys

    names = [name.strip() for name in args.nodes.split(",") if name.strip()]
    keys = (add_node_keys if args.add else create_network_keys)(args.keys_dir, names)
    summary = {"keys_dir": str(keys.folder), "network": keys.studio.fingerprint,
               "nodes": {node: str(keys.bundle_path(node)) for node in keys.nodes}, "problems": list(keys.problems)}
    if not args.json:
        print(f"network {keys.studio.fingerprint}: keys in {keys.folder}")
        for node in names:
            print(f"  {node}: copy {keys.bundle_path(node)} to its computer; run {keys.agent_command(node)}")
    return summary
