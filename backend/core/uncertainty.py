"""1-sigma from a covariance: the one way every result reads its uncertainties."""

from __future__ import annotations

import numpy as np


def sigmas(covariance: np.ndarray) -> np.ndarray:
    """1-sigma of each parameter (the square roots of the covariance's diagonal, in the parameters' own units).

    A variance a hair below zero (round-off in an inverse) reads as 0; NaN, a parameter the data do not
    determine, stays NaN.
    """
    return np.sqrt(np.clip(np.diag(np.asarray(covariance, dtype=float)), 0, None))
