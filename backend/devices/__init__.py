"""Sensor drivers behind the one capture interface in :mod:`backend.devices.base`."""
from backend.devices import image_folder, uvc_camera  # noqa: F401
from backend.devices import simulated_camera  # noqa: F401
