"""Turn a rendered visible image of a board into what a thermal (LWIR) camera shows of it.

A thermal camera sees emitted, not reflected, light: a surface's signal grows with
its emissivity and its temperature. A board at room temperature is all but
invisible. Heated (sunlight, a heat gun from behind, a heating pad) or cooled, its
printed and bare areas differ in emissivity (black paint about 0.95 against bare
aluminium about 0.1, which mostly mirrors the colder room; ink against paper by a
few per cent) or in temperature (black ink absorbs more sunlight or lamp light and
runs warmer). The pattern then spans only a few per cent of the scene's range, and
its polarity depends on the set-up and the palette: in "white-hot" a heated black
print on a bare plate comes out *bright*, inverted against the visible image.

:func:`thermal_image` imitates this from a visible image (e.g.
:func:`backend.sim.board_renderer.render_board_image`): the visible grey level is
read as the print's darkness, squeezed into ``contrast`` levels around ``offset``,
optionally inverted, tilted by a temperature gradient across the image (a board
heated from one side, the camera's own warm housing), blurred by soft germanium
optics and given sensor noise. The geometry is untouched, so the visible image's
ground-truth corners stay true.
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np


def thermal_image(
    visible: np.ndarray,
    rng: np.random.Generator,
    *,
    contrast: float = 16.0,
    inverted: bool = True,
    offset: float = 110.0,
    gradient: float = 20.0,
    noise_sigma: float = 1.0,
    blur_px: float = 1.5,
    bit_depth: Literal[8, 16] = 8,
) -> np.ndarray:
    """A thermal view (uint8 or uint16 (H, W)) of a uint8 grayscale visible image.

    Args:
        visible: uint8 (H, W) grayscale image of the scene in visible light.
        rng: the only source of randomness (gradient direction, noise).
        contrast: output levels (grey levels, or raw counts for 16 bits) between a
            visible grey of 0 and one of 255. Under ``render_board_image``'s lighting
            the print (paper against ink) spans 50-70 % of it, so 16 gives about 10
            grey levels between neighbouring squares.
        inverted: whether visibly dark areas come out bright (a heated black print
            in a "white-hot" palette); False for a cooled board or "black-hot".
        offset: output level of the image mean (grey levels or counts).
        gradient: a temperature gradient: a linear ramp along a random direction that
            changes the level by up to this much from the image centre to a corner
            (grey levels or counts).
        noise_sigma: sigma of the additive Gaussian sensor noise (grey levels or counts).
        blur_px: sigma of the Gaussian blur of the optics (px); 0 for none.
        bit_depth: 8 for a palette-mapped uint8 frame, 16 for uint16 raw counts.
    """
    signal = visible.astype(np.float32) / 255.0
    if inverted:
        signal = 1.0 - signal
    signal = np.float32(contrast) * (signal - signal.mean()) + np.float32(offset)
    signal += _gradient(visible.shape, gradient, rng.uniform(0.0, 2 * np.pi))
    if blur_px > 0:
        signal = cv2.GaussianBlur(signal, (0, 0), blur_px)
    signal += noise_sigma * rng.standard_normal(signal.shape, dtype=np.float32)
    dtype = np.uint8 if bit_depth == 8 else np.uint16
    return np.clip(np.rint(signal), 0, np.iinfo(dtype).max).astype(dtype)


def _gradient(shape: tuple[int, ...], amplitude: float, angle_rad: float) -> np.ndarray:
    """(H, W) float32 linear ramp along ``angle_rad`` (rad, from +x towards +y): 0 at the centre, ``amplitude`` at
    half the image diagonal."""
    height, width = shape[:2]
    half_diagonal = 0.5 * np.hypot(width, height)
    x = ((np.arange(width, dtype=np.float32) - (width - 1) / 2) / half_diagonal)[None, :]
    y = ((np.arange(height, dtype=np.float32) - (height - 1) / 2) / half_diagonal)[:, None]
    return np.float32(amplitude) * (np.float32(np.cos(angle_rad)) * x + np.float32(np.sin(angle_rad)) * y)
