"""Making a node network's keys: a folder the studio listens with, and one file per node to copy to its computer.

``calib-studio node-keys KEYS_DIR --nodes sn1,sn2`` calls :func:`create_network_keys` (a new network) or
:func:`add_node_keys` (a node joins later); the studio's depth-network step and the depth-cell demo call
:func:`ensure_network_keys` (whichever of the two the rig's nodes need). The folder's layout is
:mod:`backend.devices.node_keys`'s; every file is written atomically and readable by its owner only (mode 0600).
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from backend.core.errors import InputError
from backend.devices.node_keys import (
    BUNDLE_SUFFIX,
    CA_CERTIFICATE,
    CA_KEY,
    NODES_FOLDER,
    STUDIO,
    STUDIO_BUNDLE,
    NetworkKeys,
    check_member_name,
    issue_bundle,
    load_network_keys,
    make_authority,
    read_authority,
)
from backend.store.atomic import write_bytes_atomic

MAX_NODES = 256
"""Most nodes issued keys at once."""


def create_network_keys(folder: Path, nodes: list[str]) -> NetworkKeys:
    """A new network's keys in ``folder`` (which must not exist yet, or be empty): the CA, the studio's bundle and
    one bundle per node. All or nothing: the files are made in a temp folder beside it, renamed into place."""
    folder = Path(folder)
    names = _new_names(nodes, [])
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise InputError(f"{folder.name} already exists and is not empty: network keys go into a new folder (add "
                         f"nodes to an existing network with --add)", "keys")
    authority = make_authority()
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(dir=folder.parent, prefix=f".{folder.name}."))
    try:
        write_bytes_atomic(staging / CA_CERTIFICATE, authority.certificate_pem())
        write_bytes_atomic(staging / CA_KEY, authority.key_pem())
        write_bytes_atomic(staging / STUDIO_BUNDLE, issue_bundle(authority, STUDIO))
        for name in names:
            write_bytes_atomic(staging / NODES_FOLDER / f"{name}{BUNDLE_SUFFIX}", issue_bundle(authority, name))
        if folder.exists():
            folder.rmdir()  # empty, checked above
        os.rename(staging, folder)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    os.chmod(folder, 0o700)
    return load_network_keys(folder)


def add_node_keys(folder: Path, nodes: list[str]) -> NetworkKeys:
    """Issue bundles for more nodes of the network in ``folder`` (signed by its CA); a name that already has one
    is refused, naming it. A studio listening already admits them once it listens again."""
    folder = Path(folder)
    keys = load_network_keys(folder)
    names = _new_names(nodes, list(keys.nodes))
    authority = read_authority(folder / CA_CERTIFICATE, folder / CA_KEY)
    for name in names:
        write_bytes_atomic(keys.bundle_path(name), issue_bundle(authority, name), exclusive=True)
    return load_network_keys(folder)


def ensure_network_keys(folder: Path, nodes: list[str]) -> NetworkKeys:
    """The network's keys in ``folder``, admitting every one of ``nodes``: made when the folder does not exist,
    else the nodes without keys are issued theirs."""
    folder = Path(folder)
    if not folder.exists():
        return create_network_keys(folder, nodes)
    keys = load_network_keys(folder)
    missing = [node for node in dict.fromkeys(nodes) if node not in keys.nodes]
    return add_node_keys(folder, missing) if missing else keys


def _new_names(nodes: list[str], issued: list[str]) -> list[str]:
    names = [check_member_name(str(node).strip()) for node in nodes]
    if not names:
        raise InputError("no node names: expected e.g. --nodes sn1,sn2", "nodes")
    if len(names) > MAX_NODES:
        raise InputError(f"{len(names)} nodes: at most {MAX_NODES} at once", "nodes")
    if STUDIO in names:
        raise InputError(f"'{STUDIO}' is the studio's own name in the network; name the nodes otherwise", "nodes")
    repeated = sorted({name for name in names if names.count(name) > 1} | (set(names) & set(issued)))
    if repeated:
        raise InputError(f"nodes {', '.join(repeated)} already have keys (or are named twice)", "nodes")
    return names
