"""The observation graph of a multi-camera capture and the initial rig from a spanning tree of PnP poses.

Cameras are the graph's nodes; two cameras are joined by as many edges as frames in
which both saw the board. The initial rig walks the maximum spanning tree of that graph
(the pairs that shared the most frames) outward from the reference camera, so a camera
that never shares a frame with the reference still joins through the cameras between
them (as Kalibr and mrcal seed their rigs). Each tree edge's relative pose is the medoid
of the per-frame PnP estimates ``T_a_board @ inv(T_b_board)``, so a single bad detection
cannot pull it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass
from itertools import combinations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

from backend.calib.board.detection import Detection
from backend.calib.board.pose import board_pose
from backend.core.boards import BoardSpec
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.transforms import invert


@dataclass(frozen=True)
class Observation:
    """One camera's detection of the board in one frame (a moment all cameras were triggered together)."""

    camera: str
    frame: str
    detection: Detection


@dataclass
class ObservationGraph:
    """Which cameras saw the board together, and how often."""

    cameras: list[str]
    frames_seen: dict[str, int]
    """Frames in which each camera saw the board."""
    shared_frames: dict[tuple[str, str], int]
    """Frames seen by both cameras of a pair (pairs in camera order, only pairs that share at least one)."""

    def to_record(self) -> dict:
        return {"cameras": list(self.cameras), "frames_seen": dict(self.frames_seen),
                "edges": [{"a": a, "b": b, "frames": n} for (a, b), n in self.shared_frames.items()]}


def observation_graph(cameras: list[str], seen: Iterable[tuple[str, str]]) -> ObservationGraph:
    """Count the frames each camera and each pair of cameras saw the board in (``seen``: (camera, frame) pairs)."""
    by_frame: dict[str, set[str]] = {}
    for camera, frame in set(seen):
        by_frame.setdefault(frame, set()).add(camera)
    order = {name: i for i, name in enumerate(cameras)}
    shared: Counter[tuple[str, str]] = Counter()
    for seen in by_frame.values():
        shared.update(combinations(sorted(seen, key=order.__getitem__), 2))
    frames_seen = Counter(camera for seen_by in by_frame.values() for camera in seen_by)
    return ObservationGraph(list(cameras), {c: frames_seen.get(c, 0) for c in cameras},
                            dict(sorted(shared.items(), key=lambda item: (order[item[0][0]], order[item[0][1]]))))


def check_connected(graph: ObservationGraph) -> None:
    """Refuse a capture in which some camera cannot be related to the reference (the first camera)."""
    for name, n in graph.frames_seen.items():
        if n == 0:
            raise InputError(f"camera {name} did not see the board in any frame; check that the board spec fits "
                             f"its images and that it was pointed at the board", name)
    labels = _components(graph)
    lost = [c for c, label in zip(graph.cameras, labels, strict=True) if label != labels[0]]
    if lost:
        reached = [c for c, label in zip(graph.cameras, labels, strict=True) if label == labels[0]]
        raise InputError(f"camera {lost[0]} never sees the board in the same frame as {', '.join(reached)} "
                         f"(nor through other cameras): capture frames where {lost[0]} and one of them see the "
                         f"board together (frames are matched by number or timestamp)", lost[0])


def _adjacency(graph: ObservationGraph, weight_of_shared) -> csr_matrix:
    index = {name: i for i, name in enumerate(graph.cameras)}
    n = len(graph.cameras)
    rows = [index[a] for a, _ in graph.shared_frames]
    cols = [index[b] for _, b in graph.shared_frames]
    weights = [weight_of_shared(k) for k in graph.shared_frames.values()]
    return csr_matrix((weights, (rows, cols)), shape=(n, n))


def _components(graph: ObservationGraph) -> np.ndarray:
    _, labels = connected_components(_adjacency(graph, lambda k: 1.0), directed=False)
    return labels


def spanning_tree(graph: ObservationGraph) -> list[tuple[str, str]]:
    """``(parent, child)`` edges of the maximum spanning tree (most shared frames) from the first camera,
    in breadth-first order; ties break by camera order."""
    most = max(graph.shared_frames.values())
    # minimum_spanning_tree on (most + 1 - shared) keeps the pairs that shared most; weights stay > 0.
    tree = minimum_spanning_tree(_adjacency(graph, lambda k: float(most + 1 - k)))
    order, predecessors = breadth_first_order(tree, 0, directed=False)
    return [(graph.cameras[predecessors[i]], graph.cameras[i]) for i in order[1:]]


def board_poses_by_pnp(cameras: dict[str, CameraIntrinsics], board: BoardSpec, observations: list[Observation]
                       ) -> dict[tuple[str, str], np.ndarray]:
    """``T_camera_board`` (4x4, m) of every observation whose PnP succeeds, keyed by (camera, frame)."""
    poses = {}
    for obs in observations:
        T = board_pose(cameras[obs.camera], board, obs.detection)
        if T is not None and T[2, 3] > 0:
            poses[obs.camera, obs.frame] = T
    return poses


def _medoid(transforms: list[np.ndarray], length_m: float) -> np.ndarray:
    """The transform closest to all others: summed rotation angle (rad) plus translation distance / ``length_m``."""
    stack = np.stack(transforms)
    R, t = stack[:, :3, :3], stack[:, :3, 3]
    cos = (np.einsum("aij,bij->ab", R, R) - 1) / 2  # trace(Ra^T Rb) = 1 + 2 cos(angle)
    distance = np.arccos(np.clip(cos, -1, 1)) + np.linalg.norm(t[:, None] - t[None], axis=2) / length_m
    return stack[int(np.argmin(distance.sum(axis=1)))]


def initial_rig(cameras: dict[str, CameraIntrinsics], board: BoardSpec, observations: list[Observation]
                ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """``T_ref_cam`` per camera and ``T_ref_board`` per frame (4x4, m), the reference being the first of ``cameras``.

    Raises :class:`InputError` naming a camera whose PnP poses leave it unconnected.
    """
    T_cam_board = board_poses_by_pnp(cameras, board, observations)
    names = list(cameras)
    posed = observation_graph(names, T_cam_board)
    for name, n in posed.frames_seen.items():
        if n == 0:
            raise InputError(f"the board's pose could not be found in any view of camera {name} (PnP failed or put "
                             f"the board behind it): its intrinsics do not fit its images", name)
    check_connected(posed)
    frames_of: dict[str, dict[str, np.ndarray]] = {}
    for (camera, frame), T in T_cam_board.items():
        frames_of.setdefault(camera, {})[frame] = T
    T_ref_cam = {names[0]: np.eye(4)}
    for parent, child in spanning_tree(posed):
        shared = sorted(frames_of[parent].keys() & frames_of[child].keys())
        T_parent_child = _medoid([frames_of[parent][f] @ invert(frames_of[child][f]) for f in shared],
                                 board.square_m * 10)
        T_ref_cam[child] = T_ref_cam[parent] @ T_parent_child
    T_ref_board: dict[str, np.ndarray] = {}
    for (camera, frame), T in sorted(T_cam_board.items(), key=lambda item: names.index(item[0][0])):
        T_ref_board.setdefault(frame, T_ref_cam[camera] @ T)
    return T_ref_cam, T_ref_board
