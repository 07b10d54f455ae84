"""Reading one of the rig's sensors live, on its own thread, at a capped rate.

The device comes from the sensor's capture settings in the rig. A corrupt sample
(e.g. a bad file in a replayed folder) is reported and skipped; a device that goes
away ends the stream with a message saying how many captures are kept, since
captures are stored as they are taken and nothing is lost.
"""

from __future__ import annotations

import abc
import threading
import time
from collections.abc import Callable
from typing import ClassVar

from backend.core.errors import InputError, shorten
from backend.devices.base import CaptureDevice, DeviceDisconnected, DeviceError, Sample, create_device
from backend.store.session import Session

StatusCallback = Callable[[str, bool], None]
"""(message naming the sensor, is_error)."""


class SensorStream(abc.ABC):
    """Opens a rig sensor's device and hands every sample to :meth:`handle` until stopped."""

    kept_phrase: ClassVar[str]
    """How kept captures are counted in the disconnect message, e.g. ``"capture(s) taken"``."""

    def __init__(self, session: Session, sensor: str, status: StatusCallback, max_hz: float):
        self.session = session
        self.sensor = sensor
        self.status = status
        self._min_period_s = 1.0 / max_hz if max_hz > 0 else 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.device_name = sensor
        """The open device's description (the sensor name until opened)."""
        self.frames_seen = 0
        self._device: CaptureDevice | None = None
        self._period_s = 0.0
        """Smoothed time between handled samples (s)."""

    @abc.abstractmethod
    def handle(self, sample: Sample) -> None:
        """Use one sample; runs on the stream's thread."""

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name=f"live-{self.sensor}", daemon=True)
        self._thread.start()

    def stop(self, timeout: float = 5.0) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout)

    def wait_stopped(self, timeout_s: float) -> bool:
        """Wait up to ``timeout_s`` (s) for :meth:`stop`; True once stopped (a paced loop's sleep that a stop ends)."""
        return self._stop.wait(timeout_s)

    @property
    def rate_hz(self) -> float:
        """Samples handled per second (smoothed); 0 before the first."""
        return 1.0 / self._period_s if self._period_s > 0 else 0.0

    @property
    def device(self) -> CaptureDevice | None:
        """The open device while the stream runs, else None."""
        return self._device

    @property
    def device_status(self) -> str | None:
        """The open device's own status line, for drivers that keep one (e.g. the YDLiDAR's "reconnecting to
        /dev/ttyUSB0 ..." while it recovers from an unplug inside a read); None otherwise."""
        return getattr(self._device, "status", None)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def _open(self) -> CaptureDevice:
        settings = self.session.rig.get(self.sensor).device
        if not settings:
            raise DeviceError("no capture device configured for this sensor; set one in the sensors step",
                              self.sensor)
        device = create_device(settings)
        device.open()
        return device

    def _run(self) -> None:
        try:
            device = self._open()
        except DeviceError as exc:
            self.status(f"{self.sensor}: {exc}", True)
            return
        except Exception as exc:  # noqa: BLE001 - a device that fails to open in any way must say why
            self.status(f"{self.sensor}: the device could not be opened: {shorten(exc)}", True)
            return
        self._device = device
        self.session.device_answered(self.sensor)
        self.device_name = device.describe()
        self.status(f"{self.sensor}: live from {self.device_name}", False)
        last = time.perf_counter()
        try:
            while not self._stop.is_set():
                started = time.perf_counter()
                try:
                    sample = device.read()
                except InputError as exc:  # one corrupt sample: say so and read on
                    self.status(f"{self.sensor}: {exc.message}", True)
                    continue
                self.frames_seen += 1
                self.handle(sample)
                now = time.perf_counter()
                # Smooth the period, not its inverse: a mean of 1/period overstates the rate of a jittery stream.
                self._period_s = now - last if self.frames_seen == 1 else 0.8 * self._period_s + 0.2 * (now - last)
                last = now
                time.sleep(max(0.0, self._min_period_s - (time.perf_counter() - started)))
        except DeviceDisconnected as exc:
            kept = len(self.session.captures(self.sensor))
            self.status(f"{self.sensor}: {exc} - the {kept} {self.kept_phrase} so far are kept", True)
        except Exception as exc:  # noqa: BLE001 - a live thread must end with a message, never silently
            self.status(f"{self.sensor}: live stopped: {shorten(exc)}", True)
        finally:
            self._device = None
            device.close()
