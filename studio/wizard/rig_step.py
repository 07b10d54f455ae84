"""Step 8: the rig - the fused tree of every accepted result, its checks, reverts and the whole-rig downloads.

The tree is :func:`backend.calib.rig.service.solve_rig`: each frame's ``T_parent_child`` with its sigma,
each edge (mounting prior or accepted result) with its residual against the tree and its
leave-one-out disagreement with the rest, the loops' closure errors and the frames no edge
connects to the root. The 3D view draws it under ``/rig_tree`` (:meth:`RigScene.show_rig_tree`):
each frame's sigma ellipsoid, scaled up, and each edge coloured by its residual. The panel and the
drawing follow every accept (:meth:`StudioContext.rig_changed`) and every session change.
"""

from __future__ import annotations

import numpy as np
import viser

from backend.calib.rig import service as rig_service
from backend.calib.rig.service import FLAG_SIGMA, EdgeResidual, RigTree
from backend.core.errors import InputError
from backend.core.transforms import transform_error
from backend.services.demo import frame_truth
from studio.context import StudioContext
from studio.marks import WARNING, mark
from studio.result_card import rotation_vector_deg, update_markdown
from studio.scene import ELLIPSOID_MAX_M

NONE = "(no accepted edge)"
HELP = ("The rig as one tree: every accepted result is an edge between two frames, the mounting guesses weak "
        "priors; the tree is their least-squares fit. An edge whose residual disagrees with the rest beyond "
        f"{FLAG_SIGMA:g} sigma is *flagged* and left out: revert it, or revert what it disagrees with. *fits*: within "
        f"{FLAG_SIGMA:g} sigma of the rest; *unverified*: no other edge checks it (a mounting guess no calibration "
        "has measured yet); *not in the fit*: it reaches no frame connected to the root.")
ELLIPSOID_SCALES = {"auto": None, "×1": 1.0, "×10": 10.0, "×100": 100.0, "×1000": 1000.0}
"""How much the sigma ellipsoids are scaled up; *auto* is :func:`auto_scale`."""
AUTO_TARGET_M = 0.1
"""*auto* draws the median frame's largest 1-sigma semi-axis at most this long (m)."""
DOWNLOADS = {"URDF": "urdf", "ROS 2 launch file": "launch", "rig YAML": "rig"}


def _numbers(values, fmt: str, factor: float = 1.0) -> str:
    return ", ".join("–" if v is None or not np.isfinite(v) else format(v * factor, fmt) for v in values)


def auto_scale(tree: RigTree) -> float:
    """The power of ten (1 to 1000) that draws the median frame's largest 1-sigma of its origin (root axes) at most
    :data:`AUTO_TARGET_M` long: millimetre sigmas show, and the centimetres of a mounting guess stay in view."""
    sigmas_m = [np.sqrt(np.max(np.diag(f.covariance_root_translation))) for f in tree.frames.values()]
    sigmas_m = [s for s in sigmas_m if np.isfinite(s) and s > 0]
    if not sigmas_m:
        return 1.0
    return float(10.0 ** np.clip(np.floor(np.log10(AUTO_TARGET_M / np.median(sigmas_m))), 0, 3))


def frames_markdown(tree: RigTree, truth: dict[str, np.ndarray] | None = None) -> str:
    """The fused frames as a table: parent, xyz (m), rotation vector (deg), 1-sigma in the parent (mm, deg about
    x, y, z); with a simulator's ``truth`` (``T_root_frame`` per frame, a demo's), each frame's distance from it
    (mm, deg) beside its sigma."""
    truth = truth or {}
    rows = ["| frame | parent | x, y, z (m) | rotation vector (°) | σ x, y, z (mm) | σ rot x, y, z (°) |"
            + (" off the truth (mm, °) |" if truth else ""), "|---|---|---|---|---|---|" + ("---|" if truth else "")]
    for name, frame in tree.frames.items():
        xyz_m = frame.T_parent_child[:3, 3]
        std = frame.std
        row = (f"| {name} | {frame.parent} | {_numbers(xyz_m, '.3f')} "
               f"| {_numbers(rotation_vector_deg(frame.T_parent_child), '.2f')} "
               f"| {_numbers(std['trans_m'], '.1f', 1000.0)} | {_numbers(std['rot_deg'], '.2f')} |")
        if truth:
            row += f" {_off_truth(frame.T_root_frame, truth.get(name))} |"
        rows.append(row)
    return "\n".join(rows)


def _off_truth(T_root_frame: np.ndarray, T_true: np.ndarray | None) -> str:
    """``12.3 mm, 1.84°``: how far a frame is from the simulator's truth (position, rotation angle); – without."""
    if T_true is None:
        return "–"
    dt_m, dr_deg = transform_error(T_root_frame, T_true)
    return f"{1000.0 * np.linalg.norm(dt_m):.1f} mm, {np.linalg.norm(dr_deg):.2f}°"


def edge_mark(residual: EdgeResidual) -> str:
    """*flagged* (beyond :data:`FLAG_SIGMA` of the rest, left out), *fits* (within it), *unverified* (no other edge
    checks it: never shown as fitting), *not in the fit*."""
    if residual.flagged:
        return mark("flagged", "bad")
    if not np.isfinite(residual.chi2):
        return mark("not in the fit", "muted")
    return mark("unverified", "warn") if residual.disagreement_sigma is None else mark("fits", "good")


def edges_markdown(tree: RigTree) -> str:
    """Every edge: its mark, frames, kind, result, residual against the tree (mm, deg, chi2/6), disagreement."""
    rows = ["| | parent → child | kind | result | residual mm / ° / χ² | disagreement (σ) |",
            "|---|---|---|---|---|---|"]
    for residual in tree.edges:
        edge = residual.edge
        fitted = np.isfinite(residual.chi2)
        value = (f"{residual.trans_m * 1000:.2f} / {residual.rot_deg:.3f} / {residual.chi2:.2f}" if fitted
                 else "not in the fit")
        disagreement = ("no other edge checks it" if residual.disagreement_sigma is None
                        else f"{residual.disagreement_sigma:.1f}")
        rows.append(f"| {edge_mark(residual)} | {edge.parent} → {edge.child} | {edge.kind} | {edge.result_id or '–'} "
                    f"| {value} | {disagreement} |")
    return "\n".join(rows)


def checks_markdown(tree: RigTree) -> str:
    """The loops with their closure errors, then what the user must look at (flagged edges, unconnected frames)."""
    lines = [f"- loop {' → '.join([*loop.frames, loop.frames[0]])}: closes within {loop.trans_m * 1000:.2f} mm, "
             f"{loop.rot_deg:.3f}°" for loop in tree.loops] or ["- no loop of measured edges yet"]
    lines += [f"- {mark('flagged', 'bad') if 'disagrees' in problem else WARNING} {problem}"
              for problem in tree.problems()]
    return "**Loops and checks**\n\n" + "\n".join(lines)


class RigStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self.tree: RigTree | None = None
        self._kalibr: dict[str, viser.GuiCheckboxHandle] = {}
        gui = ctx.server.gui
        with gui.add_folder("8 · Rig", expand_by_default=False):
            gui.add_markdown(HELP)
            self.refresh_button = gui.add_button("Re-solve the tree", hint="after accepts made outside the studio "
                                                 "(the API, the command line); the studio's own accepts redraw it")
            self.frames_text = gui.add_markdown("No session open.")
            self.edges_text = gui.add_markdown("")
            self.checks_text = gui.add_markdown("")
            self.scale = gui.add_dropdown("Ellipsoid scale", options=list(ELLIPSOID_SCALES), initial_value="auto")
            self.scale_note = gui.add_markdown("")
            with gui.add_folder("Revert an edge", expand_by_default=False):
                self.revert_slot = gui.add_dropdown("Accepted slot", options=[NONE])
                self.revert_button = gui.add_button("Revert slot", color="red")
                self.revert_text = gui.add_markdown("")
            with gui.add_folder("Downloads", expand_by_default=False):
                self.format = gui.add_dropdown("Rig file", options=list(DOWNLOADS))
                self.convention = gui.add_dropdown("Cameras as", options=["optical", "body"],
                                                   hint="optical: each camera frame is its optical frame; body: "
                                                        "a body frame with a fixed CAM_optical_frame child")
                self.download_button = gui.add_button("Download rig file")
                self.kalibr_folder = gui.add_folder("Kalibr camchain cameras")
                self.kalibr_button = gui.add_button("Download Kalibr camchain (checked cameras)")
                self.report_button = gui.add_button("Download calibration report (HTML)")
        self.refresh_button.on_click(lambda _: self._work(self.refresh))
        self.scale.on_update(lambda _: self._work(self._draw))
        self.revert_button.on_click(lambda _: self._work(self._revert))
        self.download_button.on_click(lambda event: ctx.download(
            event, DOWNLOADS[self.format.value], convention=self.convention.value))
        self.kalibr_button.on_click(lambda event: ctx.download(
            event, "kalibr", cameras=[name for name, box in self._kalibr.items() if box.value]))
        self.report_button.on_click(lambda event: ctx.send_file(event, self._report))
        ctx.on_session_changed(self._on_session)
        ctx.on_rig_changed(lambda session: self.refresh())

    def _work(self, action) -> None:
        """Run what the user asked for here, with this step's layers (the rig tree) in view."""
        self.ctx.show_step("rig")
        action()

    def _on_session(self, session) -> None:
        for checkbox in self._kalibr.values():
            checkbox.remove()
        with self.kalibr_folder:
            self._kalibr = {frame.name: self.ctx.server.gui.add_checkbox(
                f"Kalibr: {frame.name}", initial_value=frame.intrinsics is not None)
                for frame in session.rig.sensors("camera")}
        self.revert_text.content = ""
        self.refresh()

    def _report(self) -> tuple[str, str]:
        """The session's HTML report (its plotting imports take seconds, so they load on the first click)."""
        from backend.services.report import render_report

        return f"{self.ctx.session.name}_report.html", render_report(self.ctx.session)

    def refresh(self) -> None:
        """Re-solve the open session's tree, fill the panel and redraw the tree in 3D."""
        session = self.ctx.session
        if session is None:
            return
        self.tree = rig_service.solve_rig(session)
        self.frames_text.content = frames_markdown(self.tree, frame_truth(session))
        self.edges_text.content = edges_markdown(self.tree)
        self.checks_text.content = checks_markdown(self.tree)
        slots = list(dict.fromkeys(r.edge.slot for r in self.tree.edges if r.edge.slot))
        self.revert_slot.options = slots or [NONE]
        self._draw()

    def _draw(self) -> None:
        if self.tree is None:
            return
        scale = ELLIPSOID_SCALES[self.scale.value] or auto_scale(self.tree)
        self.scale_note.content = (
            f"The 3D view (*Rig tree* layer): each frame's 1-sigma ellipsoid of its origin in {self.tree.root} axes, "
            f"drawn **×{scale:g}** to be visible (wireframe: cut at {ELLIPSOID_MAX_M:g} m); each edge a line "
            "coloured by its residual: green χ² ≤ 1, amber ≤ 9, red beyond or flagged, grey not in the fit; mounting "
            "priors thinner.")
        self.ctx.scene.show_rig_tree(self.tree, scale)

    def _revert(self) -> None:
        session, slot = self.ctx.session, self.revert_slot.value
        if session is None or slot == NONE:
            return
        try:
            update = rig_service.revert(session, slot)
        except InputError as exc:
            self.ctx.notify("Cannot revert", exc.message, error=True)
            return
        self.revert_text.content = f"**{slot} reverted.**\n\n{update_markdown(update)}"
        self.ctx.rig_changed()
