"""Step 3's *Pose in the test field* panel: a camera's exterior orientation in the wall's frame.

It works with the session's wall test field (beside the board, or as the board; step 1 sets either). The user
picks one of the camera's images that shows the wall and clicks *Resect this image*, or uploads one (*Resect an
image file*: kept as a capture, the board need not be in it); the camera is posed from the surveyed markers in it
through its intrinsics in the rig (:mod:`backend.calib.test_field.service`). The result is kept in
the session's history (never accepted: the rig holds no wall) and shown here: ``T_wall_camera`` with its 1-sigma,
the photogrammetric X0/Y0/Z0 and omega/phi/kappa, the residuals and the verdict; the surveyed marker centres are
drawn in 3D where that pose puts the wall in front of the camera.
"""

from __future__ import annotations

import numpy as np

from backend.calib._session import session_test_field
from backend.calib.test_field import service as exterior_service
from backend.core.errors import InputError
from backend.core.test_field import TestField
from backend.core.transforms import invert, to_xyz_ypr
from backend.core.verdict import Verdict
from studio.context import StudioContext
from studio.marks import WARNING
from studio.result_history import ResultHistory
from studio.verdict_view import verdict_markdown

NONE = "(none)"
LAYER = "intrinsics"
"""The layer group the posed wall is drawn in (step 3's)."""
HELP = ("The camera's pose in the wall's frame, from the surveyed markers one image shows (spatial resection), "
        "through the camera's intrinsics in the rig: accept them first.")


def exterior_markdown(record: dict) -> str:
    """A stored exterior orientation as the panel shows it (markdown)."""
    T_wall_camera = np.array(record["T_parent_child"])
    xyz, ypr = to_xyz_ypr(T_wall_camera)
    eo = record["diagnostics"]["exterior_orientation"]
    trans_mm = [1000 * v for v in record["std"]["trans_m"]]
    residuals = record["residuals"]
    lines = [
        f"**{record['id']}** · {record['child']} in the wall's frame, from {record['settings']['image']} "
        f"(capture {record['settings']['capture_id']}) through the intrinsics of {record['settings']['intrinsics']}",
        "",
        f"T_wall_camera: {', '.join(f'{v:.4f}' for v in xyz)} m · yaw, pitch, roll "
        f"{', '.join(f'{v:.3f}' for v in np.degrees(ypr))}°  ",
        f"1σ: {', '.join(f'{v:.1f}' for v in trans_mm)} mm · "
        f"{', '.join(f'{v:.3f}' for v in record['std']['rot_deg'])}° about x, y, z  ",
        f"X0, Y0, Z0: {eo['X0_m']:.4f}, {eo['Y0_m']:.4f}, {eo['Z0_m']:.4f} m · ω, φ, κ: {eo['omega_deg']:.3f}, "
        f"{eo['phi_deg']:.3f}, {eo['kappa_deg']:.3f}°  ",
        f"RMS {residuals['rms_px']:.3f} px over {residuals['markers_used']} of {residuals['markers_seen']} markers",
        "",
        verdict_markdown(Verdict.from_record(record)),
    ]
    lines += [f"\n{WARNING} {warning}" for warning in record.get("warnings", [])]
    return "\n".join(lines)


class ExteriorPanel:
    """The panel, built inside step 3's folder; :meth:`show` follows the step's camera."""

    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self.camera: str | None = None
        self._images: dict[str, str] = {}
        """Image label -> capture id."""
        gui = ctx.server.gui
        with gui.add_folder("Pose in the test field", expand_by_default=True):
            gui.add_markdown(HELP)
            self.field_text = gui.add_markdown("")
            self.image = gui.add_dropdown("Wall image", options=[NONE], hint="one of the camera's images that shows "
                                          "the wall's markers")
            self.resect_button = gui.add_button("Resect this image", color="blue")
            self.upload_button = gui.add_upload_button("Resect an image file", mime_type="image/*",
                                                       hint="an image of the wall, kept as the camera's capture")
            self.history = ResultHistory(gui, lambda _: self._show_result(draw=True), label="Exterior result",
                                         hint="every exterior orientation of this camera")
            self.result_text = gui.add_markdown("")
        self.resect_button.on_click(lambda _: self._resect())
        self.upload_button.on_upload(lambda _: self._resect_upload())

    def show(self, camera: str | None) -> None:
        """Follow ``camera`` of the open session (None: no camera)."""
        self.camera = camera
        self.list_images()
        if camera is None:
            self.history.fill([], None)
            self.result_text.content = ""
        else:
            self._fill_history(None, draw=False)

    def list_images(self) -> None:
        """List the camera's images, newest first, and choose the newest known to show the wall (else the newest);
        say which test field a pose would be in."""
        captures = [] if self.camera is None else self.ctx.session.captures(self.camera)[::-1]
        self._images = {f"{c.source or c.id} ({c.id})": c.id for c in captures}
        self.image.options = list(self._images) or [NONE]
        self.image.value = next((label for label, c in zip(self._images, captures, strict=True)
                                 if exterior_service.shows_the_wall(c)), self.image.options[0])
        self._show_field()

    def _show_field(self) -> TestField | None:
        """Say which test field a pose would be in, or why there is none (step 1 may have set it since); returns
        it (None without one)."""
        try:
            test_field = session_test_field(self.ctx.session)
        except InputError as exc:
            self.field_text.content = f"{WARNING} {exc.message}" if self.camera else ""
            return None
        self.field_text.content = f"Test field: `{test_field}`" if self.camera else ""
        return test_field

    def _fill_history(self, result_id: str | None, draw: bool) -> None:
        results = exterior_service.exterior_results(self.ctx.session, self.camera)
        self.history.fill([r["id"] for r in reversed(results)], result_id)
        self._show_result(draw)

    def _resect(self) -> None:
        self._show_field()
        capture_id = self._images.get(self.image.value)
        if self.camera is None or capture_id is None:
            self.ctx.notify("No image", "Capture or import an image of the wall first.", error=True)
            return
        try:
            result_id, _ = exterior_service.resect_capture(self.ctx.session, self.camera, capture_id)
        except InputError as exc:
            self.ctx.notify("Cannot pose the camera", exc.message, error=True)
            return
        self._fill_history(result_id, draw=True)

    def _resect_upload(self) -> None:
        self._show_field()
        upload = self.upload_button.value
        if self.camera is None:
            self.ctx.notify("No camera", "Pick a camera first.", error=True)
            return
        try:
            capture, result_id, _ = exterior_service.resect_upload(self.ctx.session, self.camera, upload.name,
                                                                   upload.content)
        except InputError as exc:
            self.ctx.notify("Cannot pose the camera", exc.message, error=True)
            return
        self.ctx.notify("Image kept", f"{upload.name} is capture {capture.id} of {self.camera}.")
        self.list_images()
        self._fill_history(result_id, draw=True)

    def _show_result(self, draw: bool) -> None:
        """Show the picked result; with ``draw``, also the wall where it puts it in 3D (in place of step 3's
        views, which its own result shows again)."""
        result_id = self.history.selected
        if result_id is None:
            self.result_text.content = "No exterior orientation of this camera yet."
            return
        record = self.ctx.session.result(result_id)
        self.result_text.content = exterior_markdown(record)
        test_field = self._show_field() if draw else None
        if test_field is not None:
            self.ctx.show_step(LAYER)
            self.ctx.scene.show_boards(LAYER, self.ctx.session.rig, self.camera, test_field,
                                       [invert(np.array(record["T_parent_child"]))])
