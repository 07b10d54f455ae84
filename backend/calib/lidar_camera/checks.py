"""Whether two solves of one transform by independent methods agree within their uncertainties.

The cross-check between LiDAR-to-camera methods (edges against intensity, on the same pairs): the difference of
the two ``T_camera_lidar`` in the result's parameters (:func:`backend.core.transforms.params_between`: m along
the camera's axes, rad about the LiDAR's) against the combined 1-sigma ``sqrt(sigma_a^2 + sigma_b^2)`` per
parameter, the two estimates' errors being independent (different cues of the same data).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from backend.core.result import finite_or_none
from backend.core.transforms import params_between

AGREEMENT_SIGMAS = 3.0
"""Two methods agree when no parameter differs by more than this many combined sigmas."""


@dataclass
class MethodAgreement:
    """How far one method's transform is from another's, in metres, degrees and combined sigmas."""

    other_method: str
    difference: np.ndarray
    """(6,) the other's transform about this one's (m, m, m, rad, rad, rad)."""
    combined_std: np.ndarray
    """(6,) ``sqrt(sigma_a^2 + sigma_b^2)`` per parameter (same units; inf where either is undetermined)."""

    @property
    def normalised(self) -> np.ndarray:
        """(6,) ``|difference| / combined_std``."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(self.combined_std > 0, np.abs(self.difference) / self.combined_std, np.inf)

    @property
    def passed(self) -> bool:
        return bool(np.all(self.normalised <= AGREEMENT_SIGMAS))

    def detail(self) -> str:
        """One line for the verdict's reasons."""
        worst = int(np.argmax(self.normalised))
        return (f"the {self.other_method} method's transform is {1000 * np.abs(self.difference[:3]).max():.1f} mm and "
                f"{np.degrees(np.abs(self.difference[3:]).max()):.3f} deg away, at most {self.normalised[worst]:.1f} "
                f"combined sigmas (parameter {worst + 1} of 6; agreement within {AGREEMENT_SIGMAS:g})")

    def to_record(self) -> dict[str, Any]:
        return {"other_method": self.other_method, "passed": self.passed,
                "difference_m": finite_or_none(self.difference[:3]),
                "difference_deg": finite_or_none(np.degrees(self.difference[3:])),
                "normalised": finite_or_none(self.normalised), "detail": self.detail()}


def compare_methods(T_a: np.ndarray, covariance_a: np.ndarray, T_b: np.ndarray, covariance_b: np.ndarray,
                    other_method: str) -> MethodAgreement:
    """The agreement of transform ``T_b`` (method ``other_method``) with ``T_a``; both covariances 6x6 over
    :data:`~backend.core.result.TRANSFORM_PARAMETERS` (m, rad)."""
    variance = np.clip(np.diag(covariance_a), 0, None) + np.clip(np.diag(covariance_b), 0, None)
    return MethodAgreement(other_method, params_between(T_a, T_b), np.sqrt(variance))
