"""A depth-camera network: layout, nodes, depth captures, solves, the guided procedure, verification, the map.

Thin routes over :mod:`backend.calib.depth.service` and :mod:`backend.calib.depth.guided_service`; solves run as
jobs (poll ``/api/jobs/{id}``). Presence and live captures go through the process's open
:class:`~backend.devices.node_network.NodeNetwork` (the demo's, or the one the studio's depth-network step
listens on) when there is one.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Depends, File, Form, Query, UploadFile
from fastapi.responses import PlainTextResponse

from backend.api.depth_schemas import (
    DepthAccept,
    DepthNodeCreate,
    GuidedFinish,
    GuidedStart,
    GuidedStep,
    LayoutBody,
    LiveCapture,
    NetworkSolveRequest,
    NodeSolveRequest,
    PickRequest,
    VerificationCreate,
)
from backend.api.routes import deps
from backend.api.schemas import JobStatus
from backend.api.uploads import UploadRoute, read_image_upload, upload_limit
from backend.calib.depth import guided_service as guided
from backend.calib.depth import service
from backend.core.depth import pose_row
from backend.core.errors import InputError
from backend.core.limits import MAX_IMAGE_UPLOAD_MB
from backend.devices.base import Sample
from backend.devices.node_network import NodeNetwork, NodeStatus, open_network

router = APIRouter(prefix="/sessions/{name}/depth-network", tags=["depth network"], route_class=UploadRoute)

MAX_MAP_VOXELS = 300_000
"""Most voxels the map route returns (the densest first); ``max_voxels`` asks for fewer."""


@router.get("/layout")
def get_layout(session: deps.SessionDep) -> dict[str, Any]:
    """The cell's known geometry (tables, floor lines, crosses, measured distances; m, world)."""
    return service.layout(session).to_dict()


@router.put("/layout")
def put_layout(body: LayoutBody, session: deps.SessionDep) -> dict[str, Any]:
    """Replace the cell's layout (the fields of ``GET .../layout``)."""
    return service.set_layout(session, body.model_dump()).to_dict()


@router.get("/nodes")
def nodes(session: deps.SessionDep) -> list[dict[str, Any]]:
    """Every depth node with its current pose (row and 4x4) and how many captures it holds."""
    return [{"name": node, "pose_row": list(pose_row(service.T_world_node(session, node))),
             "T_world_node": service.T_world_node(session, node).tolist(),
             "captures": len(service.captures(session, node))} for node in service.node_names(session)]


@router.post("/nodes", status_code=201)
def add_node(body: DepthNodeCreate, session: deps.SessionDep) -> dict[str, Any]:
    """Add a node under ``world`` at its measured pose (an empty rig is rooted at ``world`` first)."""
    frame = service.add_node(session, body.name, body.pose and body.pose.row(), body.mount_sigma, body.device)
    return {"name": frame.name, "pose_row": list(pose_row(frame.T_parent_child))}


@router.get("/nodes/{sensor}/captures")
def list_captures(sensor: str, session: deps.SessionDep) -> list[dict[str, Any]]:
    return [c.model_dump() for c in service.captures(session, sensor)]


@router.post("/nodes/{sensor}/captures", status_code=201)
@upload_limit(MAX_IMAGE_UPLOAD_MB, "depth")
def upload_capture(sensor: str, session: deps.SessionDep, depth: Annotated[UploadFile, File()],
                   amplitude: Annotated[UploadFile | None, File()] = None,
                   arrangement: Annotated[Literal["behind", "beside", "free"], Form()] = "free",
                   tables: Annotated[str, Form()] = "",
                   timestamp_s: Annotated[float, Form()] = 0.0) -> dict[str, Any]:
    """Add one depth frame: ``depth`` a ``.npy`` (float m or integer mm) or 16-bit ``.png`` (mm) of the node's
    512 x 424 image, ``amplitude`` (optional) the IR amplitude image alike, ``tables`` the comma-separated names
    of the layout's tables in view, ``arrangement`` how they stand (behind, beside, free)."""
    depth_name, depth_bytes = read_image_upload(depth, "depth", "depth.npy")
    depth_m = service.read_depth_upload(depth_name, depth_bytes, "depth")
    sample = Sample(float(timestamp_s), depth=depth_m, meta={"source": depth_name})
    if amplitude is not None:
        amplitude_name, amplitude_bytes = read_image_upload(amplitude, "amplitude", "amplitude.npy")
        image = service.read_depth_upload(amplitude_name, amplitude_bytes, "amplitude")
        if image.shape != depth_m.shape:
            raise InputError(f"{amplitude_name}: the amplitude image is {image.shape[1]}x{image.shape[0]} px; "
                             f"expected the depth image's {depth_m.shape[1]}x{depth_m.shape[0]}", "amplitude")
        sample.intensity, sample.meta["pixel_index"] = image.ravel(), np.arange(image.size)
    names = [t.strip() for t in tables.split(",") if t.strip()]
    return service.capture_node(session, sensor, sample, arrangement, names, device="upload",
                                source=depth_name).model_dump()


def _network() -> NodeNetwork:
    network = open_network()
    if network is None:
        raise InputError("no node network is open in this server: listen for nodes in the studio's depth-network "
                         "step (or start calib-studio demo --rig depth-cell), or upload the depth image",
                         "node_network", 409)
    return network


@router.get("/presence", dependencies=[Depends(deps.session)])
def presence() -> list[dict[str, Any]]:
    """The nodes the open node network sees or saw (alive, clock offset and round trip (s), bandwidth (B/s),
    frames, rate (Hz), dropped frames, latency (s), the Zenoh id holding the name, other agents refused under it,
    ``held``: why its captures wait); 404 for an unknown session, 409 without a network."""
    return [_presence_row(status) for status in _network().nodes()]


def _presence_row(status: NodeStatus) -> dict[str, Any]:
    """A node's status as the presence list gives it (its info reply left out)."""
    return {k: v for k, v in asdict(status).items() if k != "info"}


@router.get("/network", dependencies=[Depends(deps.session)])
def network_info() -> dict[str, Any]:
    """The open node network: where it listens, whether links need its keys (``secure``), the network's key
    fingerprint, the nodes its keys admit and the node key files it could not read; 409 without a network."""
    network = _network()
    keys = network.keys
    return {"listen": network.listen, "secure": network.secure, "admitted": network.admitted(),
            "fingerprint": None if keys is None else keys.studio.fingerprint,
            "problems": [] if keys is None else list(keys.problems)}


@router.post("/nodes/{sensor}/confirm-device", dependencies=[Depends(deps.session)])
def confirm_device(sensor: str) -> dict[str, Any]:
    """Confirm that a node which came back with another device or sensor serial is meant to: its live captures
    no longer wait (404 for a node never seen, 409 for one with no change to confirm)."""
    return _presence_row(_network().confirm_device(sensor))


@router.post("/nodes/{sensor}/capture-live", status_code=201)
def capture_live(sensor: str, body: LiveCapture, session: deps.SessionDep) -> dict[str, Any]:
    """Capture one full frame from the node's agent over the studio's node network (409 without one)."""
    network = _network()
    service.check_node(session, sensor)
    sample = network.capture(sensor, timeout_s=body.timeout_s)
    offset = next((s.clock_offset_s for s in network.nodes() if s.name == sensor), None)
    return service.capture_node(session, sensor, sample, body.arrangement, body.tables, device="node",
                                clock_offset_s=offset).model_dump()


@router.post("/nodes/{sensor}/solve", status_code=202, response_model=JobStatus)
def solve_node(sensor: str, body: NodeSolveRequest, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Solve the node's pose from its captures in the background (not accepted); the job's ``result_id``."""
    if not service.captures(session, sensor):  # fail fast, before queueing
        raise InputError(f"no depth captures of {sensor} yet; capture the node first", sensor)
    T_init = None if body.init is None else body.init.matrix()
    job = jobs.submit(f"depth node {sensor}", lambda progress: service.solve_session(session, sensor, progress,
                                                                                 T_init)["id"])
    return job.status() | {"result_id": None}


@router.post("/nodes/{sensor}/accept")
def accept_node(sensor: str, body: DepthAccept, session: deps.SessionDep) -> dict[str, Any]:
    """Accept a ``depth_node`` result of the node into the rig (a ``check`` verdict needs ``confirm``)."""
    return service.accept_node(session, sensor, body.result_id, body.confirm).to_dict()


@router.post("/solve", status_code=202, response_model=JobStatus)
def solve_network(body: NetworkSolveRequest, session: deps.SessionDep, jobs: deps.JobsDep) -> dict[str, Any]:
    """Solve and accept every node (optionally with ICP edges) in the background; the job's ``summary`` says
    which results were stored and accepted and what went wrong."""
    for node in body.nodes or []:
        service.check_node(session, node)
    job = jobs.submit("depth network", lambda progress: service.solve_network(
        session, body.nodes, icp=body.icp, confirm=body.confirm, progress=progress))
    return job.status() | {"result_id": None}


@router.get("/summary")
def summary(session: deps.SessionDep) -> dict[str, Any]:
    """``calib-studio depth-network --json``'s object: every node's pose, sigma and verdict, the verification."""
    return service.network_summary(session)


@router.get("/pose-table", response_class=PlainTextResponse)
def pose_table(session: deps.SessionDep) -> PlainTextResponse:
    """The pose table as text (X, Y, Z m; RotZ, RotY, RotX deg), then the verification table."""
    return PlainTextResponse(service.pose_table_text(service.network_summary(session)))


# -- the guided procedure ---------------------------------------------------------------------------


@router.get("/guided/{sensor}")
def guided_state(sensor: str, session: deps.SessionDep) -> dict[str, Any]:
    return guided.state(session, sensor)


@router.post("/guided/{sensor}/start")
def guided_start(sensor: str, body: GuidedStart, session: deps.SessionDep) -> dict[str, Any]:
    """Start from the measured pose (X, Y, Z m; RotZ, RotY, RotX deg)."""
    return guided.start(session, sensor, body.pose.row())


@router.post("/guided/{sensor}/advise")
def guided_advise(sensor: str, body: GuidedStep, session: deps.SessionDep) -> dict[str, Any]:
    """The step's residuals, suggestion and criterion at the current pose (nothing changes)."""
    return guided.advice_dict(guided.advise(session, sensor, body.step))


@router.post("/guided/{sensor}/apply")
def guided_apply(sensor: str, body: GuidedStep, session: deps.SessionDep) -> dict[str, Any]:
    """Take the step's suggestion; the state, with the step's advice at the new pose."""
    return guided.apply(session, sensor, body.step)


@router.post("/guided/{sensor}/nudge")
def guided_nudge(sensor: str, body: GuidedStart, session: deps.SessionDep) -> dict[str, Any]:
    """Set the pose by hand (X, Y, Z m; RotZ, RotY, RotX deg)."""
    return guided.nudge(session, sensor, body.pose.row())


@router.post("/guided/{sensor}/undo")
def guided_undo(sensor: str, session: deps.SessionDep) -> dict[str, Any]:
    return guided.undo(session, sensor)


@router.post("/guided/{sensor}/finish", status_code=201)
def guided_finish(sensor: str, body: GuidedFinish, session: deps.SessionDep) -> dict[str, Any]:
    """Keep the final pose as a result (method ``guided``), optionally accepting it."""
    return guided.finish(session, sensor, accept=body.accept, confirm=body.confirm)


# -- verification and the merged map -----------------------------------------------------------------


@router.get("/verification")
def verification(session: deps.SessionDep) -> list[dict[str, Any]]:
    """Measured against estimated distances at the nodes' current poses (m)."""
    return service.verification_rows(session)


@router.post("/verification", status_code=201)
def add_verification(body: VerificationCreate, session: deps.SessionDep) -> dict[str, Any]:
    """Add a laser-measured distance between two picked points."""
    return service.add_verification(session, body.a.model_dump(), body.b.model_dump(), body.measured_m)


@router.post("/verification/layout", status_code=201)
def verify_layout(session: deps.SessionDep) -> list[dict[str, Any]]:
    """Add a row for each of the layout's measured cross distances whose crosses the nodes see."""
    return service.verify_layout_distances(session)


@router.delete("/verification", status_code=204)
def remove_verification(index: Annotated[int, Query(ge=0, description="the row's index")],
                        session: deps.SessionDep) -> None:
    service.remove_verification(session, index)


@router.get("/targets")
def targets(session: deps.SessionDep) -> list[dict[str, Any]]:
    """The retroreflective crosses the nodes see, as pick targets (world, m)."""
    return service.detected_crosses(session)


@router.post("/pick")
def pick(body: PickRequest, session: deps.SessionDep) -> dict[str, Any]:
    """The cross or cloud point a ray (world, m) picks."""
    return service.pick(session, body.origin_m, body.direction)


@router.get("/voxel-map")
def voxel_map(session: deps.SessionDep,
              voxel_m: Annotated[float, Query(ge=0.005, le=2.0, description="voxel side, m")] = service.DEFAULT_VOXEL_M,
              max_voxels: Annotated[int, Query(ge=1, le=MAX_MAP_VOXELS)] = MAX_MAP_VOXELS) -> dict[str, Any]:
    """Every node's latest cloud merged on a grid (world): centres, counts, the node of most points per voxel."""
    return service.voxel_map_dict(session, service.merged_voxel_map(session, voxel_m), voxel_m, max_voxels)
