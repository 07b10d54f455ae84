"""A targetless solve where the scene cannot determine the translation: the rotation is solved with the translation
held at the initial guess, which is reported with the guess's own sigma (a tape measure's).

Far scenes (a road, 10-40 m) fix the rotation well and the translation hardly: 10 cm sideways is 0.3 deg of yaw at
20 m. Rather than refuse, or answer a translation the scene does not hold, both targetless methods (edges and
intensity) solve again with the translation held at the guess (:data:`HELD_PRIOR_M`) when no translation prior was
given and the free solve found alignments far apart that fit about equally well, or pinned some axis less well
than the guess. The result says so (:func:`mark_held`) and its verdict is ``check`` at best.
"""

from __future__ import annotations

import numpy as np

from backend.core.result import TransformResult, finite_or_none

HELD_PRIOR_M = 1e-4
"""The translation prior (m, 1-sigma) that holds the translation at the guess when the scene cannot determine it:
tight enough that the data do not move it (a fraction of a millimetre)."""
AMBIGUOUS = "ambiguous"
"""How the warning of a free solve whose competing alignments lie too far apart begins."""


def translation_undetermined(result: TransformResult, guess_sigma_m: float, cue: str, ambiguous_suffix: str
                             ) -> str | None:
    """Why the free solve's ``result`` leaves the translation to the guess, or None: alignments far apart fit about
    equally well (its :data:`AMBIGUOUS` warning, less ``ambiguous_suffix``), or ``cue`` ("the edges") pins some axis
    of the translation less well than the guess's ``guess_sigma_m`` (m)."""
    ambiguous = next((w for w in result.warnings if w.startswith(AMBIGUOUS)), None)
    if ambiguous is not None:
        return ambiguous.removesuffix(ambiguous_suffix).removeprefix(AMBIGUOUS + ": ")
    loose = [(axis, s) for axis, s in zip("xyz", result.std["trans_m"], strict=True) if s is None or s > guess_sigma_m]
    if not loose:
        return None
    return f"{cue} pin the translation less well than the guess: " + ", ".join(
        f"{axis} {'undetermined' if s is None else f'sigma {100 * s:.1f} cm'}" for axis, s in loose)


def held_covariance(information: np.ndarray, guess_sigma_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The (6, 6) covariance of a held solve whose translation is the guess's, known to ``guess_sigma_m`` (m) per
    axis, and the (3,) translation sigmas (m) the data alone give (inf where they give none).

    ``information`` (6, 6; m, m, m, rad, rad, rad) is the data's own, without the holding prior: the rotation given
    the translation has covariance ``I_rr^-1``, and a translation error ``dt`` moves the solved rotation by ``A dt``
    with ``A = -I_rr^-1 I_rt``, so ``C_tt = s^2 1``, ``C_rt = A C_tt`` and ``C_rr = I_rr^-1 + A C_tt A^T``. The data's
    own hold on the translation is not used: the scene was just found unable to determine it.
    """
    rotation_given_translation = np.linalg.inv(information[3:, 3:])
    A = -rotation_given_translation @ information[3:, :3]
    C_tt = guess_sigma_m**2 * np.eye(3)
    covariance = np.block([[C_tt, (A @ C_tt).T], [A @ C_tt, rotation_given_translation + A @ C_tt @ A.T]])
    try:
        alone = np.sqrt(np.clip(np.diag(np.linalg.inv(information))[:3], 0, None))
    except np.linalg.LinAlgError:
        alone = np.full(3, np.inf)
    return 0.5 * (covariance + covariance.T), alone


def mark_held(result: TransformResult, guess_sigma_m: float, why: str, alone: np.ndarray, cue: str, advice: str
              ) -> None:
    """Say on ``result`` that its translation was held: the warning (``cue`` alone pins it to ``alone`` (3,) m, then
    ``advice``: what would determine it) and ``diagnostics["translation_held"]`` (``sigma_m``, ``why``,
    ``alone_m``), which the verdict reads."""
    pinned = ", ".join(f"{axis} {'undetermined' if not np.isfinite(s) else f'{100 * s:.1f} cm'}"
                       for axis, s in zip("xyz", alone, strict=True))
    result.warnings.append(f"translation held at the guess \u00b1 {100 * guess_sigma_m:g} cm: this scene cannot "
                           f"determine it ({why}); {cue} alone pin it to {pinned} (1 sigma, camera axes). {advice}, "
                           "or pass the measured mounting as a translation prior")
    result.diagnostics["translation_held"] = {"sigma_m": guess_sigma_m, "why": why, "alone_m": finite_or_none(alone)}
