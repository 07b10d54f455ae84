"""Which image + cloud pairs were taken in one place: the unit of independent evidence of the targetless methods.

A rig standing still while a board or a person moves sees one scene in every pair: the pairs share that scene's
misleading edges and reflectors, so a cross-check between them (leave one out, two halves) checks nothing and
their costs do not add as independent evidence. The targetless solves group their pairs by the LiDAR clouds
(:func:`~backend.core.clouds.group_by_place`) and cross-check places, not pairs.
"""

from __future__ import annotations

import numpy as np

from backend.core.clouds import group_by_place

PLACE_VOXEL_M = 0.1
"""Voxel (m) in which two pairs' LiDAR points count as the same surface (as the LiDAR-LiDAR scenes' fine voxel)."""


def place_of_pairs(clouds: list[np.ndarray]) -> np.ndarray:
    """(n,) the place index of each pair (0, 1, ... in first-seen order) from its LiDAR cloud (N, 3, m, LiDAR
    frame)."""
    place = np.empty(len(clouds), dtype=np.int64)
    for k, members in enumerate(group_by_place(clouds, PLACE_VOXEL_M)):
        place[members] = k
    return place


def named_places(place: np.ndarray, names: list[str]) -> list[list[str]]:
    """The pairs' ``names`` grouped by their ``place`` (:func:`place_of_pairs`), places in index order: a result's
    ``diagnostics["places"]``."""
    return [[names[i] for i in np.flatnonzero(place == k)] for k in range(int(place.max()) + 1)]


def one_place_note(n_pairs: int, n_places: int, needed: int) -> str:
    """Why a cross-check over places cannot be made: ``n_pairs`` pairs from ``n_places`` places, ``needed`` wanted."""
    advice = (f"pairs from {needed} or more places are needed - add pairs taken with the rig elsewhere, or solve the "
              "same pairs with another method")
    if n_pairs == 1:
        return f"one pair: {advice}"
    taken = "one place" if n_places == 1 else f"{n_places} places"
    return (f"the {n_pairs} pairs were taken in {taken} (their clouds lie on each other), and pairs of one place "
            f"share its errors; {advice}")
