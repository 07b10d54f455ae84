"""Sensor drivers behind the one capture interface in :mod:`backend.devices.base`."""
from backend.devices import (  # noqa: F401
    image_folder,
    simulated_camera,  # noqa: F401
    uvc_camera,
)
