"""LiDAR-to-LiDAR workflow shared by the API, the studio and the CLI.

capture or import clouds -> store them -> solve ``T_target_source`` from pairs of
captures (one per scene, or several) -> store the result, a
:class:`~backend.core.result.TransformResult` record with ``parent`` the target LiDAR and
``child`` the source LiDAR, with its verdict. Accepting it (an edge of the rig's pose graph) is
:func:`backend.calib.rig.service.accept`'s, as for every result kind; :func:`check_result` is what the
LiDAR routes check first. The studio's nudging (a global guess, the fit at the sliders' pose) is
here too, so the step only draws.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from scipy.spatial import cKDTree

from backend.calib._session import check_lidar, read_uploaded_cloud, result_of, store_cloud
from backend.calib.lidar_lidar.gicp import LidarLidarSettings, global_initial_guess
from backend.calib.lidar_lidar.scenes import register_pairs
from backend.core.errors import InputError
from backend.core.result import ProgressCallback, TransformResult, no_progress
from backend.core.transforms import transform_points
from backend.devices.cloud_files import read_cloud
from backend.store.schema import CaptureRecord
from backend.store.session import Session


def import_clouds(session: Session, sensor: str, files: list[tuple[str, bytes | Path]],
                  progress: ProgressCallback = no_progress) -> list[CaptureRecord]:
    """Add uploaded cloud files (their bytes, or where they were saved) as captures; any unreadable file rejects
    the whole batch, naming it, and nothing of the batch is stored."""
    check_lidar(session, sensor)
    clouds = []
    for i, (name, data) in enumerate(files):
        progress(i / max(len(files), 1), f"reading {name}")
        clouds.append(read_uploaded_cloud(name, data))
    return [store_cloud(session, sensor, sample, device="upload", source=sample.meta["source"]) for sample in clouds]


PAIR_WINDOW_S = 1.0
"""Two LiDARs' captures pair when their time stamps lie within this of each other (s): a static scene, read by
both at about the same moment (a scan is 0.1 s)."""


@dataclass(frozen=True)
class Pairing:
    """How two LiDARs' captures pair up: by time stamp within a window, never by capture number."""

    pairs: list[tuple[str, str]]
    """(source capture id, target capture id), in the source's time order."""
    unpaired: list[str]
    """Each capture with no partner, named with why (``lidar_front 00003 (12:04:51): no lidar_top capture within
    1 s``)."""


def pairing(session: Session, source: str, target: str, window_s: float = PAIR_WINDOW_S) -> Pairing:
    """Pair ``source``'s and ``target``'s clouds by time stamp: the closest stamps first, each capture used once,
    within ``window_s`` (s). Stamps are compared on the rig's clock (each less its sensor's accepted clock offset,
    :meth:`~backend.core.rig.Frame.rig_time`; 0 until a time offset is accepted). Uploaded clouds carry no stamp
    (0): they pair with each other in upload order, as a user uploads matching files, and never with a stamped
    capture."""
    check_lidar(session, source)
    check_lidar(session, target)
    sources = [c for c in session.captures(source) if c.n_points]
    targets = [c for c in session.captures(target) if c.n_points]
    if not sources or not targets:
        empty = source if not sources else target
        raise InputError(f"no clouds captured for {empty} yet; capture or import clouds of both LiDARs", empty)
    pairs = list(zip([c.id for c in sources if not c.timestamp_s], [c.id for c in targets if not c.timestamp_s],
                     strict=False))
    stamped_s = [c for c in sources if c.timestamp_s]
    stamped_t = [c for c in targets if c.timestamp_s]
    rig_s, rig_t = session.rig.get(source), session.rig.get(target)
    gaps = np.abs(np.subtract.outer([rig_s.rig_time(c.timestamp_s) for c in stamped_s],
                                    [rig_t.rig_time(c.timestamp_s) for c in stamped_t]))
    taken_s, taken_t = set(), set()
    for i, j in zip(*np.unravel_index(np.argsort(gaps, axis=None), gaps.shape), strict=True):
        if gaps[i, j] > window_s:
            break
        if i not in taken_s and j not in taken_t:
            taken_s.add(i)
            taken_t.add(j)
            pairs.append((stamped_s[i].id, stamped_t[j].id))
    order = {c.id: (c.timestamp_s, k) for k, c in enumerate(sources)}
    pairs.sort(key=lambda pair: order[pair[0]])
    paired = [{pair[0] for pair in pairs}, {pair[1] for pair in pairs}]  # capture ids count per sensor
    unpaired = [f"{sensor} {c.id} ({_clock(c.timestamp_s)}): no {other} capture within {window_s:g} s"
                if c.timestamp_s else f"{sensor} {c.id} (uploaded, no time stamp): no uploaded {other} cloud left "
                                      f"to pair it with"
                for side, (sensor, other, captures) in enumerate(((source, target, sources), (target, source, targets)))
                for c in captures if c.id not in paired[side]]
    return Pairing(pairs, unpaired)


def pair_ids(session: Session, source: str, target: str) -> list[tuple[str, str]]:
    """The default frame pairs, (source capture id, target capture id): :func:`pairing`'s; :class:`InputError`
    naming the captures when none pair."""
    found = pairing(session, source, target)
    if not found.pairs:
        raise InputError(f"no capture of {source} pairs with one of {target} (time stamps within "
                         f"{PAIR_WINDOW_S:g} s): capture both while both are live; " + "; ".join(found.unpaired[:4]),
                         "pairs")
    return found.pairs


def _clock(timestamp_s: float) -> str:
    return time.strftime("%H:%M:%S", time.localtime(timestamp_s))


def capture_pairs(session: Session, source: str, target: str,
                  pairs: list[tuple[str, str]] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Clouds to register: the given (source id, target id) pairs, or :func:`pair_ids`."""
    check_lidar(session, source)
    check_lidar(session, target)
    if pairs is None:
        pairs = pair_ids(session, source, target)
    return [(session.capture_cloud(source, s)[0], session.capture_cloud(target, t)[0]) for s, t in pairs]


def solve_session(session: Session, source: str, target: str, *, T_init: np.ndarray | None = None,
                  use_rig_guess: bool = True, settings: LidarLidarSettings | None = None,
                  pairs: list[tuple[str, str]] | None = None,
                  progress: ProgressCallback = no_progress) -> tuple[str, TransformResult]:
    """Register ``source`` into ``target`` over the frame ``pairs`` (default :func:`pair_ids`) and store the
    result (not yet accepted) under the source LiDAR: ``T_parent_child`` is ``T_target_source`` with ``parent``
    ``target`` and ``child`` ``source``. Pairs from different places are scenes that cross-check each other (see
    :mod:`backend.calib.lidar_lidar.scenes`); the record's ``inputs`` are the pairs as "source id:target id".

    The initial guess is ``T_init`` if given, else the rig's current transform
    (manual nudges included) when ``use_rig_guess``, else global registration.
    """
    pairs = pair_ids(session, source, target) if pairs is None else [tuple(p) for p in pairs]
    clouds = capture_pairs(session, source, target, pairs)
    if T_init is None and use_rig_guess:
        T_init = session.rig.T_a_b(target, source)
    result = register_pairs(clouds, T_init, settings, progress,
                            names=[(f"{source} {s}", f"{target} {t}") for s, t in pairs]).named(target, source)
    result_id = session.add_result(source, result.to_record(), inputs=[f"{s}:{t}" for s, t in pairs])
    return result_id, result


def solve_files(files: Sequence[tuple[Path, Path]], T_init: np.ndarray | None = None, *,
                voxel_m: float | None = None, max_correspondence_m: float | None = None,
                progress: ProgressCallback = no_progress,
                warn: Callable[[str], None] = lambda message: None) -> TransformResult:
    """Register cloud files, no session: one ``T_target_source`` for every (source file, target file) pair (one per
    scene, as :func:`solve_session`), from ``T_init`` or else global registration. ``voxel_m`` and
    ``max_correspondence_m`` (m) override :class:`LidarLidarSettings`' fine resolution and inlier distance. Each
    file is read once (:func:`~backend.devices.cloud_files.read_cloud`); the points it dropped as non-finite are
    told to ``warn`` as it is read. The result is not named (``parent`` "target", ``child`` "source")."""
    settings = LidarLidarSettings()
    if voxel_m is not None:
        settings.voxel_m = voxel_m
    if max_correspondence_m is not None:
        settings.max_correspondence_m = max_correspondence_m
    clouds = {}
    for path in dict.fromkeys(p for pair in files for p in pair):
        progress(0.0, f"reading {path}")
        cloud = read_cloud(path)
        if cloud.dropped_non_finite:
            warn(f"{path}: dropped {cloud.dropped_non_finite} non-finite points")
        clouds[path] = cloud.points
    return register_pairs([(clouds[s], clouds[t]) for s, t in files], T_init, settings, progress,
                          names=[(str(s), str(t)) for s, t in files])


def pair_results(session: Session, source: str, target: str) -> list[dict[str, Any]]:
    """The stored LiDAR-to-LiDAR records of ``source`` into ``target``, newest first."""
    return [r for r in reversed(session.results(source, "lidar_lidar")) if r.get("parent") == target]


def check_result(session: Session, source: str, result_id: str) -> dict[str, Any]:
    """The stored record ``result_id`` if it is a LiDAR-to-LiDAR result of ``source`` (the child); else an
    :class:`InputError` naming the result's kind or sensor."""
    return result_of(session, "lidar_lidar", result_id, source)


@dataclass(frozen=True)
class StartingPose:
    """What *Global guess* leaves on the sliders: RANSAC's pose or the current one, whichever fits better."""

    T_target_source: np.ndarray
    """The kept starting pose (4x4, m)."""
    kept: Literal["global", "current"]
    global_fitness: float
    """The RANSAC pose's share of source points within ``max_distance_m`` of the target."""
    current_fitness: float | None
    """The current pose's, by the same score (None without a current pose)."""
    max_distance_m: float

    def message(self) -> str:
        """Which pose was kept and why, in the scores both were judged by."""
        scores = f"fitness at {self.max_distance_m:g} m: global {self.global_fitness:.3f}"
        if self.current_fitness is None:
            return f"Global guess on the sliders ({scores}); press Refine."
        scores += f", current {self.current_fitness:.3f}"
        if self.kept == "current":
            return f"Kept the current pose: it fits better than the global guess ({scores})."
        return f"The global guess fits better than the current pose and is on the sliders ({scores}); press Refine."


def global_guess(session: Session, source: str, target: str, pairs: list[tuple[str, str]] | None = None,
                 progress: ProgressCallback = no_progress, T_current: np.ndarray | None = None) -> StartingPose:
    """A starting ``T_target_source`` from FPFH features and RANSAC on the last of ``pairs`` (default the last of
    :func:`pair_ids`), about a voxel (``global_voxel_m``) accurate, for GICP to refine; but never worse than
    ``T_current``: both are scored alike (the share of source points within the fine correspondence distance,
    ``max_correspondence_m``, of the target) and the better one is kept (the current one on a tie)."""
    progress(0.05, "FPFH features + RANSAC on the last frame pair")
    settings = LidarLidarSettings()
    source_points, target_points = capture_pairs(session, source, target, pairs)[-1]
    T_global, _ = global_initial_guess(source_points, target_points, voxel_m=settings.global_voxel_m)
    progress(0.9, "scoring the global guess against the current pose")
    tree = cKDTree(target_points)
    distance_m = settings.max_correspondence_m
    global_fitness = fit_at(source_points, tree, T_global, distance_m)["fitness"]
    if T_current is None:
        return StartingPose(T_global, "global", global_fitness, None, distance_m)
    current_fitness = fit_at(source_points, tree, T_current, distance_m)["fitness"]
    if current_fitness >= global_fitness:
        return StartingPose(np.array(T_current, dtype=float), "current", global_fitness, current_fitness, distance_m)
    return StartingPose(T_global, "global", global_fitness, current_fitness, distance_m)


def fit_at(source_points: np.ndarray, target_tree: cKDTree, T_target_source: np.ndarray,
           max_distance_m: float) -> dict[str, Any]:
    """How the source cloud (N, 3, m, source frame) lies on the target (its KD-tree, target frame) at a nudged
    ``T_target_source``: ``distances_m`` (N,) from each source point to its nearest target point (inf beyond
    ``2 * max_distance_m``), ``inliers_m`` (those within ``max_distance_m``), ``fitness`` (their share) and
    ``c2c_mean_m`` (their mean distance, NaN when there are none)."""
    distances, _ = target_tree.query(transform_points(T_target_source, np.asarray(source_points, dtype=float)), k=1,
                                     distance_upper_bound=2 * max_distance_m, workers=2)
    inliers = distances[distances <= max_distance_m]
    return {"distances_m": distances, "inliers_m": inliers, "fitness": len(inliers) / max(len(distances), 1),
            "c2c_mean_m": float(inliers.mean()) if inliers.size else float("nan")}
