"""A depth-camera network (issue 14), shared by the API, the studio and the CLI.

capture depth images per node (``captures/<node>/<id>.npz``: depth and IR amplitude, so the pixel structure
survives) -> :func:`observations` (the node's points with the tables the user says stood in view) -> the
constraint solve of each node's ``T_world_node`` (:mod:`backend.calib.depth.node`), stored as a
:class:`~backend.core.result.TransformResult` of kind ``depth_node`` (parent ``world``, child the node)
and accepted into the rig like every result (:func:`backend.calib.rig.service.accept`); pairwise ICP between
overlapping nodes only as extra edges beside those, never alone. The whole network: every node's latest
cloud in the world (:func:`world_clouds`), merged into a voxel map (:func:`merged_voxel_map`), the
retroreflective crosses found in it (:func:`detected_crosses`), a point picked by a ray (:func:`pick_point`),
and the verification table of laser-measured distances (:func:`add_verification`), whose estimates follow
the nodes' current poses. :func:`network_summary` is the CLI's ``depth-network --json`` contract.

The cell's layout, the guided state and the verification table live in the session's
``depth_network.json`` (:meth:`Session.depth_network`).
"""

from __future__ import annotations

import io
import itertools
from collections.abc import Mapping, Sequence
from typing import Any, Literal, NamedTuple

import numpy as np
from pydantic import ValidationError

from backend.calib._session import result_of
from backend.calib.rig import service as rig_service
from backend.core.depth import DepthIntrinsics, pose_from_row, stored_intrinsics
from backend.core.depth_cell import CellLayout, Cross, TableSpec, default_cell_layout
from backend.core.errors import InputError, shorten
from backend.core.limits import MAX_IMAGE_PIXELS
from backend.core.result import ProgressCallback, no_progress, transform_std
from backend.core.rig import DEFAULT_MOUNT_SIGMA, Frame, edge_slot
from backend.core.transforms import invert, transform_points
from backend.core.verdict import Verdict
from backend.devices.base import Sample
from backend.devices.image_io import check_pixels
from backend.exports.pose_table import format_pose_table, node_order, pose_table_rows
from backend.store.schema import CaptureRecord, DepthNetworkFile, VerificationEntry, VerificationPoint
from backend.store.session import Session, read_bounded_npy

WORLD = "world"
"""The root of a depth cell's rig: the cell's floor corner, Z up (m)."""
Arrangement = Literal["behind", "beside", "free"]
ARRANGEMENTS: tuple[str, ...] = ("behind", "beside", "free")
"""How the tables of a capture stand: behind each other (bottom to top of the view), beside each other
(left to right), or anywhere."""
CROSS_REFLECTIVITY = 3.0
"""Range-normalised IR amplitude ``amplitude * (range / 4 m)^2`` above which a pixel is retroreflective: a
diffuse surface stays below its albedo (< 1), a retroreflective cross returns far more."""
MIN_CROSS_PIXELS = 8
"""Fewest connected retroreflective pixels that make a cross."""
WHOLE_CROSS_EXTENT = 1.5
"""A cross is seen whole when its pixels span this many arm lengths (``Cross.size_m``) along world X and Y (both
bars end to end span two)."""
CROSS_NAME_RADIUS_M = 0.5
"""A cross found within this distance (m, world) of a cross of the layout takes its name."""
PARTIAL_CROSS_AREA = 0.6
"""A sighting of a cross covering less than this share of its best-seen area is partial and left out."""
CROSS_SNAP_M = 0.15
"""A pick ray passing within this distance (m) of a found cross picks the cross."""
PICK_RADIUS_M = 0.05
"""A pick ray passing within this distance (m) of a cloud point picks the nearest such point along the ray."""
ICP_OVERLAP_VOXEL_M = 0.25
"""Voxel (m) on which two nodes' world clouds are compared to decide whether they overlap."""
ICP_MIN_OVERLAP_VOXELS = 150
"""Shared voxels of :data:`ICP_OVERLAP_VOXEL_M` two nodes need before pairwise ICP is tried between them."""
MAX_CLOCK_OFFSET_S = 0.5
"""A node whose clock is further than this (s) off the studio's is named in the summary's problems."""
DEFAULT_VOXEL_M = 0.04
"""The merged map's voxel (m), as the paper shows it."""
MAX_UPLOAD_DEPTH_BYTES = 64 << 20
"""Largest depth or amplitude file read from an upload (bytes): a 512 x 424 float32 image is 0.9 MB."""


# ---------------------------------------------------------------------------------------------
# Layout and nodes


def state(session: Session) -> DepthNetworkFile:
    """The session's ``depth_network.json`` (empty when there is none; a broken one is quarantined, 422)."""
    return session.depth_network()


def layout(session: Session, network: DepthNetworkFile | None = None) -> CellLayout:
    """The cell's known geometry: as set for the session, else :func:`default_cell_layout`."""
    network = state(session) if network is None else network
    return default_cell_layout() if network.layout is None else CellLayout.from_dict(network.layout)


def set_layout(session: Session, data: Mapping[str, Any]) -> CellLayout:
    """Keep ``data`` (``CellLayout.to_dict``) as the session's layout; a malformed one is refused naming its field."""
    cell = CellLayout.from_dict(dict(data))
    names = [t.name for t in cell.tables] + [c.name for c in cell.crosses]
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InputError(f"cell layout: the names {repeated} are used twice; tables and crosses need unique names",
                         "layout")
    with session.lock:
        network = state(session)
        network.layout = cell.to_dict()
        session.save_depth_network(network)
    return cell


def node_names(session: Session) -> list[str]:
    """The rig's depth nodes, in natural order (``sn1`` ... ``sn10``)."""
    return node_order(f.name for f in session.rig.sensors("depth"))


def check_node(session: Session, node: str) -> Frame:
    """The node's frame; :class:`InputError` naming it if it is not a depth sensor of the rig."""
    frame = session.rig.get(node)
    if frame.kind != "depth":
        raise InputError(f"sensor {node!r} is a {frame.kind}, not a depth node", "node")
    return frame


def add_node(session: Session, node: str, pose: Sequence[float] | None = None,
             mount_sigma: tuple[float, float] | None = DEFAULT_MOUNT_SIGMA,
             device: Mapping[str, Any] | None = None) -> Frame:
    """Add depth node ``node`` under ``world`` at ``pose`` (the row X, Y, Z m, RotZ, RotY, RotX deg, from tape or a
    laser meter; identity when None, then with no mounting prior). An empty rig is rooted at ``world`` first."""
    with session.lock:
        if WORLD not in session.rig.frames:
            if len(session.rig.frames) > 1:
                raise InputError(f"a depth node hangs under the cell's {WORLD!r} frame, which this rig (rooted at "
                                 f"{session.rig.root!r}, with other frames) lacks: add a frame {WORLD!r} first, or "
                                 "calibrate the cell in a session of its own", "parent", 409)
            session.set_root(WORLD)
        T_world_node = np.eye(4) if pose is None else pose_from_row(pose)
        frame = Frame(node, WORLD, T_world_node, kind="depth", device=dict(device or {}),
                      mount_sigma=None if pose is None else mount_sigma)
        return session.add_sensor(frame)


def T_world_node(session: Session, node: str) -> np.ndarray:
    """The node's current pose in the cell (4x4, m): the fused rig tree's."""
    check_node(session, node)
    return session.rig.T_a_b(WORLD, node)


# ---------------------------------------------------------------------------------------------
# Captures


def capture_node(session: Session, node: str, sample: Sample, arrangement: Arrangement = "free",
                 tables: Sequence[str | TableSpec] = (), *, device: str = "node", source: str | None = None,
                 clock_offset_s: float | None = None, intrinsics: DepthIntrinsics | None = None) -> CaptureRecord:
    """Keep one depth frame of ``node``: ``sample.depth`` (H, W, m along the optical axis, 0 = no return) and
    its IR amplitude (``sample.meta["amplitude"]`` (H, W), else the image from ``sample.intensity`` at
    ``sample.meta["pixel_index"]``, or at the valid pixels when the counts agree; zeros when the sample has
    none), with the ``arrangement`` and the ``tables`` (names or specs, of the layout) that stood in view. The
    pinhole is ``intrinsics``, else the sample's ``meta["intrinsics"]``, else the Kinect v2's. ``record.meta``
    holds ``arrangement``, ``tables``, ``node_time_s``, ``clock_offset_s`` and ``intrinsics`` beside the driver's
    own facts. An empty or wrongly sized depth image is refused and nothing is stored."""
    check_node(session, node)
    if arrangement not in ARRANGEMENTS:
        raise InputError(f"arrangement {shorten(arrangement)}: expected one of {list(ARRANGEMENTS)}", "arrangement")
    cell = layout(session)
    names = [t.name if isinstance(t, TableSpec) else str(t) for t in tables]
    for name in names:
        cell.table(name)
    if len(set(names)) != len(names):
        raise InputError(f"tables {names}: a table can stand only once in one capture", "tables")
    if sample.depth is None:
        raise InputError(f"{source or node}: the frame holds no depth image (is the node a depth camera?)", "depth")
    depth = np.asarray(sample.depth, dtype=np.float32)
    intrinsics = intrinsics or _sample_intrinsics(sample)
    _, index = intrinsics.unproject(depth)  # checks the size
    if not len(index):
        raise InputError(f"{source or node}: the depth image holds no return within {intrinsics.min_range_m:g}-"
                         f"{intrinsics.max_range_m:g} m (0 of {depth.size} px); is the lens covered or the "
                         "node facing away?", "depth")
    amplitude = _amplitude_image(sample, depth.shape, index)
    meta = sample.storable_meta() | {
        "arrangement": arrangement, "tables": names, "node_time_s": sample.meta.get("node_time_s"),
        "clock_offset_s": clock_offset_s if clock_offset_s is not None else sample.meta.get("clock_offset_s"),
        "intrinsics": intrinsics.to_dict()}
    if amplitude is None:
        meta["amplitude_missing"] = True
        amplitude = np.zeros_like(depth)
    return session.add_depth_capture(node, depth, amplitude, {"timestamp_s": sample.timestamp_s, "device": device,
                                                             "source": source, "meta": meta})


def _sample_intrinsics(sample: Sample) -> DepthIntrinsics:
    """The pinhole a source put in ``sample.meta["intrinsics"]``, else the Kinect v2's."""
    return stored_intrinsics(sample.meta)


def _amplitude_image(sample: Sample, shape: tuple[int, ...], valid_index: np.ndarray) -> np.ndarray | None:
    """The (H, W) IR amplitude image of a sample (its ``meta["amplitude"]``, or its ``intensity`` placed at its
    points' pixels), or None."""
    image = sample.meta.get("amplitude")
    if isinstance(image, np.ndarray) and image.shape == shape:
        return image.astype(np.float32)
    if sample.intensity is None:
        return None
    values = np.asarray(sample.intensity, dtype=np.float32).ravel()
    index = sample.meta.get("pixel_index")
    index = valid_index if index is None else np.asarray(index, dtype=np.int64).ravel()
    if len(index) != len(values) or (len(index) and (index.min() < 0 or index.max() >= np.prod(shape))):
        return None
    image = np.zeros(int(np.prod(shape)), np.float32)
    image[index] = values
    return image.reshape(shape)


def read_depth_upload(name: str, data: bytes, what: Literal["depth", "amplitude"] = "depth") -> np.ndarray:
    """A depth image (H, W, float32 m) from an uploaded ``.npy`` (float m, or integer mm) or 16-bit ``.png`` (mm),
    or an amplitude image (``what="amplitude"``, values as they are). Sizes are checked from the header before
    decoding; an unreadable file raises :class:`InputError` naming it."""
    suffix = name.lower().rsplit(".", 1)[-1] if "." in name else ""
    if len(data) > MAX_UPLOAD_DEPTH_BYTES:
        raise InputError(f"{name}: {len(data):,} bytes, more than the {MAX_UPLOAD_DEPTH_BYTES:,}-byte limit on a "
                         f"{what} image", name, 413)
    if suffix == "npy":
        try:
            image = read_bounded_npy(io.BytesIO(data), name, MAX_IMAGE_PIXELS.value())
        except (ValueError, EOFError) as exc:
            raise InputError(f"{name}: not a readable .npy {what} image ({exc})", name) from None
        integer = image.dtype.kind in "iu"
    elif suffix == "png":
        import cv2

        check_pixels(data, name)
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_ANYDEPTH)
        if image is None:
            raise InputError(f"{name}: not a readable PNG", name)
        if what == "depth" and image.dtype != np.uint16:
            raise InputError(f"{name}: a {image.dtype} PNG holds no depth; expected a 16-bit PNG of millimetres", name)
        integer = True
    else:
        raise InputError(f"{name}: expected a .npy (m, or integer mm) or a 16-bit .png (mm) {what} image", name)
    if image.ndim != 2:
        raise InputError(f"{name}: a {what} image is H x W; got shape {image.shape}", name)
    image = image.astype(np.float32)
    return image / 1000.0 if what == "depth" and integer else image


def captures(session: Session, node: str, arrangement: str | None = None) -> list[CaptureRecord]:
    """The node's depth captures (oldest first), optionally only those of one ``arrangement``."""
    check_node(session, node)
    return [c for c in session.captures(node) if c.image_size is not None and c.meta.get("arrangement") is not None
            and (arrangement is None or c.meta["arrangement"] == arrangement)]


def capture_intrinsics(record: CaptureRecord) -> DepthIntrinsics:
    """The pinhole a depth capture was taken with (stored in its meta; the Kinect v2's otherwise)."""
    return stored_intrinsics(record.meta)


def observations(session: Session, node: str, arrangement: str | None = None,
                 cell: CellLayout | None = None) -> list[Any]:
    """The node's captures (optionally of one ``arrangement``) as the solvers' ``DepthObservation``: points (N, 3,
    m, node frame) of the valid pixels, their amplitude and flat pixel index, the tables in view (of the layout)."""
    from backend.calib.depth.features import DepthObservation

    cell = layout(session) if cell is None else cell
    out = []
    for record in captures(session, node, arrangement):
        depth, amplitude = session.depth_capture(node, record.id)
        points, index = capture_intrinsics(record).unproject(depth)
        out.append(DepthObservation(capture_id=record.id, points=points, amplitude=amplitude.ravel()[index],
                                    pixel_index=index, tables=[cell.table(t) for t in record.meta.get("tables", [])],
                                    arrangement=record.meta["arrangement"], intrinsics=capture_intrinsics(record)))
    return out


# ---------------------------------------------------------------------------------------------
# Solves


def solve_session(session: Session, node: str, progress: ProgressCallback = no_progress,
               T_init: np.ndarray | None = None) -> dict[str, Any]:
    """Solve ``T_world_node`` from every capture of ``node`` (floor, tables, lines and surveyed points of the
    layout; :func:`backend.calib.depth.node.solve_depth_node`) from ``T_init`` (default: the rig's current
    pose) and store the result (not yet accepted) under the node; the stored record (its ``id``, the
    :class:`~backend.core.result.TransformResult` record, ``inputs``: the capture ids). Evidence that does not
    fix all six degrees of freedom raises :class:`InputError` naming what is missing; nothing is stored then."""
    from backend.calib.depth.node import solve_depth_node

    cell = layout(session)
    observed = observations(session, node, cell=cell)
    if not observed:
        raise InputError(f"no depth captures of {node} yet; capture the node first", node)
    T_init = T_world_node(session, node) if T_init is None else np.asarray(T_init, dtype=float)
    result = solve_depth_node(node, observed, cell, T_init, progress=progress).named(WORLD, node)
    return session.result(session.add_result(node, result.to_record(), inputs=[o.capture_id for o in observed]))


def accept_node(session: Session, node: str, result_id: str, confirm: bool = False) -> rig_service.RigUpdate:
    """Accept a ``depth_node`` result of ``node`` into the rig (a ``check`` verdict needs ``confirm``)."""
    result_of(session, "depth_node", result_id, node)
    return rig_service.accept(session, result_id, confirm=confirm)


def solve_nodes(session: Session, nodes: Sequence[str] | None = None,
                progress: ProgressCallback = no_progress) -> dict[str, Any]:
    """Solve every node (default: all with captures), accepting none: ``{"results": {node: result_id},
    "problems": [...]}``, a node that cannot be solved named in ``problems`` and the others solved."""
    nodes = [n for n in node_names(session) if captures(session, n)] if nodes is None else list(nodes)
    out: dict[str, Any] = {"results": {}, "problems": []}
    for i, node in enumerate(nodes):
        progress(i / max(len(nodes), 1), f"solving {node}")
        try:
            out["results"][node] = solve_session(session, node)["id"]
        except InputError as exc:
            out["problems"].append(f"{node}: {exc.message}")
    return out


def solve_network(session: Session, nodes: Sequence[str] | None = None, *, icp: bool = False,
                  confirm: bool = False, progress: ProgressCallback = no_progress) -> dict[str, Any]:
    """Solve and accept every node (default: all with captures; the CLI's ``--solve`` and the API's job); with
    ``icp``, pairwise ICP between nodes whose clouds overlap is added as extra edges, only between nodes that a
    constraint solve placed. Returns ``{"results": {node: result_id}, "accepted": [result ids], "icp": [result
    ids], "problems": [...]}``: a node that cannot be solved, or whose verdict keeps it out (``check`` without
    ``confirm``, ``reject``), is named in ``problems`` and the others go on."""
    out = solve_nodes(session, nodes, lambda fraction, text: progress(fraction * (0.8 if icp else 1.0), text))
    out |= {"accepted": [], "icp": []}
    placed = []
    for node, result_id in out["results"].items():
        try:
            accept_node(session, node, result_id, confirm)
            out["accepted"].append(result_id)
            placed.append(node)
        except InputError as exc:
            out["problems"].append(f"{node}: {exc.message}")
    if icp:
        progress(0.8, "pairwise ICP between overlapping nodes")
        _icp_edges(session, placed, confirm, out)
    return out


def _icp_edges(session: Session, nodes: Sequence[str], confirm: bool, out: dict[str, Any]) -> None:
    """Pairwise ICP (``backend.calib.depth.icp.pairwise_icp``) between every two ``nodes`` whose world clouds
    share :data:`ICP_MIN_OVERLAP_VOXELS`; each result (parent the first node, child the second) is stored and
    accepted as one more edge, which the rig graph weighs against the constraint solves (and flags if it
    disagrees)."""
    from backend.calib.depth.icp import pairwise_icp

    clouds = world_clouds(session, nodes)
    for a, b in itertools.combinations([n for n in nodes if n in clouds], 2):
        keys_a = np.unique(np.floor(clouds[a][0] / ICP_OVERLAP_VOXEL_M).astype(np.int64), axis=0)
        keys_b = np.unique(np.floor(clouds[b][0] / ICP_OVERLAP_VOXEL_M).astype(np.int64), axis=0)
        shared = len(np.concatenate([keys_a, keys_b])) - len(np.unique(np.concatenate([keys_a, keys_b]), axis=0))
        if shared < ICP_MIN_OVERLAP_VOXELS:
            continue
        try:
            result = pairwise_icp(a, clouds[a][0], b, clouds[b][0], T_world_node(session, a),
                                  T_world_node(session, b), None)
            result_id = session.add_result(b, result.to_record(), inputs=[f"{a}:{b}"])
            out["icp"].append(result_id)
            rig_service.accept(session, result_id, confirm=confirm)
            out["accepted"].append(result_id)
        except InputError as exc:
            out["problems"].append(f"ICP {a} to {b}: {exc.message}")


# ---------------------------------------------------------------------------------------------
# The whole network


def world_clouds(session: Session, nodes: Sequence[str] | None = None) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each node's latest capture in the world at its current pose: points (N, 3, m) and amplitude (N,); nodes
    without captures are left out."""
    out = {}
    for node in node_names(session) if nodes is None else nodes:
        latest = captures(session, node)[-1:]
        if not latest:
            continue
        depth, amplitude = session.depth_capture(node, latest[0].id)
        points, index = capture_intrinsics(latest[0]).unproject(depth)
        out[node] = (transform_points(T_world_node(session, node), points), amplitude.ravel()[index])
    return out


class VoxelMap(NamedTuple):
    """Every node's cloud accumulated on a grid in the world: the paper's merged map."""

    centres_m: np.ndarray
    """(M, 3) voxel centres, world frame, m."""
    counts: np.ndarray
    """(M,) points in each voxel (the map's intensity)."""
    node_index: np.ndarray
    """(M,) index into :func:`node_names` of the node with most points in each voxel."""


def voxel_map_dict(session: Session, voxel_map: VoxelMap, voxel_m: float, max_voxels: int | None = None
                   ) -> dict[str, Any]:
    """JSON form of a :func:`merged_voxel_map`; with ``max_voxels``, only the densest that many (``truncated``)."""
    keep = np.arange(len(voxel_map.counts))
    if max_voxels is not None and len(keep) > max_voxels:
        keep = np.sort(np.argsort(-voxel_map.counts, kind="stable")[:max_voxels])
    return {"voxel_m": voxel_m, "nodes": node_names(session), "n_voxels": len(voxel_map.counts),
            "truncated": len(keep) < len(voxel_map.counts),
            "centres_m": np.round(voxel_map.centres_m[keep], 4).tolist(),
            "counts": voxel_map.counts[keep].tolist(), "node_index": voxel_map.node_index[keep].tolist()}


def merged_voxel_map(session: Session, voxel_m: float = DEFAULT_VOXEL_M, nodes: Sequence[str] | None = None
                     ) -> VoxelMap:
    """Every node's latest cloud in the world (at the current poses) on a ``voxel_m`` grid: voxel centres (M, 3,
    m), the point count per voxel and which node (index into :func:`node_names`) gave most of its points."""
    if not np.isfinite(voxel_m) or not 0.005 <= voxel_m <= 2.0:
        raise InputError(f"voxel size {voxel_m} m: expected 0.005 to 2 m", "voxel_m")
    clouds = world_clouds(session, nodes)
    if not clouds:
        return VoxelMap(np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64))
    names = node_names(session)
    points = np.concatenate([cloud for cloud, _ in clouds.values()])
    owner = np.concatenate([np.full(len(cloud), names.index(n)) for n, (cloud, _) in clouds.items()])
    cells = np.floor(points / voxel_m).astype(np.int64)
    low, span = cells.min(axis=0), np.ptp(cells, axis=0) + 1
    flat_keys, inverse, counts = np.unique((cells[:, 0] - low[0]) * span[1] * span[2] + (cells[:, 1] - low[1])
                                           * span[2] + (cells[:, 2] - low[2]), return_inverse=True,
                                           return_counts=True)  # one integer per cell: 1-D unique is fast
    keys = np.column_stack(np.unravel_index(flat_keys, tuple(span))) + low
    combos, combo_counts = np.unique(inverse.ravel() * len(names) + owner, return_counts=True)
    voxel_of, node_of = combos // len(names), combos % len(names)
    order = np.lexsort((-combo_counts, voxel_of))  # per voxel, its largest node count first
    first = order[np.r_[True, voxel_of[order][1:] != voxel_of[order][:-1]]]
    return VoxelMap((keys + 0.5) * voxel_m, counts, node_of[first])


def cross_sightings(session: Session, nodes: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """The retroreflective crosses each node's latest capture sees: connected pixels whose range-normalised
    amplitude exceeds :data:`CROSS_REFLECTIVITY`, seen whole (clusters touching the image border, or whose extent
    along world X or Y is under :data:`WHOLE_CROSS_EXTENT` arm lengths, are left out: cut or hidden in part, their
    centre would be biased). Each centre is the solvers' :func:`~backend.calib.depth.features.cross_centre`
    of its points at the node's current pose (bars along world X and Y) and ``area_m2`` the floor area its pixels
    cover (a pixel's footprint grows as range^2 / cos(incidence)). ``[{"name" (the layout's cross within
    :data:`CROSS_NAME_RADIUS_M`, else ``cross@NODE#k``), "node", "point_m" (world), "point_node_m", "n_pixels",
    "area_m2"}]``."""
    from scipy import ndimage

    from backend.calib.depth.features import cross_centre

    cell = layout(session)
    found = []
    for node in node_names(session) if nodes is None else nodes:
        latest = captures(session, node)[-1:]
        if not latest:
            continue
        depth, amplitude = session.depth_capture(node, latest[0].id)
        intrinsics = capture_intrinsics(latest[0])
        rays = intrinsics.rays()
        with np.errstate(invalid="ignore"):
            bright = (depth > 0) & (amplitude * (depth * np.linalg.norm(rays, axis=2) / 4.0) ** 2
                                    > CROSS_REFLECTIVITY)
        labels, count = ndimage.label(bright, structure=np.ones((3, 3)))
        if not count:
            continue
        T = T_world_node(session, node)
        up_node = T[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        flat = labels.ravel()
        pixels = np.flatnonzero(flat)
        points = rays.reshape(-1, 3)[pixels] * depth.ravel()[pixels, None]
        ranges = np.linalg.norm(points, axis=1)
        area = ranges**2 / (intrinsics.fx * intrinsics.fy) / np.clip(np.abs(points @ up_node) / ranges, 0.05, None)
        label = flat[pixels]
        total = np.bincount(label, weights=area, minlength=count + 1)
        n_pixels = np.bincount(label, minlength=count + 1)
        border = set(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]).tolist())
        points_world = transform_points(T, points)
        T_node_world = invert(T)
        for k in range(1, count + 1):
            if n_pixels[k] < MIN_CROSS_PIXELS or k in border:
                continue
            blob = points_world[label == k]
            centre = cross_centre(blob)
            name = _cross_name(cell, centre, f"cross@{node}#{k}")
            size_m = next((c.size_m for c in cell.crosses if c.name == name), Cross.size_m)
            if (np.ptp(blob[:, :2], axis=0) < WHOLE_CROSS_EXTENT * size_m).any():
                continue  # a bar not seen end to end: hidden in part (a table) or cut by the range limit
            centre_node = transform_points(T_node_world, centre[None])[0]
            found.append({"name": name, "node": node,
                          "point_m": centre.tolist(), "point_node_m": centre_node.tolist(),
                          "n_pixels": int(n_pixels[k]), "area_m2": float(total[k])})
    return found


def detected_crosses(session: Session, nodes: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """Every cross the nodes see, as a pick target: ``{"name", "point_m" (world, m), "views": [{"node",
    "point_node_m", "weight"}], "n_pixels"}``, its position the pixel-weighted mean of its sightings
    (:func:`cross_sightings`) at the nodes' current poses. A sighting covering less than
    :data:`PARTIAL_CROSS_AREA` of the cross's best-seen area (or of the median sighting's, crosses being alike)
    is left out (part of it hidden or out of range: its centre would be biased). Several nodes' sightings average
    each one's pixel aliasing (a bar of a cross is about two pixels wide from the ceiling)."""
    sightings_all = cross_sightings(session, nodes)
    if not sightings_all:
        return []
    typical_area = float(np.median([s["area_m2"] for s in sightings_all]))
    by_name: dict[str, list[dict[str, Any]]] = {}
    for sighting in sightings_all:
        by_name.setdefault(sighting["name"], []).append(sighting)
    targets = []
    for name, sightings in sorted(by_name.items()):
        whole_area = max(typical_area, *(s["area_m2"] for s in sightings))
        kept = [s for s in sightings if s["area_m2"] >= PARTIAL_CROSS_AREA * whole_area]
        if not kept:
            continue
        views = [{"node": s["node"], "point_node_m": s["point_node_m"], "weight": float(s["n_pixels"])} for s in kept]
        weights = np.array([v["weight"] for v in views])
        centre = (np.array([s["point_m"] for s in kept]) * weights[:, None]).sum(0) / weights.sum()
        targets.append({"name": name, "kind": "cross", "point_m": centre.tolist(), "views": views,
                        "n_pixels": int(weights.sum())})
    return targets


def _cross_name(cell: CellLayout, point_m: np.ndarray, fallback: str) -> str:
    """The layout's cross within :data:`CROSS_NAME_RADIUS_M` of ``point_m`` (world, m), or ``fallback``."""
    if not cell.crosses:
        return fallback
    positions = np.array([c.position_m for c in cell.crosses])
    distances = np.linalg.norm(positions - point_m, axis=1)
    nearest = int(np.argmin(distances))
    return cell.crosses[nearest].name if distances[nearest] <= CROSS_NAME_RADIUS_M else fallback


def pick_point(session: Session, origin_m: Sequence[float], direction: Sequence[float]) -> np.ndarray:
    """The world point (3, m) a click's ray picks (:func:`pick`)."""
    return np.array(pick(session, origin_m, direction)["point_m"])


def pick(session: Session, origin_m: Sequence[float], direction: Sequence[float]) -> dict[str, Any]:
    """The point a click's ray (``origin_m``, ``direction``: world frame, m) picks in the merged cloud: a found
    cross within :data:`CROSS_SNAP_M` of the ray (:func:`detected_crosses`), else the nearest cloud point along the
    ray within :data:`PICK_RADIUS_M` of it. ``{"name", "kind": "cross" | "point", "point_m", "views",
    "ray_distance_m"}``, ready for :func:`add_verification`; :class:`InputError` when the ray misses everything."""
    origin = np.asarray(origin_m, dtype=float)
    ray = np.asarray(direction, dtype=float)
    if origin.shape != (3,) or ray.shape != (3,) or not (np.isfinite(origin).all() and np.isfinite(ray).all()):
        raise InputError("a pick ray is an origin and a direction of three finite numbers each (m, world)", "ray")
    if np.linalg.norm(ray) < 1e-9:
        raise InputError("the pick ray's direction is zero", "direction")
    ray = ray / np.linalg.norm(ray)

    def along_and_off(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        offset = points - origin
        along = offset @ ray
        return along, np.linalg.norm(offset - along[:, None] * ray, axis=1)

    targets = detected_crosses(session)
    if targets:
        along, off = along_and_off(np.array([t["point_m"] for t in targets]))
        near = np.flatnonzero((off <= CROSS_SNAP_M) & (along > 0))
        if len(near):
            best = near[np.argmin(along[near])]
            return targets[best] | {"ray_distance_m": float(off[best])}
    best_hit: dict[str, Any] | None = None
    for node, (points, _) in world_clouds(session).items():
        along, off = along_and_off(points)
        near = np.flatnonzero((off <= PICK_RADIUS_M) & (along > 0))
        if len(near) and (best_hit is None or along[near].min() < best_hit["along"]):
            i = near[np.argmin(along[near])]
            point_node = transform_points(invert(T_world_node(session, node)), points[i][None])[0]
            best_hit = {"along": float(along[i]), "name": f"{node} point", "kind": "point",
                        "point_m": points[i].tolist(),
                        "views": [{"node": node, "point_node_m": point_node.tolist(), "weight": 1.0}],
                        "ray_distance_m": float(off[i])}
    if best_hit is None:
        raise InputError(f"the ray misses every node's cloud (nothing within {PICK_RADIUS_M * 1000:.0f} mm of it)",
                         "ray")
    best_hit.pop("along")
    return best_hit


# ---------------------------------------------------------------------------------------------
# Verification


def _point_now(session: Session, point: VerificationPoint) -> np.ndarray:
    """A picked point (world, m) at the current poses: the weighted mean of its views, each moving with its node
    (a point without views, or whose nodes are gone, stays where it was picked)."""
    views = [v for v in point.views if v.node in session.rig.frames]
    if not views:
        return np.array(point.point_m, dtype=float)
    weights = np.array([v.weight for v in views])
    positions = np.array([transform_points(T_world_node(session, v.node), np.array([v.point_node_m]))[0]
                          for v in views])
    return (positions * weights[:, None]).sum(0) / weights.sum()


def verification_row(session: Session, entry: VerificationEntry, index: int) -> dict[str, Any]:
    """``{"a", "b" (names), "measured_m", "estimated_m", "error_m" (estimated - measured), "index", "a_m", "b_m"
    (world points now, m)}``."""
    a, b = _point_now(session, entry.a), _point_now(session, entry.b)
    estimated = float(np.linalg.norm(a - b))
    return {"a": entry.a.name, "b": entry.b.name, "measured_m": entry.measured_m, "estimated_m": estimated,
            "error_m": estimated - entry.measured_m, "index": index, "a_m": a.tolist(), "b_m": b.tolist()}


def verification_rows(session: Session, network: DepthNetworkFile | None = None) -> list[dict[str, Any]]:
    """The verification table at the nodes' current poses."""
    network = state(session) if network is None else network
    return [verification_row(session, entry, i) for i, entry in enumerate(network.verification)]


def _verification_point(session: Session, data: Mapping[str, Any], field: str) -> VerificationPoint:
    """A verification end from a request (or :func:`pick`'s answer: extra keys are ignored)."""
    try:
        point = VerificationPoint.model_validate({k: data[k] for k in ("name", "point_m", "views") if k in data})
    except (ValidationError, TypeError, ValueError) as exc:
        raise InputError(f"verification point {field}: expected {{'name', 'point_m': [x, y, z] (m, world), "
                         f"optional 'views'}}; {shorten(str(exc), 300)}", field) from None
    for view in point.views:
        check_node(session, view.node)
    return point


def add_verification(session: Session, a: Mapping[str, Any], b: Mapping[str, Any], measured_m: float
                     ) -> dict[str, Any]:
    """Add a laser-measured distance ``measured_m`` (m) between two picked points ``a`` and ``b``
    (``{"name", "point_m"}`` world m, optionally ``views`` as :func:`pick` gives them) to the session's
    table; the row as :func:`verification_row` gives it."""
    point_a, point_b = _verification_point(session, a, "a"), _verification_point(session, b, "b")
    if not np.isfinite(measured_m) or not 0 < measured_m < 1000:
        raise InputError(f"measured distance {measured_m} m: expected a positive distance in metres", "measured_m")
    entry = VerificationEntry(a=point_a, b=point_b, measured_m=float(measured_m))
    with session.lock:
        network = state(session)
        network.verification.append(entry)
        session.save_depth_network(network)
        return verification_row(session, entry, len(network.verification) - 1)


def remove_verification(session: Session, index: int) -> None:
    """Drop row ``index`` of the verification table."""
    with session.lock:
        network = state(session)
        if not 0 <= index < len(network.verification):
            raise InputError(f"no verification row {index}; the table has {len(network.verification)}", "index", 404)
        del network.verification[index]
        session.save_depth_network(network)


def verify_layout_distances(session: Session) -> list[dict[str, Any]]:
    """Add a verification row for every laser-measured distance of the layout whose two crosses the nodes see
    (:func:`detected_crosses`) and that the table does not hold yet; the rows added."""
    targets = {t["name"]: t for t in detected_crosses(session)}
    present = {(e.a.name, e.b.name, e.measured_m) for e in state(session).verification}
    return [add_verification(session, targets[d.a], targets[d.b], d.measured_m) for d in layout(session).distances
            if d.a in targets and d.b in targets and (d.a, d.b, d.measured_m) not in present]


# ---------------------------------------------------------------------------------------------
# Summary


def node_verdict(session: Session, node: str) -> tuple[dict[str, Any], str | None]:
    """The verdict of the node's accepted ``world`` result and its id; a node with none is ``check`` (its pose
    is the mounting guess, or nothing at all)."""
    result_id = session.accepted(edge_slot(WORLD, node))
    if result_id is None:
        latest = session.results(node, "depth_node")
        why = (f"no accepted calibration (latest result {latest[-1]['id']} judged "
               f"{Verdict.from_record(latest[-1]).level}, not accepted)" if latest else "no calibration yet")
        return {"level": "check", "reasons": [f"{why}: the pose is the mounting guess"]}, None
    return Verdict.from_record(session.result(result_id)).to_dict(), result_id


def network_summary(session: Session, solve: bool = False, progress: ProgressCallback = no_progress,
                    confirm: bool = False) -> dict[str, Any]:
    """The CLI's ``depth-network --json`` object: ``{"nodes": {NODE: {"T_world_node", "std": {"trans_m": [3],
    "rot_deg": [3]}, "verdict"}}, "verification": [{"a", "b", "measured_m", "estimated_m", "error_m"}]}`` plus
    ``pose_table`` (rows of X, Y, Z m, RotZ, RotY, RotX deg) and ``problems``. Poses and sigmas are the fused rig
    tree's; with ``solve``, every node with captures is solved and accepted first (:func:`solve_network`)."""
    problems: list[str] = []
    if solve:
        problems += solve_network(session, confirm=confirm, progress=progress)["problems"]
    try:
        network = state(session)
    except InputError as exc:  # quarantined: the poses still stand, the table starts afresh
        problems.append(exc.message)
        network = DepthNetworkFile()
    nodes: dict[str, Any] = {}
    for node in node_names(session):
        frame = session.rig.get(node)
        covariance = frame.covariance if frame.covariance is not None else frame.mount_covariance
        verdict, result_id = node_verdict(session, node)
        nodes[node] = {"T_world_node": T_world_node(session, node).tolist(),
                       "std": transform_std(np.full((6, 6), np.nan) if covariance is None else covariance),
                       "verdict": verdict, "result_id": result_id, "captures": len(captures(session, node))}
        latest = captures(session, node)[-1:]
        if not latest:
            problems.append(f"{node}: no depth captures yet")
        elif abs(offset := latest[0].meta.get("clock_offset_s") or 0.0) > MAX_CLOCK_OFFSET_S:
            problems.append(f"{node}: its clock is {offset:+.2f} s off the studio's (capture {latest[0].id}); set "
                            "its clock (NTP or PTP): frames of several nodes are matched by time")
    if not nodes:
        problems.append("the rig has no depth nodes")
    rows = pose_table_rows({n: np.array(v["T_world_node"]) for n, v in nodes.items()},
                           {n: v["std"] for n, v in nodes.items()})
    return {"nodes": nodes, "verification": verification_rows(session, network), "pose_table": rows,
            "problems": problems}


def pose_table_text(summary: Mapping[str, Any]) -> str:
    """The summary as text: the pose table in the paper's order (X, Y, Z m; RotZ, RotY, RotX deg) with each node's
    largest sigma and verdict, then the verification table (mm) and any problems."""
    nodes = summary["nodes"]
    rows = pose_table_rows({n: np.array(v["T_world_node"]) for n, v in nodes.items()},
                           {n: v["std"] for n, v in nodes.items()})
    lines = [format_pose_table(rows, {n: v["verdict"]["level"] for n, v in nodes.items()})]
    if summary["verification"]:
        lines += ["", f"{'a':<14}{'b':<14}{'measured mm':>12}{'estimated mm':>14}{'error mm':>10}"]
        lines += [f"{r['a']:<14}{r['b']:<14}{r['measured_m'] * 1e3:>12.1f}{r['estimated_m'] * 1e3:>14.1f}"
                  f"{r['error_m'] * 1e3:>10.1f}" for r in summary["verification"]]
    lines += [f"problem: {p}" for p in summary.get("problems", [])]
    return "\n".join(lines)
