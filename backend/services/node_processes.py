"""Node agents on this computer, each its own ``calib-studio node`` process, connected to the studio over Zenoh.

The simulated depth cell runs its six nodes this way (``calib-studio demo --rig depth-cell``): the same agent a
node's own computer runs, so the studio takes their frames through the network exactly as from real nodes.

- Each agent writes its stdout and stderr to one log, ``<log_dir>/<name>.log`` (started afresh), so the studio's
  own stdout keeps the URL as its first line.
- :meth:`NodeProcesses.stop` (the server's ``finally``, and ``atexit`` for any other exit) sends every agent
  SIGTERM, waits, and kills those still running. On Linux each agent is also started through ``setpriv
  --pdeathsig TERM`` so the kernel stops it should the studio die without running either (SIGKILL): no orphans.
  The death signal follows the *thread* that started the agent, so start them from a thread that lives as long
  as the studio (the main thread). As that signal can be lost in an agent's start-up, each agent also stops
  itself once the studio's process is gone (:data:`~backend.devices.node_agent.PARENT_PID_ENV`).
- An agent that exits while the studio runs is named with its exit code and the last line of its log
  (:meth:`NodeProcesses.dead`; :meth:`NodeProcesses.watch` calls back once per agent).
"""

from __future__ import annotations

import atexit
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from backend.core.errors import InputError
from backend.devices.node_agent import PARENT_PID_ENV
from backend.devices.node_keys import NetworkKeys

STOP_TIMEOUT_S = 5.0
"""How long (s) the agents get after SIGTERM before they are killed."""
LOG_TAIL_BYTES = 4096
"""How much of the end of an agent's log (bytes) is read for the line that says why it exited."""
WATCH_POLL_S = 1.0
"""How often (s) :meth:`NodeProcesses.watch` looks for agents that exited."""


def free_tcp_port(host: str = "127.0.0.1") -> int:
    """A TCP port free on ``host`` now (the OS picks it; another process may take it before it is used)."""
    with socket.socket() as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


def _death_signal_prefix() -> list[str]:
    """``setpriv --pdeathsig TERM --`` where util-linux's ``setpriv`` exists (Linux), else nothing: it sets the
    agent's parent-death signal and then executes the agent in the same process (no wrapper stays behind)."""
    setpriv = shutil.which("setpriv") if sys.platform.startswith("linux") else None
    return [setpriv, "--pdeathsig", "TERM", "--"] if setpriv else []


def _last_line(log: Path) -> str:
    """The last non-empty line of ``log`` (read from its last :data:`LOG_TAIL_BYTES`), or ``""``."""
    try:
        with log.open("rb") as handle:
            handle.seek(0, 2)
            handle.seek(max(0, handle.tell() - LOG_TAIL_BYTES))
            lines = handle.read().decode(errors="replace").splitlines()
    except OSError:
        return ""
    return next((line.strip() for line in reversed(lines) if line.strip()), "")


@dataclass
class NodeProcess:
    """One running (or exited) agent."""

    name: str
    device: str
    """The agent's ``--device`` spec (``sim-cell:sn1``)."""
    process: subprocess.Popen
    log: Path

    def exit_message(self) -> str | None:
        """None while it runs, else ``"exited with code 2: <last log line>"``."""
        code = self.process.poll()
        if code is None:
            return None
        why = {-signal.SIGKILL: "was killed (SIGKILL)", -signal.SIGTERM: "was stopped (SIGTERM)"}.get(
            code, f"exited with code {code}")
        last = _last_line(self.log)
        return f"{why}: {last}" if last else why

    def status(self) -> dict[str, Any]:
        """``{"name", "device", "pid", "alive", "exit", "log"}`` (``exit``: :meth:`exit_message`)."""
        message = self.exit_message()
        return {"name": self.name, "device": self.device, "pid": self.process.pid, "alive": message is None,
                "exit": message, "log": str(self.log)}


class NodeProcesses:
    """Node-agent subprocesses that connect to one Zenoh endpoint (the studio's ``tcp/127.0.0.1:PORT``)."""

    def __init__(self, connect: str, log_dir: Path, *, rate_hz: float | None = None, voxel_m: float | None = None,
                 keys: NetworkKeys | None = None):
        """``rate_hz``: each agent's publishing rate (Hz; None: the device's own); ``voxel_m``: the voxel (m) of
        its streamed clouds (None: the agent's default); ``keys``: the network's keys, each agent joining with its
        own bundle (``--keys``). Nothing starts before :meth:`start`."""
        self.connect = connect
        self.keys = keys
        self.log_dir = Path(log_dir)
        self.rate_hz = rate_hz
        self.voxel_m = voxel_m
        self._agents: dict[str, NodeProcess] = {}
        self._stopping = threading.Event()
        self._lock = threading.Lock()
        self._exit_hook = False

    def command(self, name: str, device: str) -> list[str]:
        """The agent's command line: ``python -m backend.cli node --name NAME --device SPEC --connect ENDPOINT
        [--keys FILE]``."""
        command = [*_death_signal_prefix(), sys.executable, "-m", "backend.cli", "node", "--name", name,
                   "--device", device, "--connect", self.connect]
        if self.keys is not None:
            command += ["--keys", str(self.keys.bundle_path(name))]
        if self.rate_hz is not None:
            command += ["--rate", f"{self.rate_hz:g}"]
        if self.voxel_m is not None:
            command += ["--voxel", f"{self.voxel_m:g}"]
        return command

    def start(self, devices: dict[str, str]) -> None:
        """Start one agent per ``{name: device spec}``; a name already running raises :class:`InputError`."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        with self._lock:
            running = sorted(set(devices) & {n for n, a in self._agents.items() if a.process.poll() is None})
            if running:
                raise InputError(f"node agents {running} are already running", "name", 409)
            if not self._exit_hook:
                atexit.register(self.stop)
                self._exit_hook = True
            self._stopping.clear()
            for name, device in devices.items():
                log = self.log_dir / f"{name}.log"
                with log.open("wb") as output:  # the child holds its own descriptor
                    process = subprocess.Popen(self.command(name, device), stdin=subprocess.DEVNULL, stdout=output,
                                               stderr=subprocess.STDOUT,
                                               env={**os.environ, PARENT_PID_ENV: str(os.getpid())})
                self._agents[name] = NodeProcess(name, device, process, log)

    @property
    def agents(self) -> dict[str, NodeProcess]:
        with self._lock:
            return dict(self._agents)

    def status(self) -> list[dict[str, Any]]:
        """Every agent's :meth:`NodeProcess.status`, in the order they were started."""
        return [agent.status() for agent in self.agents.values()]

    def alive(self) -> list[str]:
        """Names of the agents still running."""
        return [name for name, agent in self.agents.items() if agent.process.poll() is None]

    def dead(self) -> dict[str, str]:
        """``{name: why}`` of every agent that has exited (``"exited with code 2: no such device ..."``)."""
        return {name: message for name, agent in self.agents.items()
                if (message := agent.exit_message()) is not None}

    def watch(self, on_exit: Callable[[str, str], None], poll_s: float = WATCH_POLL_S) -> threading.Thread:
        """Call ``on_exit(name, why)`` once for each agent that exits before :meth:`stop` (a daemon thread)."""
        def follow() -> None:
            told: set[str] = set()
            while not self._stopping.wait(poll_s):
                for name, why in self.dead().items():
                    if name not in told and not self._stopping.is_set():
                        told.add(name)
                        on_exit(name, why)

        thread = threading.Thread(target=follow, name="node-agents-watch", daemon=True)
        thread.start()
        return thread

    def stop(self, timeout_s: float = STOP_TIMEOUT_S) -> None:
        """SIGTERM every agent, wait up to ``timeout_s`` (s) for all, then kill what still runs. Safe to repeat."""
        self._stopping.set()
        agents = list(self.agents.values())
        for agent in agents:
            if agent.process.poll() is None:
                agent.process.terminate()
        deadline = time.monotonic() + timeout_s  # one shared wait: they stop in parallel
        for agent in agents:
            try:
                agent.process.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                agent.process.kill()
                agent.process.wait(timeout=timeout_s)

    def __enter__(self) -> NodeProcesses:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()
