"""One result card for every step: what a result says, how far to trust it, and *Accept* with the rig preview.

Every kind of result (intrinsics, LiDAR-LiDAR, LiDAR-camera, multi-camera, a sweep geometry)
is shown the same way: its transforms with their 1-sigma, its residual statistics, the verdict
with every reason, and its warnings. *Accept* first shows what accepting would do to the whole
rig (:func:`backend.calib.rig.service.preview`: which frames move, by how many sigma, which edges
would disagree with the rest) and applies on the second click, optionally reverting an edge the
new result disagrees with (the user chooses which to keep).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from backend.calib.rig import service as rig_service
from backend.core.camera import CameraIntrinsics
from backend.core.errors import InputError
from backend.core.result import StoredResult, TransformResult
from backend.core.transforms import to_rvec_tvec
from backend.services.exports import camera_exports
from studio.context import StudioContext
from studio.marks import WARNING, mark
from studio.verdict_view import ConfirmCheck, verdict_markdown

KEEP_BOTH = "(revert nothing)"


def _values(values: list[float | None], scale: float, digits: int) -> str:
    return ", ".join("n/a" if v is None else f"{scale * v:.{digits}f}" for v in values)


def rotation_vector_deg(T: np.ndarray) -> np.ndarray:
    """The rotation of ``T`` as a rotation vector (deg): its axis times its angle, with the same components in the
    parent's and the child's axes. Shown instead of yaw, pitch and roll wherever a rotation is read, not typed:
    a small change reads small at any attitude, where near pitch ±90° yaw and roll turn 0.2° into degrees."""
    return np.degrees(to_rvec_tvec(T)[0])


def transform_markdown(transform: TransformResult) -> str:
    """``parent → child``: x, y, z (m), the rotation vector (deg) and the 1-sigma (mm, deg about x, y, z)."""
    std, T = transform.std, transform.T_parent_child
    return (f"**{transform.parent} → {transform.child}**: {', '.join(f'{v:.4f}' for v in T[:3, 3])} m · "
            f"rotation vector {', '.join(f'{v:.3f}' for v in rotation_vector_deg(T))}°\n\n"
            f"1σ: {_values(std['trans_m'], 1000, 2)} mm · {_values(std['rot_deg'], 1, 3)}° about x, y, z")


def _statistic(key: str, value: Any) -> str | None:
    """One residual statistic as a person reads it (lengths in mm), or None for what is not a number."""
    if isinstance(value, bool) or value is None:
        return None
    if isinstance(value, int | float):
        if key.endswith("_m"):
            return f"{key[:-2]} {1000 * value:.2f} mm"
        unit = {"_px": " px", "_deg": "°", "_s": " s"}.get(key[key.rfind("_"):], "")
        return f"{key.removesuffix(key[key.rfind('_'):]) if unit else key} {value:.3g}{unit}"
    if isinstance(value, dict) and key.endswith("_m"):  # e.g. c2c_m: mean, median, p95, std
        parts = [f"{name} {1000 * v:.1f}" for name, v in value.items() if isinstance(v, int | float)]
        return f"{key[:-2]} {' / '.join(parts)} mm" if parts else None
    return None


def residuals_markdown(residuals: dict[str, Any]) -> str:
    return " · ".join(text for key, value in residuals.items() if (text := _statistic(key, value)) is not None)


def _intrinsics_markdown(camera: dict[str, Any]) -> str:
    K = np.array(camera["K"])
    spline = camera.get("spline")
    lens = (f"spline {spline['nx']}×{spline['ny']} knots over {spline['fov_x_deg']:g}° across" if spline else
            f"dist [{', '.join(f'{d:.4g}' for d in camera['dist'])}]")
    return (f"{camera['model']} {camera['width']}×{camera['height']} · fx {K[0, 0]:.1f}, fy {K[1, 1]:.1f}, "
            f"cx {K[0, 2]:.1f}, cy {K[1, 2]:.1f} px · {lens}")


def exports_markdown(name: str, camera: CameraIntrinsics) -> str:
    """Which exports carry the lens as solved, said with the result rather than found out at export time."""
    support = camera_exports(name, camera)
    carried = [fmt for fmt, refusal in support.items() if refusal is None]
    lines = [f"Exports that carry this lens: {', '.join(carried)}"]
    lines += [f"- not {fmt}: {refusal}" for fmt, refusal in support.items() if refusal is not None]
    return "\n".join(lines)


def update_markdown(update: rig_service.RigUpdate) -> str:
    """What an accept moves in the rig (each frame against its sigma) and what disagrees (markdown)."""
    lines = []
    for move in update.moves:
        ratio = "" if move.sigma_ratio is None else f" ({move.sigma_ratio:.1f} sigma)"
        lines.append(f"- **{move.frame}** moves {move.trans_m * 1000:.2f} mm, {move.rot_deg:.3f} deg{ratio}")
    if not lines:
        lines.append("- no frame moves")
    for conflict in update.conflicts:
        lines.append(f"- {mark('flagged', 'bad')} {conflict.edge.label} disagrees with the rest by "
                     f"{conflict.disagreement_sigma:.1f} sigma (beyond {rig_service.FLAG_SIGMA:g}) and is left out of "
                     "the tree")
    lines += [f"- {WARNING} {problem}" for problem in update.tree.problems() if "not connected" in problem]
    return "\n".join(lines)


def card_markdown(record: dict[str, Any], accepted_id: str | None) -> str:
    """The card of any stored result (markdown)."""
    result = StoredResult(record)
    status = mark("accepted", "good") if result.id == accepted_id else "not accepted"
    converged = "" if result.converged else f" · {mark('not converged', 'bad')}: it cannot be accepted"
    method = f" · {result.method}" if result.method else ""
    lines = [f"**{result.id}** ({status}) · {result.kind}{method} · {result.seconds:.2f} s{converged}",
             verdict_markdown(result.verdict)]
    if result.camera is not None:
        lines.append(_intrinsics_markdown(result.camera))
        lines.append(exports_markdown(record["sensor"], CameraIntrinsics.from_dict(result.camera)))
    if result.rms_px is not None:
        lines.append(f"reprojection RMS **{result.rms_px:.3f} px**")
    for transform in result.transforms:
        lines.append(transform_markdown(transform))
        if statistics := residuals_markdown(transform.residuals):
            lines.append(statistics)
    if not result.transforms and (statistics := residuals_markdown(result.residuals)):
        lines.append(statistics)
    lines += [f"{WARNING} {warning}" for warning in result.warnings]
    return "\n\n".join(lines)


class ResultCard:
    """The card, its confirmation box and *Accept*; built inside the step's gui folder."""

    def __init__(self, ctx: StudioContext, on_accepted: Callable[[str], None] | None = None,
                 empty_text: str = "No result yet."):
        gui = ctx.server.gui
        self.ctx = ctx
        self.on_accepted = on_accepted
        self.empty_text = empty_text
        self.text = gui.add_markdown(empty_text)
        self.confirm = ConfirmCheck(gui)
        self.revert_choice = gui.add_dropdown(
            "If it disagrees", options=[KEEP_BOTH], visible=False,
            hint="keep this result over an accepted one it disagrees with: that one is reverted in the same step")
        self.accept_button = gui.add_button("Accept", disabled=True, hint="shows what accepting would move in the "
                                            "rig; nothing is written until *Confirm accept*")
        self.preview_text = gui.add_markdown("")
        self.apply_button = gui.add_button("Confirm accept", visible=False)
        self.accept_button.on_click(lambda _: self.preview())
        self.apply_button.on_click(lambda _: self.accept())
        self.record: dict[str, Any] | None = None
        self._previewed: str | None = None

    def show(self, record: dict[str, Any] | None, accepted_id: str | None) -> None:
        """Show ``record`` (None: nothing yet); ``accepted_id`` is the result its slot holds now."""
        self.record = record
        self._previewed = None
        self.apply_button.visible = False
        self.preview_text.content = ""
        self.revert_choice.visible = False
        self.confirm.show_for(None if record is None else StoredResult(record).verdict.level)
        self.accept_button.disabled = record is None  # nothing to accept yet
        self.text.content = self.empty_text if record is None else card_markdown(record, accepted_id)

    def preview(self) -> None:
        """*Accept*: what accepting the shown result would move and what it disagrees with; *Confirm accept* shows
        unless its verdict refuses it (then the preview says why)."""
        record = self._current()
        if record is None:
            return
        try:
            update = rig_service.preview(self.ctx.session, record["id"])
        except InputError as exc:
            self.ctx.notify("Cannot accept", exc.message, error=True)
            return
        others = [c.edge.slot for c in update.conflicts if c.edge.slot is not None and c.edge.result_id != record["id"]]
        self.revert_choice.options = [KEEP_BOTH, *dict.fromkeys(others)]
        self.revert_choice.value = KEEP_BOTH
        verdict = StoredResult(record).verdict
        refused = verdict.level == "reject"
        self.revert_choice.visible = bool(others) and not refused
        self._previewed = None if refused else record["id"]
        self.apply_button.visible = not refused
        tail = (f"It cannot be accepted: its verdict is reject ({'; '.join(verdict.reasons) or 'no reason given'})."
                if refused else "Click *Confirm accept* to make it current.")
        self.preview_text.content = f"**Accepting {record['id']} would:**\n\n{update_markdown(update)}\n\n{tail}"

    def accept(self) -> None:
        """*Confirm accept*: accept the previewed result, with the chosen revert."""
        session, record = self.ctx.session, self._current()
        if session is None or record is None or self._previewed != record["id"]:
            return
        try:
            revert = [] if self.revert_choice.value == KEEP_BOTH else [self.revert_choice.value]
            update = rig_service.accept(session, record["id"], confirm=self.confirm.take(), revert=revert)
        except InputError as exc:
            self.ctx.notify("Cannot accept", exc.message, error=True)
            return
        self.ctx.notify("Accepted", f"{record['id']} is accepted; the rig was re-fitted.")
        self.ctx.rig_changed()
        self.show(record, record["id"])
        self.preview_text.content = "**Accepted.**\n\n" + update_markdown(update)
        if self.on_accepted is not None:
            self.on_accepted(record["id"])

    def _current(self) -> dict[str, Any] | None:
        """The shown record, or None (and a toast) when there is no session or no result."""
        if self.ctx.session is None or self.record is None:
            self.ctx.notify("Nothing to accept", "Solve first, or pick a result.", error=True)
            return None
        return self.record
