"""A board carried about without stopping: where it is at a moment of the wall clock every simulated device shares.

The person walks the board through a cycle of poses (``T_base_board``, 4x4, m), holding each for ``hold_s`` seconds
(0: not at all) and carrying it on to the next in ``carry_s`` seconds. The carry starts and ends at rest: the
fraction of the way is the smoothstep of the fraction of the time (``3u² - 2u³``), the position moves along the
straight line and the rotation along the shortest arc (SciPy's ``Slerp``), so the board's pose, velocity and angular
rate are continuous, as a hand-carried board's are. On the way the board is also turned to and fro about its own
vertical axis, once each way per carry (:data:`SWAY_DEG`, zero at both ends): the path alone turns the board one way
only, and then any error that depends on the board's pose (a 16-beam LiDAR's normal is off by up to a degree where
few rings cross the board) reads as a lag, 4 ms on the demo's LiDAR; turned to and fro, such errors cancel, as a
person asked to "tilt and turn it" makes them. A camera and a LiDAR reading at the same moment see the same
pose whatever their frame rates, so their clocks can be lined up against each other
(:mod:`backend.calib.time_offset`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from backend.sim.timing import held_pose_index

SWAY_DEG = 20.0
"""Amplitude (deg) of the to-and-fro turn about the board's vertical (its y axis) during each carry."""


def carried_board_pose(poses: Sequence[np.ndarray], t_s: float, hold_s: float, carry_s: float
                       ) -> tuple[int, np.ndarray]:
    """The board at wall-clock time ``t_s`` (s): the index of the pose it last left (or holds) and ``T_base_board``.

    Each cycle step lasts ``hold_s + carry_s`` (s, ``carry_s > 0``); after the last pose the board is carried back
    to the first.
    """
    step_s = hold_s + carry_s
    steps = int(t_s // step_s)
    index, into_s = steps % len(poses), t_s - steps * step_s
    T_from = np.asarray(poses[index], float)
    if into_s <= hold_s:
        return index, T_from.copy()
    T_to = np.asarray(poses[(index + 1) % len(poses)], float)
    u = (into_s - hold_s) / carry_s
    way = u * u * (3.0 - 2.0 * u)
    T = np.eye(4)
    sway = Rotation.from_rotvec([0.0, np.radians(SWAY_DEG) * np.sin(2.0 * np.pi * u), 0.0])
    T[:3, :3] = (Slerp([0.0, 1.0], Rotation.from_matrix([T_from[:3, :3], T_to[:3, :3]]))(way) * sway).as_matrix()
    T[:3, 3] = (1.0 - way) * T_from[:3, 3] + way * T_to[:3, 3]
    return index, T


def yard_board_pose(poses: Sequence[np.ndarray], frame_index: int, t_s: float, hold_s: float, carry_s: float
                    ) -> tuple[int, np.ndarray]:
    """Where a simulated device's frame ``frame_index``, read at wall-clock ``t_s`` (s), sees the yard's board: the
    index of its pose and ``T_base_board``; carried between the poses when ``carry_s > 0``
    (:func:`carried_board_pose`), else at one of them (:func:`~backend.sim.timing.held_pose_index`)."""
    if carry_s > 0:
        return carried_board_pose(poses, t_s, hold_s, carry_s)
    index = held_pose_index(frame_index, len(poses), hold_s)
    return index, np.asarray(poses[index], float)
