"""The one capture interface every sensor driver implements.

A driver is opened from a plain settings dict (stored with the sensor in the rig)
and yields :class:`Sample` objects. Cameras fill ``image``; later LiDAR drivers
fill ``points``. A driver that loses its device raises :class:`DeviceDisconnected`
from :meth:`CaptureDevice.read`; samples already returned belong to the caller
and are never lost.
"""

from __future__ import annotations

import abc
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

import numpy as np

from backend.core.errors import InputError
from backend.core.imu import ImuSamples


class DeviceError(RuntimeError):
    """A device could not be opened or configured; the message says which and why."""

    def __init__(self, message: str, device: str):
        super().__init__(f"{device}: {message}")
        self.message = message
        self.device = device


class DeviceDisconnected(DeviceError):
    """The device went away mid-capture (unplugged, stream ended, read failed)."""


class RecordingError(InputError, DeviceError):
    """A recording (a bag, an .lvx file) that cannot be used as asked; ``input`` and ``device`` name the file.

    Caught as :class:`~backend.core.errors.InputError` by the API and CLI (a 4xx, a one-line error) and as
    :class:`DeviceError` by code that opens devices; ``str(exc)`` is the message, which itself names the file.
    """

    def __init__(self, message: str, path: str):
        InputError.__init__(self, message, path)
        self.device = path


@dataclass
class Sample:
    """One reading from a sensor."""

    timestamp_s: float
    """Capture time, seconds since the epoch (or since the start of a recording)."""
    image: np.ndarray | None = None
    """uint8 image, HxW (gray) or HxWx3 (BGR), for cameras."""
    points: np.ndarray | None = None
    """(N, 3) float64 points in the sensor's frame (m), for range sensors; z = 0 for a 2D scanner."""
    intensity: np.ndarray | None = None
    """(N,) float32 return intensity of each point, in the sensor's own units, when it reports one."""
    imu: ImuSamples | None = None
    """The IMU samples of this read (an IMU's driver returns a batch at a time)."""
    depth: np.ndarray | None = None
    """(H, W) float32 depth along the optical axis (m, 0 = no return), for depth cameras; ``points`` and
    ``intensity`` then hold its valid pixels (node frame) and their IR amplitude."""
    meta: dict[str, Any] = field(default_factory=dict)
    """Driver facts worth keeping (source file, frame index, ground truth in simulation)."""

    def storable_meta(self) -> dict[str, Any]:
        """The JSON-friendly part of :attr:`meta` (numbers, text, flags, and lists and dicts of those), for a
        capture record; arrays are left out."""
        return {k: v for k, v in self.meta.items() if _json_friendly(v)}


def _json_friendly(value: Any) -> bool:
    """True for numbers, text and flags, and (nested) lists and string-keyed dicts of them (or None)."""
    if isinstance(value, (int, float, str, bool)):
        return True
    if isinstance(value, list):
        return all(v is None or _json_friendly(v) for v in value)
    if isinstance(value, dict):
        return all(isinstance(k, str) and (v is None or _json_friendly(v)) for k, v in value.items())
    return False


class CaptureDevice(abc.ABC):
    """A sensor that can be opened, read sample by sample and closed."""

    driver: ClassVar[str]
    """The name stored in a sensor's ``device`` settings, e.g. ``"uvc"``."""

    @abc.abstractmethod
    def open(self) -> None:
        """Connect to the device; raise :class:`DeviceError` with the reason on failure."""

    @abc.abstractmethod
    def read(self) -> Sample:
        """Return the next sample; raise :class:`DeviceDisconnected` when the device is gone."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the device. Safe to call twice."""

    def describe(self) -> str:
        """A short human name for status lines, e.g. ``"uvc /dev/video0 1280x720"``."""
        return self.driver

    def probe(self) -> None:
        """Check that the device answers, as a sensor is added: open it and close it again (a driver whose open is
        slow or has side effects may override this with a cheaper check). Raises :class:`DeviceError` saying why
        it does not."""
        try:
            self.open()
        finally:
            self.close()

    def __enter__(self) -> CaptureDevice:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_DRIVERS: dict[str, Callable[..., CaptureDevice]] = {}
_SIMULATORS: dict[str, Callable[..., Any]] = {}
"""Simulated endpoints by name (:func:`register_simulator`): a driver that can talk to a simulated sensor
(``port="sim"``, ``host="sim"`` ...) knows only the bytes on its wire; the simulator behind that wire lives in the
simulation package, which registers it here, so drivers never import simulators."""

SIMULATORS_MODULE = "backend.sim.devices"
"""The module that registers every simulated driver and endpoint when imported (``backend.services`` imports it
for every front-end); named here only in messages, never imported."""


def register_driver(cls: type[CaptureDevice]) -> type[CaptureDevice]:
    """Class decorator: make a driver available to :func:`create_device` by its name."""
    _DRIVERS[cls.driver] = cls
    return cls


def driver_names() -> list[str]:
    """The names of every built-in driver (what a sensor's ``device["driver"]`` may be)."""
    from backend import devices  # noqa: F401  (importing registers the built-in drivers)

    return sorted(_DRIVERS)


def check_settings(settings: dict[str, Any]) -> CaptureDevice:
    """The device ``settings`` describe, built and not opened; settings no driver takes (an unknown driver, options
    its driver does not have or lacks) are refused with an :class:`InputError` naming ``device``."""
    try:
        return create_device(settings)
    except DeviceError as exc:
        raise InputError(f"device {exc.device}: {exc.message}", "device") from None


def check_device(settings: dict[str, Any]) -> None:
    """:func:`check_settings`, then the device is opened and closed (:meth:`CaptureDevice.probe`): one that does
    not answer (a camera index with no camera, a serial port that is not there, a UDP port that is taken, a missing
    folder or topic) is refused with an :class:`InputError` naming ``device`` and saying why."""
    device = check_settings(settings)
    try:
        device.probe()
    except DeviceError as exc:
        raise InputError(f"device {exc.device}: {exc.message}", "device") from None
    except InputError as exc:  # a recording's own check (a bag without the topic)
        raise InputError(f"device {device.describe()}: {exc.message}", "device", exc.status_code) from None
    except OSError as exc:  # a driver's own file or port error that it did not word itself
        raise InputError(f"device {device.describe()}: {exc.strerror or exc}", "device") from None


def create_device(settings: dict[str, Any]) -> CaptureDevice:
    """Build (not open) a device from ``{"driver": name, **kwargs}``."""
    from backend import devices  # noqa: F401  (importing registers the built-in drivers)

    name = settings.get("driver")
    if name not in _DRIVERS:
        sim_loaded = SIMULATORS_MODULE in sys.modules
        hint = "" if sim_loaded else f" (simulated drivers are registered by importing {SIMULATORS_MODULE})"
        raise DeviceError(f"unknown driver {name!r}; available: {sorted(_DRIVERS)}{hint}", str(name))
    kwargs = {k: v for k, v in settings.items() if k != "driver"}
    try:
        return _DRIVERS[name](**kwargs)
    except TypeError as exc:
        raise DeviceError(f"bad settings {kwargs}: {exc}", name) from None


# ---------------------------------------------------------------------------------------------- simulated endpoints

class SimulatedEndpoint(Protocol):
    """What :func:`start_simulator` returns: a running simulated sensor a driver reads from (a pty's ``port``
    path, a UDP sender toward the driver's socket, ...); :meth:`stop` ends it."""

    def stop(self) -> None:
        """Stop the simulator and release what it holds. Safe twice."""


def register_simulator(name: str, start: Callable[..., Any]) -> None:
    """Make a simulated endpoint available to drivers as :func:`start_simulator` ``(name, ...)``.

    ``start(**settings)`` returns the running endpoint (usually a :class:`SimulatedEndpoint`); it raises
    :class:`ValueError` for settings it cannot simulate (reported as a :class:`DeviceError`).
    """
    _SIMULATORS[name] = start


def simulator_names() -> list[str]:
    """The names of every registered simulated endpoint."""
    return sorted(_SIMULATORS)


def start_simulator(name: str, device: str, **settings: Any) -> Any:
    """Start the simulated endpoint registered as ``name`` with ``settings`` and return it.

    ``device`` is who asks (the driver's :meth:`CaptureDevice.describe`), for the errors: a :class:`DeviceError`
    if nothing is registered under ``name`` (:data:`SIMULATORS_MODULE` registers the built-in simulators when
    imported) or if the simulator rejects its settings (:class:`ValueError`).
    """
    start = _SIMULATORS.get(name)
    if start is None:
        raise DeviceError(f"no simulator {name!r} is registered (available: {simulator_names()}); simulators are "
                          f"registered by importing {SIMULATORS_MODULE}", device)
    try:
        return start(**settings)
    except ValueError as exc:
        raise DeviceError(str(exc), device) from None
