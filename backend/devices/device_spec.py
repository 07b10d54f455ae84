"""The one-string device spec a node agent is started with (``calib-studio node --device SPEC``).

A spec names what the agent captures from, in the short forms a person types on a node's computer, or as
the JSON settings any driver takes (what a sensor's ``device`` holds in the rig):

- ``sim-cell:sn1``: node ``sn1`` of the simulated depth cell (driver ``sim_depth``);
- ``sim-lidar:lidar_top``, ``sim-camera:cam_front``: a LiDAR or a camera of the simulated demo rig;
- ``kinect2`` or ``kinect2:SERIAL``, ``realsense`` or ``realsense:SERIAL``: a depth camera (the first one, or the
  one with that serial number);
- ``depth-files:DIR``: a folder of depth images;
- ``{"driver": "...", ...}``: any driver's settings.

:func:`parse_device_spec` only reads the text; opening the device (and the driver's own checks of its settings)
is :func:`backend.devices.base.create_device`'s.
"""

from __future__ import annotations

import json
from typing import Any

from backend.core.errors import InputError, shorten

SHORT_FORMS: dict[str, tuple[str, str, bool]] = {
    "sim-cell": ("sim_depth", "node", True),
    "sim-lidar": ("simulated_lidar", "sensor", True),
    "sim-camera": ("simulated", "camera", True),
    "kinect2": ("kinect2", "serial", False),
    "realsense": ("realsense", "serial", False),
    "depth-files": ("depth_files", "path", True),
}
"""Short form -> (driver, the settings key its argument fills, whether the argument is required)."""

FIELD = "device"
"""The input a bad spec is blamed on (the CLI's ``--device``)."""


def parse_device_spec(spec: str) -> dict[str, Any]:
    """The driver settings ``{"driver": name, **kwargs}`` a spec stands for.

    ``"sim-cell:sn1"`` -> ``{"driver": "sim_depth", "node": "sn1"}``; ``"kinect2"`` -> ``{"driver": "kinect2"}``;
    ``"kinect2:0123"`` -> ``{"driver": "kinect2", "serial": "0123"}``; ``"depth-files:/data/sn1"`` ->
    ``{"driver": "depth_files", "path": "/data/sn1"}``; a JSON object is returned as it is (it must name its
    ``driver``). Raises :class:`InputError` (input ``device``) naming what was expected.
    """
    text = spec.strip() if isinstance(spec, str) else ""
    if not text:
        raise InputError(f"empty device spec {shorten(spec)}; expected one of {_forms()} or a driver's JSON "
                         "settings", FIELD)
    if text.startswith("{"):
        return _json_settings(text)
    form, sep, argument = text.partition(":")
    if form not in SHORT_FORMS:
        raise InputError(f"unknown device spec {shorten(spec)}; expected one of {_forms()} or a driver's JSON "
                         "settings", FIELD)
    driver, key, required = SHORT_FORMS[form]
    argument = argument.strip()
    if sep and not argument or required and not argument:
        raise InputError(f"device spec {shorten(spec)} lacks its {key}: expected {form}:{key.upper()}", FIELD)
    return {"driver": driver, key: argument} if argument else {"driver": driver}


def _json_settings(text: str) -> dict[str, Any]:
    """A driver's settings given as one JSON object with a ``driver`` name."""
    try:
        settings = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"device spec is not valid JSON ({exc.msg} at character {exc.pos})", FIELD) from None
    if not isinstance(settings, dict) or not isinstance(settings.get("driver"), str) or not settings["driver"]:
        raise InputError(f"device JSON {shorten(settings)} must be an object naming its \"driver\"", FIELD)
    return settings


def _forms() -> str:
    """The short forms, as a message lists them."""
    return ", ".join(f"{form}:{key.upper()}" if required else f"{form}[:{key.upper()}]"
                     for form, (_, key, required) in SHORT_FORMS.items())
