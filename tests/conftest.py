"""Shared fixtures: paths to the real data sets in ../shared/data."""

from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
STEREO_CHESSBOARD = SHARED_DATA / "opencv_stereo_chessboard"


@pytest.fixture(scope="session")
def stereo_chessboard() -> Path:
    if not STEREO_CHESSBOARD.is_dir():
        pytest.fail(f"real data missing: {STEREO_CHESSBOARD} (shared/data must sit beside the checkout)")
    return STEREO_CHESSBOARD


@pytest.fixture(scope="session")
def left_images(stereo_chessboard: Path) -> list[Path]:
    return sorted(stereo_chessboard.glob("left*.jpg"))
