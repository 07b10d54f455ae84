"""A serial device simulated on a pty pair, reachable at a stable path like a udev symlink.

A new pty gets a new ``/dev/pts/N``, so :attr:`PtyDevice.port` is a symlink in a
private folder that :meth:`PtyDevice.replug` re-points, as a udev rule's
``/dev/ttyUSB-lidar`` would. pyserial opens the symlink like any serial port (a
pty ignores the baud rate). Subclasses implement the device's protocol in
:meth:`PtyDevice.serve`, reading with :meth:`read` and answering with :meth:`write`.
"""

from __future__ import annotations

import abc
import contextlib
import os
import select
import shutil
import tempfile
import threading
import tty
from typing import Self


class PtyDevice(abc.ABC):
    """Owns the pty, the symlink and the device thread; the protocol is the subclass's."""

    def __init__(self, link_name: str):
        self._dir = tempfile.mkdtemp(prefix=f"{link_name.lower()}-sim-")
        self.port = os.path.join(self._dir, link_name)
        """Stable path (a symlink to the current pty slave) for the driver to open."""
        self._master = -1
        self._slave = -1
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    @abc.abstractmethod
    def serve(self) -> None:
        """The device loop, run on its own thread until :attr:`stopping`; return when the pty is gone."""

    @abc.abstractmethod
    def on_plug(self) -> None:
        """Reset what a power cycle resets, just before the device loop starts."""

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def start(self) -> Self:
        """Plug in: create the pty, point :attr:`port` at it and start the device loop."""
        if self._thread is not None:
            return self
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # pyserial does this too; raw before anyone writes
        tmp = self.port + ".new"
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        os.symlink(os.ttyname(self._slave), tmp)
        os.replace(tmp, self.port)
        self.on_plug()
        self._stop.clear()
        self._thread = threading.Thread(target=self.serve, name=f"sim-{os.path.basename(self.port)}", daemon=True)
        self._thread.start()
        return self

    def unplug(self) -> None:
        """Pull the cable: the path disappears and the driver's next read fails."""
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.port)
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        for fd in (self._master, self._slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = -1

    def replug(self) -> None:
        """Plug back in: a new pty behind the same :attr:`port`."""
        self.unplug()
        self.start()

    def stop(self) -> None:
        """Unplug for good and remove the private folder. Safe twice."""
        self.unplug()
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def read(self, timeout_s: float) -> bytes | None:
        """Bytes the driver sent (``b""`` if none within ``timeout_s``); None when the pty is gone."""
        try:
            readable, _, _ = select.select([self._master], [], [], timeout_s)
            return os.read(self._master, 4096) if readable else b""
        except (OSError, ValueError):
            return None

    def write(self, data: bytes) -> bool:
        """Send all of ``data`` unless stopped; False when the pty is gone."""
        view = memoryview(data)
        while view and not self._stop.is_set():
            try:
                _, writable, _ = select.select([], [self._master], [], 0.05)
                if writable:
                    view = view[os.write(self._master, view):]
            except (OSError, ValueError):
                return False
        return True
