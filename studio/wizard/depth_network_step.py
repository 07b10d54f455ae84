"""Step 9: the depth-camera network - nodes over the network, the guided table procedure per node, the automatic
solve of every node, the merged map and its check against laser-measured distances.

Shown only when the open session's rig has depth nodes (frames of kind ``depth`` under ``world``,
each ``T_world_node`` in the paper's optical node frame, :mod:`backend.core.depth`). Four folders:

- **Nodes**: who is there (:class:`backend.devices.node_network.NodeNetwork` presence through Zenoh
  liveliness, live), each node's clock offset, bandwidth and frames/s; *Capture* one node or
  *Capture all* (what arrived is stored; a node that vanished is named).
- **Guided procedure** of one node, in its order (:data:`backend.calib.depth.guided.GUIDED_STEPS`):
  1 initial pose typed, 2 tables behind each other, 3 tables beside each other, 4 lines and points.
  Each step says what to place where and why it comes here, holds the node's pose in the transform
  editor (sliders and nudges), shows the live residuals (table heights measured against known, line
  distances), offers the solver's suggestion as one button and ticks its *done* criterion. In a
  simulated cell *Place tables (simulation)* moves the simulated tables for the step.
- **Automatic solve**: every node's six degrees of freedom from the same evidence (a job), one result
  card per node (:class:`studio.result_card.ResultCard`), accepted into the rig like any result.
- **Network**: the merged voxel map in 3D, verification (two points, picked in 3D or chosen among the
  detected crosses, and the laser-measured distance: measured against estimated) and the pose table.

Logic lives in the services (:mod:`backend.calib.depth.service`, :mod:`backend.calib.depth.guided_service`);
the 3D drawing in :mod:`studio.depth_view`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from backend.calib.depth import guided_service
from backend.calib.depth import service as network_service
from backend.calib.depth.guided_service import GUIDED_STEPS
from backend.calib.rig import service as rig_service
from backend.core.depth import POSE_COLUMNS, pose_from_row, pose_row
from backend.core.errors import InputError
from backend.core.rig import edge_slot
from backend.core.verdict import Verdict
from studio.cloud_colours import sensor_colour
from studio.context import StudioContext
from studio.depth_view import COUNT_COLOUR_MAX, STEP, DepthView
from studio.job_panel import JobPanel
from studio.layers import STEPS
from studio.marks import WARNING, mark
from studio.result_card import ResultCard, update_markdown
from studio.result_history import ResultHistory
from studio.transform_sliders import TransformSliders
from studio.verdict_view import BADGES

NONE = "(no depth node)"
KIND = "depth_node"
STEP_LABELS = {"initial": "1 · Initial pose", "tables_behind": "2 · Tables behind each other",
               "tables_beside": "3 · Tables beside each other", "lines": "4 · Lines and points"}
"""The guided steps (:data:`GUIDED_STEPS`) as the step dropdown names them."""
ARRANGEMENTS = {"initial": "free", "tables_behind": "behind", "tables_beside": "beside", "lines": "free"}
"""The table arrangement a capture taken during each guided step is stored with."""
SIM_ARRANGEMENTS = {"tables_behind": "behind", "tables_beside": "beside"}
"""The steps whose tables *Place tables (simulation)* moves, and how."""
INSTRUCTIONS = {
    "initial": ("**Measure where the node hangs** with the tape or the laser meter: X and Y from the cell's origin "
                "corner along its walls, Z above the floor (m), at the IR sensor. Type the rotations you know, or 0; "
                "a ceiling node looking down has RotZ about its heading and RotX about −150° to −140°.\n\n"
                "*Why first:* every later step corrects a few degrees and centimetres, and finds the tables and the "
                "lines near where this pose puts them."),
    "tables_behind": ("**Place the three tables one behind the other** along the node's view: at the bottom, the "
                      "middle and the top of its image, all fully in view. Their tops are planes of known height.\n\n"
                      "*Why now:* a tilt error (RotX) makes the far table come out higher or lower than the near "
                      "one, while a height error (Z) moves all three alike; so RotX first, then Z. Rotations "
                      "interact: the roll (step 3) cannot be read while the tilt is still wrong."),
    "tables_beside": ("**Place the three tables side by side** across the view at mid distance: left, centre and "
                      "right.\n\n*Why now:* with the tilt right, a roll error (RotY) makes the left and right tops "
                      "differ in height; then Z is checked again."),
    "lines": ("**The cell's floor lines and crosses** (drawn in 3D) fix what the tables cannot: horizontal planes "
              "say nothing about where the node stands in the floor plane or where it looks. Keep the floor lines "
              "in view (no table on them).\n\n*Why last:* with the node level (steps 2 and 3), its heading (RotZ) "
              "and then X and Y move the seen lines onto the known ones without disturbing the heights."),
}
COLOUR_BY = {"per node": "node", "by count": "count"}
CLICKED = "(the point picked in 3D)"
REFRESH_S = 1.0
"""How often the nodes panel is refreshed (s): bandwidth and frames/s move continuously."""
DEFAULT_LISTEN = "tls/127.0.0.1:7447"
KEYS_FOLDER = "network-keys"
"""The network's keys, in the session's folder unless another is typed (made by *Make the nodes' keys*)."""
HELP = ("Calibrate every depth node of the cell: capture from each node's computer over the network, then either "
        "walk a node through the guided table procedure or solve all nodes at once; check the merged map against "
        "distances measured with the laser meter.")


def _metres(value: float | None) -> str:
    return "–" if value is None or not np.isfinite(value) else f"{value:.3f}"


def _mm(value: float | None) -> str:
    return "–" if value is None or not np.isfinite(value) else f"{1000.0 * value:+.1f}"


def nodes_markdown(statuses: list, nodes: list[str], captures: dict[str, int]) -> str:
    """The presence table: every rig node and every node the network sees, alive or not, with its clock offset
    (ms, node minus studio) and round trip (ms), its stream's bandwidth (kB/s), frames/s and latency (ms),
    and the captures stored; then each node's warnings (a clock far off, a second agent refused under its name,
    a device change that holds its captures)."""
    by_name = {s.name: s for s in statuses}
    rows = ["| node | present | device | clock Δ (ms) | RTT (ms) | kB/s | frames/s | latency (ms) | stored |",
            "|---|---|---|---|---|---|---|---|---|"]
    warnings = []
    for name in dict.fromkeys([*nodes, *by_name]):
        status = by_name.get(name)
        if status is None:
            rows.append(f"| {name} | {mark('not seen', 'muted')} | – | – | – | – | – | – | {captures.get(name, 0)} |")
            continue
        offset = "–" if status.clock_offset_s is None else f"{1000.0 * status.clock_offset_s:+.1f}"
        rtt = "–" if status.clock_rtt_s is None else f"{1000.0 * status.clock_rtt_s:.1f}"
        latency = "–" if status.latency_s is None else f"{1000.0 * status.latency_s:.0f}"
        presence = mark("alive", "good") if status.alive else mark("gone", "bad")
        if status.held is not None:
            presence += " " + mark("held", "warn")
        if status.refused:
            presence += " " + mark(f"{len(status.refused)} refused", "bad")
        rows.append(f"| {name} | {presence} | {status.device or '–'} | {offset} | "
                    f"{rtt} | {status.bandwidth_bps / 1000.0:.0f} | {status.rate_hz:.1f} | {latency} | "
                    f"{captures.get(name, 0)} |")
        warnings += [f"- {WARNING} {name}: {warning}" for warning in status.warnings]
    return "\n".join(rows + ([""] + warnings if warnings else []))


def network_markdown(network) -> str:
    """One line on who may join the open network: its keys' fingerprint and the nodes they admit, or a warning
    that anyone can join; then the node key files it could not read."""
    if not network.secure:
        return (f"{WARNING} listening on {', '.join(network.listen)} **without keys**: anyone who reaches the port "
                f"can join as any node.")
    lines = [f"{mark('secured', 'good')} with keys {network.keys.studio.fingerprint} on {', '.join(network.listen)}: "
             f"only {', '.join(network.admitted()) or 'no node'} can join, each under its own name."]
    return "\n".join(lines + [f"- {WARNING} {problem}" for problem in network.keys.problems])


def keys_markdown(keys, shown_folder: str) -> str:
    """Which key file each node's computer takes, and the command it runs."""
    rows = [f"Keys of network {keys.studio.fingerprint} in `{shown_folder}`. Copy each node's file to its computer "
            f"and start its agent there:", ""]
    rows += [f"- **{node}**: `{keys.bundle_path(node).name}`: `{keys.agent_command(node)}`" for node in keys.nodes]
    return "\n".join(rows + [f"- {WARNING} {problem}" for problem in keys.problems])


def residuals_markdown(residuals: list[dict[str, Any]]) -> str:
    """The live residual table of a guided step: per feature its capture, points, known and measured value (m)
    and error (mm)."""
    if not residuals:
        return "No feature to measure yet: capture for this step first."
    rows = ["| feature | capture | points | known (m) | measured (m) | error (mm) | RMS (mm) |",
            "|---|---|---|---|---|---|---|"]
    for r in residuals:
        rows.append(f"| {r['name']} | {r.get('capture_id') or '–'} | {r.get('n_points', 0):,} | "
                    f"{_metres(r.get('known_m'))} | {_metres(r.get('measured_m'))} | {_mm(r.get('error_m'))} | "
                    f"{_mm(r.get('rms_m')).lstrip('+')} |")
    return "\n".join(rows)


def suggestion_label(suggestion: dict[str, float]) -> str:
    """The suggestion button's label: ``Apply RotX -138.61°, then Z 4.898 m`` (pose-row fields in order)."""
    parts = [f"{name} {value:.2f}°" if name.startswith("Rot") else f"{name} {value:.3f} m"
             for name, value in suggestion.items()]
    return "Apply " + ", then ".join(parts) if parts else "Nothing to apply"


def criterion_markdown(advice: dict[str, Any]) -> str:
    """The step's done criterion with its tick and the problems the solver met (``advice``:
    :func:`backend.calib.depth.guided_service.advice_dict`; why the step comes here is in :data:`INSTRUCTIONS`)."""
    tick = mark("Done", "good") if advice["done"] else mark("Not yet", "muted")
    return "\n".join([f"{tick}: {advice['criterion']}", *(f"- {WARNING} {problem}" for problem in advice["problems"])])


def verification_markdown(rows: list[dict[str, Any]]) -> str:
    """Measured against estimated distances (m) and the error (mm)."""
    if not rows:
        return "No distance checked yet."
    lines = ["| from | to | measured (m) | estimated (m) | error (mm) |", "|---|---|---|---|---|"]
    for row in rows:
        lines.append(f"| {row['a']} | {row['b']} | {row['measured_m']:.4f} | {_metres(row.get('estimated_m'))} | "
                     f"{_mm(row.get('error_m'))} |")
    return "\n".join(lines)


def legend_html(nodes: list[str]) -> str:
    """The merged map's per-node colours (:func:`studio.cloud_colours.sensor_colour` by the node's index)."""
    return " ".join(f'<span style="color:rgb{sensor_colour(i)}">■</span>&nbsp;{name}' for i, name in enumerate(nodes))


class DepthNetworkStep:
    """The panel. The node network is the server's when it opened one (:meth:`attach`, the demo cell's), else
    *Listen for nodes* opens one on the endpoint typed."""

    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self.network = None
        self.view = DepthView(ctx.scene)
        self._measured: tuple[str, str, np.ndarray] | None = None
        """(node, step, T_world_node) of the advice on show: a pass at the same pose shows it again unmeasured."""
        self._wake = threading.Event()
        self._lock = threading.Lock()
        """Held by each advice pass, so that leaving a session waits for the one in flight."""
        self._points: tuple[str, np.ndarray] | None = None
        """(``node/capture id``, points (N, 3) m in the node frame) of the node's latest capture, drawn at the
        editor's pose."""
        self._to_accept: list[str] = []
        """The trusted results *Solve all nodes* previewed, which *Confirm accept* takes."""
        self._stored: dict[str, int] = {}
        """Depth captures stored per node (the presence table's last column), counted when they change."""
        self._crosses: dict[str, dict[str, Any]] = {}
        self._picked: dict[str, Any] | None = None
        gui = ctx.server.gui
        self.folder = gui.add_folder("9 · Depth network", expand_by_default=True, visible=False)
        with self.folder:
            gui.add_markdown(HELP)
            self.node = gui.add_dropdown("Depth node", options=[NONE], hint="the node the panels below work on")
            with gui.add_folder("Nodes", expand_by_default=True):
                self.listen = gui.add_text("Listen on", DEFAULT_LISTEN, hint="Zenoh endpoint the node agents connect "
                                           "to (calib-studio node --connect ...)")
                self.keys_folder = gui.add_text("Network keys", KEYS_FOLDER, hint="the folder of the network's keys "
                                                "(in the session's folder unless a path is typed); only nodes "
                                                "holding keys from it can join")
                self.keys_button = gui.add_button("Make the nodes' keys", hint="the network's keys, and one file "
                                                  "per rig node to copy to its computer")
                self.open_checkbox = gui.add_checkbox("Without keys", False, hint="listen on tcp/ with no "
                                                      "authentication: anyone who reaches the port can join as "
                                                      "any node")
                self.listen_button = gui.add_button("Listen for nodes")
                self.network_text = gui.add_markdown("")
                self.nodes_text = gui.add_markdown("No node network yet: *Listen for nodes*.")
                self.confirm_button = gui.add_button("Confirm the device change", visible=False, color="orange",
                                                     hint="this node came back with another device or serial: "
                                                     "confirm that is meant, and its captures go on")
                self.capture_button = gui.add_button("Capture this node", color="green", hint="one full frame of the "
                                                     "node, stored with the guided step's table arrangement")
                self.capture_all_button = gui.add_button("Capture all", hint="every node at once: what arrives is "
                                                         "kept, a node that does not answer is named")
                self.capture_jobs = JobPanel(ctx, [self.capture_button, self.capture_all_button])
            with gui.add_folder("Guided procedure", expand_by_default=True):
                self.guided_step = gui.add_dropdown("Guided step", options=list(STEP_LABELS.values()))
                self.instructions = gui.add_markdown(INSTRUCTIONS["initial"])
                self.pose_inputs = {name: gui.add_number(f"{name} ({'m' if name in 'XYZ' else '°'})", 0.0,
                                                         step=0.001 if name in "XYZ" else 0.01)
                                    for name in POSE_COLUMNS}
                self.start_button = gui.add_button("Start from this pose", color="blue")
                self.place_button = gui.add_button("Place tables (simulation)", visible=False,
                                                   hint="move the simulated tables where this step wants them")
                self.editor = TransformSliders(gui, lambda _: self._wake.set(), max_translation_m=0.3)
                self.editor.bind_keys(gui, "Depth node")
                self.residuals_text = gui.add_markdown("")
                self.apply_button = gui.add_button("Nothing to apply", disabled=True, color="blue")
                self.criterion_text = gui.add_markdown("")
                self.next_button = gui.add_button("Next step")
                self.finish_button = gui.add_button("Keep this pose as the node's result",
                                                    hint="a guided result, its sigma from a least-squares solve of "
                                                         "the same captures; shown on the card of *Automatic solve* "
                                                         "to accept")
                self.finish_text = gui.add_markdown("")
            with gui.add_folder("Automatic solve", expand_by_default=True):
                self.solve_button = gui.add_button("Solve all nodes", color="blue", hint="every node with captures; "
                                                   "then what accepting the trusted results would move, to confirm")
                self.solve_node_button = gui.add_button("Solve this node", hint="its result on the card below, to "
                                                        "accept after the preview")
                self.solve_jobs = JobPanel(ctx, [self.solve_button, self.solve_node_button])
                self.accept_all_button = gui.add_button("Confirm accept of the trusted results", visible=False,
                                                        color="green", hint="accept every trusted result the "
                                                        "preview above lists, in one go")
                self.history = ResultHistory(gui, lambda _: self._show_result(),
                                             hint="every result of this node (guided and automatic), newest first")
                self.card = ResultCard(ctx, on_accepted=lambda _: self._show_result(),
                                       empty_text="No result for this node yet.")
            with gui.add_folder("Network", expand_by_default=False):
                self.voxel = gui.add_number("Voxel (m)", network_service.DEFAULT_VOXEL_M, min=0.01, max=0.5,
                                            step=0.01)
                self.colour_by = gui.add_dropdown("Colour the map", options=list(COLOUR_BY))
                self.map_button = gui.add_button("Draw the merged map")
                self.map_jobs = JobPanel(ctx, [self.map_button])
                self.legend = gui.add_html("")
                self.point_a = gui.add_dropdown("Point A", options=[CLICKED])
                self.point_b = gui.add_dropdown("Point B", options=[CLICKED])
                self.pick_button = gui.add_button("Pick a point in 3D", hint="click the map: a cross near the ray, "
                                                  "else the nearest cloud point along it")
                self.pick_text = gui.add_markdown("")
                self.measured = gui.add_number("Laser distance (m)", 0.0, min=0.0, max=1000.0, step=0.001)
                self.verify_button = gui.add_button("Add the measured distance")
                self.verification_text = gui.add_markdown("")
                self.pose_table_text = gui.add_markdown("")
        self.node.on_update(lambda _: self._select())
        self.guided_step.on_update(lambda _: self._show_guided_step())
        self.listen_button.on_click(lambda _: self._open_network())
        self.keys_button.on_click(lambda _: self._work(self._make_keys))
        self.open_checkbox.on_update(lambda _: self._toggle_keys())
        self.confirm_button.on_click(lambda _: self._work(self._confirm_device))
        self.capture_button.on_click(lambda _: self._capture([self.current]))
        self.capture_all_button.on_click(lambda _: self._capture(self.nodes))
        self.start_button.on_click(lambda _: self._work(self._start))
        self.place_button.on_click(lambda _: self._work(self._place_tables))
        self.apply_button.on_click(lambda _: self._work(self._apply))
        self.next_button.on_click(lambda _: self._work(self._next_step))
        self.finish_button.on_click(lambda _: self._work(self._finish))
        self.solve_button.on_click(lambda _: self._solve_all())
        self.accept_all_button.on_click(lambda _: self._work(self._accept_all))
        self.solve_node_button.on_click(lambda _: self._solve_node())
        self.map_button.on_click(lambda _: self._draw_map())
        self.pick_button.on_click(lambda _: self._arm_pick())
        self.verify_button.on_click(lambda _: self._work(self._verify))
        threading.Thread(target=self._advice_loop, name="depth-advice", daemon=True).start()
        threading.Thread(target=self._refresh_loop, name="depth-nodes", daemon=True).start()
        ctx.on_session_closing(self._close)
        ctx.on_session_changed(self._on_session)
        ctx.on_rig_changed(lambda _: self._show_result())

    # -- session and node -------------------------------------------------------------------------
    @property
    def nodes(self) -> list[str]:
        return [] if self.ctx.session is None else network_service.node_names(self.ctx.session)

    @property
    def current(self) -> str | None:
        return None if self.ctx.session is None or self.node.value not in self.nodes else self.node.value

    @property
    def step(self) -> str:
        """The guided step on show (a :data:`GUIDED_STEPS` name)."""
        return next(step for step, label in STEP_LABELS.items() if label == self.guided_step.value)

    def _in_view(self) -> None:
        """Put this step's layers in view (the layers panel knows the step once studio/layers.py lists it)."""
        if STEP in STEPS:
            self.ctx.show_step(STEP)

    def _work(self, action: Callable[[], None]) -> None:
        """Run what the user asked for with this step's layers in view; an :class:`InputError` becomes a toast
        (the node's pose and what was captured are kept)."""
        self._in_view()
        try:
            action()
        except InputError as exc:
            self.ctx.notify("Depth network", exc.message, error=True)

    def _close(self) -> None:
        """Leave the open session: the advice in flight ends first, and the scene is redrawn afresh."""
        with self._lock:
            self._measured, self._points, self._picked, self._crosses, self._stored = None, None, None, {}, {}
            self.view.forget()

    def _on_session(self, session) -> None:
        nodes = self.nodes
        self.folder.visible = bool(nodes)
        self.node.options = nodes or [NONE]
        self.node.value = self.node.options[0]
        self.legend.content = self.pick_text.content = self.finish_text.content = ""
        if not nodes:
            self.view.look_at(None)
            return
        self._count_captures()
        cell = network_service.layout(session)
        self.view.look_at(cell)
        self.view.show_cell(cell)
        self._list_crosses()
        self._select()

    def _select(self) -> None:
        """The node changed: its guided state, its pose on the editor and the typed row, its results."""
        node = self.current
        if node is None:
            return
        self.editor.frames = ("world", node)
        state = guided_service.state(self.ctx.session, node)
        self.guided_step.value = STEP_LABELS[state["step"] or GUIDED_STEPS[-1]]
        T = self._node_pose(node)
        for name, value in zip(POSE_COLUMNS, pose_row(T), strict=True):
            self.pose_inputs[name].value = round(value, 4)
        self.editor.set(T, undoable=False)
        self._show_guided_step()
        self._show_result()

    def _node_pose(self, node: str) -> np.ndarray:
        """The pose the guided procedure holds for ``node``, else the rig's (``T_world_node``, m)."""
        held = guided_service.state(self.ctx.session, node)["T_world_node"]
        return np.array(held) if held is not None else network_service.T_world_node(self.ctx.session, node)

    # -- nodes over the network -------------------------------------------------------------------
    def _keys_path(self) -> Path:
        """The typed keys folder, relative to the open session's folder unless absolute."""
        typed = Path(self.keys_folder.value.strip() or KEYS_FOLDER)
        return typed if typed.is_absolute() else self.ctx.session.path / typed

    def _toggle_keys(self) -> None:
        """*Without keys* listens on ``tcp/``, with them on ``tls/``: the endpoint follows."""
        scheme, other = ("tcp/", "tls/") if self.open_checkbox.value else ("tls/", "tcp/")
        if self.listen.value.startswith(other):
            self.listen.value = scheme + self.listen.value[len(other):]
        self.keys_folder.disabled = self.keys_button.disabled = self.open_checkbox.value

    def _make_keys(self) -> None:
        """Make the network's keys for the rig's nodes (or issue the missing ones) and say which file goes where."""
        from backend.services.network_keys import ensure_network_keys

        if not self.nodes:
            raise InputError("the rig has no depth node yet: add the nodes first", "nodes")
        keys = ensure_network_keys(self._keys_path(), self.nodes)
        self.network_text.content = keys_markdown(keys, self.ctx.session.shown(keys.folder))

    def _open_network(self) -> None:
        from backend.devices.node_keys import load_network_keys
        from backend.devices.node_network import NodeNetwork

        try:
            keys = None if self.open_checkbox.value else load_network_keys(self._keys_path())
            network = NodeNetwork(listen=[self.listen.value.strip()], keys=keys)
            network.open()
        except InputError as exc:
            self.ctx.notify("Cannot listen for nodes", exc.message, error=True)
            return
        self.attach(network)

    def attach(self, network) -> None:
        """Use ``network`` (an open :class:`~backend.devices.node_network.NodeNetwork`) for presence and capture."""
        self.network = network
        for handle in (self.listen, self.listen_button, self.keys_folder, self.keys_button, self.open_checkbox):
            handle.disabled = True
        self.network_text.content = network_markdown(network)
        network.on_change(lambda _: self._show_nodes())
        self._show_nodes()

    def _confirm_device(self) -> None:
        if self.network is not None and self.current is not None:
            self.network.confirm_device(self.current)
            self._show_nodes()

    def _refresh_loop(self) -> None:
        """Bandwidth, frames/s and latency move all the time: refresh the presence table every :data:`REFRESH_S`."""
        while True:
            time.sleep(REFRESH_S)
            try:
                self._show_nodes()
            except Exception as exc:  # noqa: BLE001 - the refresher must survive one bad status and say why
                self.nodes_text.content = f"{WARNING} the node status could not be read: {exc}"

    def _show_nodes(self) -> None:
        """The presence table; *Place tables* shows for a table step when the nodes are simulated."""
        session, network = self.ctx.session, self.network
        if session is None or network is None or not self.folder.visible:
            return
        statuses = network.nodes()
        self.nodes_text.content = nodes_markdown(statuses, self.nodes, self._stored)
        self.confirm_button.visible = any(s.name == self.current and s.held is not None for s in statuses)
        self.place_button.visible = self.step in SIM_ARRANGEMENTS and any(
            s.alive and str(s.device).startswith("sim") for s in statuses)

    def _capture(self, nodes: list[str | None]) -> None:
        session, network, nodes = self.ctx.session, self.network, [n for n in nodes if n is not None]
        if network is None:
            self.ctx.notify("No node network", "Listen for nodes first (the Nodes folder).", error=True)
            return
        if not nodes:
            return
        arrangement = ARRANGEMENTS[self.step]
        tables = network_service.layout(session).tables if arrangement in SIM_ARRANGEMENTS.values() else []

        def work(progress) -> tuple[list[str], dict[str, str]]:
            progress(0.1, f"capturing {', '.join(nodes)}")
            frames, failures = network.capture_all(nodes)
            stored = []
            for i, (node, sample) in enumerate(frames.items()):
                progress(0.5 + 0.5 * i / len(frames), f"storing {node}")
                try:
                    stored.append(network_service.capture_node(session, node, sample, arrangement, tables).id)
                except InputError as exc:
                    failures[node] = exc.message
            return stored, failures

        self._in_view()
        self.capture_jobs.run(f"capture of {', '.join(nodes)}", work, self._on_captured)

    def _on_captured(self, result: tuple[list[str], dict[str, str]]) -> None:
        stored, failures = result
        text = f"Stored {len(stored)} capture(s) ({', '.join(stored) or 'none'}) as *{ARRANGEMENTS[self.step]}*."
        if failures:
            text += "\n\n" + "\n".join(f"- {WARNING} {node}: {why}" for node, why in failures.items())
            self.ctx.notify("Not every node was captured", "; ".join(f"{n}: {w}" for n, w in failures.items()),
                            error=True)
        self.capture_jobs.text.content = text
        self._count_captures()
        self._show_nodes()
        self._list_crosses()
        self._measured = None  # a new capture: measure again
        self._wake.set()

    def _count_captures(self) -> None:
        self._stored = {node: len(network_service.captures(self.ctx.session, node)) for node in self.nodes}

    def _place_tables(self) -> None:
        """Move the simulated tables where this step wants them in the node's view (the sim cell's nodes)."""
        from backend.sim.depth_cell import table_placements

        node, arrangement = self.current, SIM_ARRANGEMENTS.get(self.step)
        if node is None or arrangement is None or self.network is None:
            raise InputError("tables are placed for step 2 or 3 of a node of a simulated cell", "step")
        self.network.set_sim_placements(table_placements(node, arrangement, network_service.layout(self.ctx.session)))
        self.capture_jobs.text.content = (f"Tables placed {arrangement} each other in {node}'s view: *Capture this "
                                          "node* now.")

    # -- the guided procedure ---------------------------------------------------------------------
    def _show_guided_step(self) -> None:
        step = self.step
        self.instructions.content = INSTRUCTIONS[step]
        initial = step == GUIDED_STEPS[0]
        for handle in self.pose_inputs.values():
            handle.visible = initial
        self.start_button.visible = initial
        self.next_button.visible = step != GUIDED_STEPS[-1]
        self._no_advice("Measuring at the editor's pose …")
        self._show_nodes()
        self._wake.set()

    def _no_advice(self, message: str) -> None:
        """No residuals on show (none yet, or what stops them): ``message`` instead, nothing to apply."""
        self._measured = None
        self.residuals_text.content = ""
        self.criterion_text.content = message
        self.apply_button.label, self.apply_button.disabled = "Nothing to apply", True

    def _keep_editor_pose(self, node: str) -> None:
        """Hand the editor's pose to the procedure (a nudge) when it moved since the procedure's pose."""
        held = guided_service.state(self.ctx.session, node)["T_world_node"]
        if held is not None and not np.allclose(held, self.editor.T, rtol=0.0, atol=1e-9):
            guided_service.nudge(self.ctx.session, node, pose_row(self.editor.T))

    def _start(self) -> None:
        node = self.current
        if node is None:
            return
        row = [float(self.pose_inputs[name].value) for name in POSE_COLUMNS]
        guided_service.start(self.ctx.session, node, row)
        self.editor.set(pose_from_row(row), undoable=False)
        self.guided_step.value = STEP_LABELS[GUIDED_STEPS[1]]

    def _apply(self) -> None:
        """Take the step's suggestion from the editor's pose; the editor moves there (one undo step)."""
        node = self.current
        if node is None:
            return
        step = self.step
        self._no_advice("Applying the suggestion …")
        try:
            self._keep_editor_pose(node)
            state = guided_service.apply(self.ctx.session, node, step)
            T = np.array(state["T_world_node"])
            with self._lock:  # the advice at the new pose came with it: the editor's move need not measure it again
                self._show_advice(node, step, T, state["advice"])
            self.editor.set(T)
        finally:
            self._wake.set()  # a refused suggestion: the residuals at the pose kept come back

    def _next_step(self) -> None:
        node = self.current
        if node is not None:
            self._keep_editor_pose(node)
        index = GUIDED_STEPS.index(self.step)
        if index + 1 < len(GUIDED_STEPS):
            self.guided_step.value = STEP_LABELS[GUIDED_STEPS[index + 1]]

    def _finish(self) -> None:
        node = self.current
        if node is None:
            return
        self._keep_editor_pose(node)
        self.finish_text.content = "Keeping the pose: solving the same captures by least squares for its sigma …"
        self.finish_button.disabled = True
        try:
            record = guided_service.finish(self.ctx.session, node)
        except InputError:
            self.finish_text.content = ""
            raise
        finally:
            self.finish_button.disabled = False
        self._show_result(select=record["id"])
        level = Verdict.from_record(record).level
        self.finish_text.content = (f"Kept as **{record['id']}** (guided, verdict {level}): accept it on the card "
                                    "below, under the automatic solve.")

    def _advice_loop(self) -> None:
        """Re-measure the step's residuals at the editor's pose after every change (the newest pose only)."""
        while True:
            self._wake.wait()
            self._wake.clear()  # changes from now on wake the next pass; this one measures the newest state
            try:
                with self._lock:
                    self._advise()
            except InputError as exc:
                self._no_advice(f"{WARNING} {exc.message}")
            except Exception as exc:  # noqa: BLE001 - the worker must survive one bad input and say why
                self.criterion_text.content = f"{WARNING} the residuals could not be measured: {exc}"

    def _advise(self) -> None:
        session, node, step, T = self.ctx.session, self.current, self.step, self.editor.T
        if session is None or node is None:
            return
        self.view.show_node(node, T, self._latest_points(node))
        if step == GUIDED_STEPS[0]:
            self._no_advice("Type the measured pose, then *Start from this pose*.")
            return
        measured = self._measured
        if measured is not None and measured[:2] == (node, step) and np.allclose(measured[2], T, rtol=0, atol=1e-12):
            return
        advice = guided_service.advice_dict(guided_service.advise(session, node, step, T_world_node=T))
        if step == self.step and node == self.current:  # else the user went on: the next pass measures that
            self._show_advice(node, step, T, advice)

    def _show_advice(self, node: str, step: str, T: np.ndarray, advice: dict[str, Any]) -> None:
        """Show ``advice`` (:func:`backend.calib.depth.guided_service.advice_dict`) of ``step`` at pose ``T``."""
        self._measured = (node, step, T)
        self.residuals_text.content = residuals_markdown(advice["residuals"])
        self.apply_button.label = suggestion_label(advice["suggestion"])
        self.apply_button.disabled = not advice["suggestion"]
        self.criterion_text.content = criterion_markdown(advice)

    def _latest_points(self, node: str) -> np.ndarray | None:
        """The node's latest capture (N, 3, m, node frame), read once per capture."""
        session = self.ctx.session
        latest = network_service.captures(session, node)[-1:]
        if not latest:
            return None
        if self._points is None or self._points[0] != f"{node}/{latest[0].id}":
            depth, _ = session.depth_capture(node, latest[0].id)
            points, _ = network_service.capture_intrinsics(latest[0]).unproject(depth)
            self._points = (f"{node}/{latest[0].id}", points)
        return self._points[1]

    # -- automatic solve and results --------------------------------------------------------------
    def _results(self) -> list[str]:
        node = self.current
        return [] if node is None else [r["id"] for r in reversed(self.ctx.session.results(node, KIND))]

    def _show_result(self, select: str | None = None) -> None:
        """The node's results (``select``, else the one picked, else the newest) on its card, and the tables."""
        session, node = self.ctx.session, self.current
        if session is None or node is None:
            self.card.show(None, None)
            return
        selected = self.history.fill(self._results(), select or self.history.selected)
        accepted = session.accepted(edge_slot(network_service.WORLD, node))
        self.card.show(None if selected is None else session.result(selected), accepted)
        self._show_tables()

    def _solve_all(self) -> None:
        """Solve every node with captures (nothing accepted), then preview accepting the trusted results."""
        session = self.ctx.session
        if session is None:
            return
        self._in_view()
        self._to_accept = []
        self.accept_all_button.visible = False
        self.solve_jobs.run("solve of every node", lambda progress: network_service.solve_nodes(
            session, progress=progress), self._on_network_solved)

    def _on_network_solved(self, out: dict[str, Any]) -> None:
        """Say what accepting the trusted results together would move; the others go through their own card."""
        session = self.ctx.session
        levels = {node: Verdict.from_record(session.result(result_id)).level
                  for node, result_id in out["results"].items()}
        self._to_accept = [out["results"][node] for node, level in levels.items() if level == "trusted"]
        lines = [f"Solved {len(out['results'])} node(s): " + (", ".join(
            f"{node} {out['results'][node]} {BADGES[level]}" for node, level in levels.items())
            or "none") + ". Nothing is accepted yet."]
        if self._to_accept:
            update = rig_service.preview_many(session, self._to_accept)
            lines += ["", f"**Accepting the {len(self._to_accept)} trusted result(s) would:**", "",
                      update_markdown(update)]
        lines += [f"- {node}: its result is *{level}*: read why on its card, accept it there"
                  for node, level in levels.items() if level != "trusted"]
        lines += [f"- {WARNING} {problem}" for problem in out["problems"]]
        self.accept_all_button.visible = bool(self._to_accept)  # before the text that offers it
        self.solve_jobs.text.content = "\n".join(lines)
        self._show_result()

    def _accept_all(self) -> None:
        """*Confirm accept*: the trusted results the preview listed go into the rig."""
        to_accept, self._to_accept = self._to_accept, []
        self.accept_all_button.visible = False
        if not to_accept:
            return
        update = rig_service.accept_many(self.ctx.session, to_accept)
        self.solve_jobs.text.content = (f"**Accepted {', '.join(to_accept)}.**\n\n" + update_markdown(update))
        self.ctx.rig_changed()  # the card, the tables and the scene follow (on_rig_changed)

    def _solve_node(self) -> None:
        """Solve the current node (not accepted: its card shows the result to accept)."""
        session, node = self.ctx.session, self.current
        if node is None:
            return
        self._in_view()
        self.solve_jobs.run(f"solve of {node}", lambda progress: network_service.solve_session(
            session, node, progress=progress)["id"], lambda result_id: self._show_result(select=result_id))

    # -- the whole network ------------------------------------------------------------------------
    def _draw_map(self) -> None:
        session, voxel_m, colour_by = self.ctx.session, float(self.voxel.value), COLOUR_BY[self.colour_by.value]

        def work(progress) -> network_service.VoxelMap:
            progress(0.1, "every node's latest capture into the world, on the voxel grid")
            return network_service.merged_voxel_map(session, voxel_m=voxel_m)

        def done(voxel_map: network_service.VoxelMap) -> None:
            self.view.show_voxel_map(*voxel_map, voxel_m=voxel_m, colour_by=colour_by)
            self.legend.content = (legend_html(self.nodes) if colour_by == "node" else
                                   f"Points per voxel: 1 (blue) to {COUNT_COLOUR_MAX}+ (red), log scale.")
            self.map_jobs.text.content = f"{len(voxel_map.counts):,} voxels of {voxel_m * 100:g} cm."
            self._list_crosses()

        self._in_view()
        self.map_jobs.run("merged voxel map", work, done)

    def _list_crosses(self) -> None:
        """Offer every cross the nodes see as a verification point (beside a point picked in 3D)."""
        self._crosses = {c["name"]: c for c in network_service.detected_crosses(self.ctx.session)}
        names = [*self._crosses, CLICKED]
        for dropdown, index in ((self.point_a, 0), (self.point_b, 1)):
            dropdown.options = names
            dropdown.value = names[min(index, len(names) - 1)]

    def _arm_pick(self) -> None:
        """The next click in the 3D view picks a point: a detected cross near the ray, else the nearest point."""
        scene = self.ctx.server.scene

        @scene.on_click()
        def picked(event) -> None:
            scene.remove_click_callback(picked)
            try:
                self._picked = network_service.pick(self.ctx.session, event.ray_origin, event.ray_direction)
            except InputError as exc:
                self.pick_text.content = f"{WARNING} {exc.message}"
                return
            self.pick_text.content = (f"Picked **{self._picked['name']}** at "
                                      f"{', '.join(f'{v:.3f}' for v in self._picked['point_m'])} m (world).")
            self.view.show_picks([np.asarray(self._picked["point_m"])])

        self._in_view()
        self.pick_text.content = "Click a point of the map in the 3D view."

    def _target(self, choice: str) -> dict[str, Any]:
        if choice != CLICKED:
            return self._crosses[choice]
        if self._picked is None:
            raise InputError("no point picked in 3D yet: *Pick a point in 3D* first, or choose a cross", "point")
        return self._picked

    def _verify(self) -> None:
        a, b = self._target(self.point_a.value), self._target(self.point_b.value)
        row = network_service.add_verification(self.ctx.session, a, b, float(self.measured.value))
        self.view.show_picks([np.asarray(row["a_m"]), np.asarray(row["b_m"])])
        self._show_tables()

    def _show_tables(self) -> None:
        """The verification table and the pose table, at the rig's current poses."""
        summary = network_service.network_summary(self.ctx.session)
        self.verification_text.content = "**Verification**\n\n" + verification_markdown(summary["verification"])
        self.pose_table_text.content = ("**Pose table** (X, Y, Z m; RotZ, RotY, RotX °; the rig's current poses)"
                                        f"\n\n```\n{network_service.pose_table_text(summary)}\n```")
