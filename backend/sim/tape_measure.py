"""Mounting guesses as a tape measure and a protractor give them: the simulator's truth, off by a few centimetres
and degrees. The demos start from these, so every accepted calibration visibly moves its sensors towards the
truth."""

from __future__ import annotations

import numpy as np

from backend.core.transforms import apply_params


def tape_guess(T_parent_child: np.ndarray, rng: np.random.Generator, error_m: tuple[float, float],
               error_deg: tuple[float, float]) -> np.ndarray:
    """``T_parent_child`` (4x4, m) moved by a random translation whose norm lies in ``error_m`` (m) and turned about a
    random axis by an angle in ``error_deg`` (deg)."""
    directions = rng.normal(size=(2, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    step = np.r_[directions[0] * rng.uniform(*error_m), directions[1] * np.radians(rng.uniform(*error_deg))]
    return apply_params(T_parent_child, step)
