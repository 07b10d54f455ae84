"""Size limits on what users send: image pixels, upload bytes, cloud points, in one place.

Each limit has a default and an environment variable that overrides it. The value is read when it is
checked, so a deployment (or a test) changes it by setting the variable; messages name both the limit and
the variable, so a refused user knows what to change. An upload limit is in MB of 1,000,000 bytes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass


@dataclass(frozen=True)
class Limit:
    """One configurable limit: ``value()`` is the environment variable's number if set, else ``default``."""

    env: str
    """The environment variable that overrides the default, e.g. ``CALIB_MAX_IMAGE_PIXELS``."""
    default: int
    unit: str
    """What the number counts: ``px``, ``MB`` (1,000,000 bytes) or ``points``."""
    what: str
    """What it limits, as a message says it: ``an image``, ``an image upload``..."""

    def value(self) -> int:
        """The limit in its unit; a variable that is not a positive number is a configuration error."""
        text = os.environ.get(self.env)
        if text is None or not text.strip():
            return self.default
        try:
            value = float(text)
        except ValueError:
            value = 0.0
        if not 0 < value < float("inf"):  # NaN fails too
            raise ValueError(f"environment variable {self.env}={text!r}: expected a positive number of {self.unit}")
        return int(value)

    def describe(self) -> str:
        """``the 50,000,000 px limit on an image (CALIB_MAX_IMAGE_PIXELS)``: for messages."""
        return f"the {self.value():,} {self.unit} limit on {self.what} ({self.env})"


MAX_IMAGE_PIXELS = Limit("CALIB_MAX_IMAGE_PIXELS", 50_000_000, "px", "an image")
"""Largest image (width x height) decoded; checked from the file's header, before decoding."""
MAX_IMAGE_UPLOAD_MB = Limit("CALIB_MAX_IMAGE_UPLOAD_MB", 100, "MB", "an image upload")
"""Largest request (all its files) that uploads images, and largest image file in any upload."""
MAX_CLOUD_UPLOAD_MB = Limit("CALIB_MAX_CLOUD_UPLOAD_MB", 2000, "MB", "a cloud upload")
"""Largest request (all its files) that uploads point clouds (alone or in an image + cloud pair)."""
MAX_CLOUD_POINTS = Limit("CALIB_MAX_CLOUD_POINTS", 50_000_000, "points", "a point cloud")
"""Most points read from one cloud file; checked on the count its header declares where it has one."""
MAX_TARGET_SQUARES = Limit("CALIB_MAX_TARGET_SQUARES", 10_000, "squares", "a printable target")
"""Most squares (a ChArUco board's each hold a marker or none) drawn into one target PDF; checked from the spec."""

MAX_TEXT_UPLOAD_MB = Limit("CALIB_MAX_TEXT_UPLOAD_MB", 2, "MB", "a text upload")
"""Largest request uploading a text file (a test field's survey)."""

BYTES_PER_MB = 1_000_000
MAX_NODE_FRAME_MB = Limit("CALIB_MAX_NODE_FRAME_MB", 256, "MB", "a node's frame")
"""Largest frame a node agent's stream or capture may send; Zenoh drops a bigger message before it is taken in."""

MAX_TABLE_MB = Limit("CALIB_MAX_TABLE_MB", 500, "MB", "a recording table (IMU samples, detected corners)")
"""Bounds a CSV of IMU samples or of detected board corners before it is parsed."""
