"""Step 3: camera intrinsics - live capture with coverage guidance, solve, inspect, accept, export."""

from __future__ import annotations

import time

import numpy as np

from backend.calib._session import session_board
from backend.calib.intrinsics import service as intrinsics_service
from backend.calib.intrinsics.service import IntrinsicsSettings
from backend.calib.rig import service as rig_service
from backend.core.camera import DIST_NAMES
from backend.core.errors import InputError
from backend.plots.board import live_view
from backend.plots.intrinsics import projection_maps, view_rms_bars
from backend.plots.render import PANEL_WIDTH_PX, to_rgb
from backend.services.demo import BOARD_MOTIONS, move_simulated_board, simulated_board_motion
from backend.services.live_capture import (
    PARAM_NAMES,
    Coverage,
    LiveCallbacks,
    LiveCapture,
    LiveFrame,
    coverage_from_captures,
    data_enough,
    last_capture,
)
from backend.store.schema import CaptureRecord
from studio.context import StudioContext
from studio.job_panel import JobPanel
from studio.live_toggle import LiveToggle
from studio.marks import WARNING, mark
from studio.result_card import ResultCard
from studio.wizard.exterior_panel import ExteriorPanel

NO_CAMERA = "(no camera)"
RMS_PLOT_WIDTH_IN = 5.0
"""The per-view RMS plot's width as drawn (in): the report's 7 in would shrink its labels in the panel."""
NO_MAPS = np.full((270, PANEL_WIDTH_PX, 3), 255, np.uint8)
"""The projection-maps image before a result (blank)."""
STEP = "intrinsics"
AUTO_FOR = {"any export": "any", "camera_info (ROS)": "camera_info", "Kalibr": "kalibr"}
"""*Auto: for the export*: what the dropdown says, what ``IntrinsicsSettings.auto_for`` takes."""
"""The step's layer group in the 3D view (the boards it draws)."""
GUIDANCE = (
    "Hold the board still, then move it: **left ↔ right**, **top ↔ bottom**, **near ↔ far**, and "
    "**tilt** it 20–40° in each direction. A frame is kept automatically when it adds coverage; the green tint "
    "shows where corners have been seen - aim to tint the whole image, corners included."
)


class IntrinsicsStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self.live: LiveCapture | None = None
        self._last_preview = 0.0
        gui = ctx.server.gui
        with gui.add_folder("3 · Camera intrinsics"):
            self.camera = gui.add_dropdown("Camera", options=[NO_CAMERA])
            gui.add_markdown(GUIDANCE)
            with gui.add_folder("Capture"):
                self.wave_button = gui.add_button("Wave the board in front of it (simulation)", visible=False,
                                                  hint="the simulated person carries the board about the yard for "
                                                       "the rig (steps 6, 7): have them wave it close, all over the "
                                                       "image, as a lens calibration needs")
                self.start_button = gui.add_button("Start live capture", color="green")
                self.stop_button = gui.add_button("Stop", color="red", visible=False)
                self.toggle = LiveToggle(self.start_button, self.stop_button, on_ended=self._on_ended)
                self.auto = gui.add_checkbox("Auto-capture when it adds coverage", initial_value=True)
                self.capture_button = gui.add_button("Capture this frame")
                self.import_button = gui.add_upload_button("Import an image file", mime_type="image/*",
                                                           hint="add a photo of the board taken elsewhere")
                self.preview = gui.add_image(np.full((270, 480, 3), 40, np.uint8), label="Live", format="jpeg")
                self.bars = {name: gui.add_progress_bar(0.0, color="teal") for name in PARAM_NAMES}
                self.coverage_text = gui.add_markdown("No views yet.")
            with gui.add_folder("Solve"):
                self.model = gui.add_dropdown("Model", options=["pinhole-radtan", "fisheye-equidistant",
                                                                "photogrammetric", "splined-stereographic", "auto"],
                                              hint="photogrammetric: c, xp, yp, K1-K3, P1, P2 and the affine A1, A2 "
                                                   "(not for ROS); splined-stereographic: mrcal's splined model for "
                                                   "wide and fisheye lenses (camera JSON only); auto: compare the lens "
                                                   "models on held-out views, solve with the recommended one")
                self.spline_knots = gui.add_vector2("Spline knots (0: from the views)", initial_value=(0, 0),
                                                    min=(0, 0), max=(40, 40), step=1, visible=False,
                                                    hint="knots across and down; 0 lets the solve choose them")
                self.spline_fov = gui.add_number("Spline field across (°, 0: from the views)", initial_value=0.0,
                                                 min=0.0, max=359.0, step=1.0, visible=False,
                                                 hint="the field of view across that the knots span")
                self.pixel_size = gui.add_number("Pixel size (µm, 0: unknown)", initial_value=0.0, min=0.0,
                                                 max=100.0, step=0.01, visible=False,
                                                 hint="the photogrammetric parameters are then given in mm too")
                self.auto_for = gui.add_dropdown("Auto: for the export", options=list(AUTO_FOR), visible=False,
                                                 hint="choose only among the lens models this export can carry "
                                                      "(Kalibr: no k3)")
                self.k3 = gui.add_checkbox("Estimate k3", initial_value=False)
                self.tangential = gui.add_checkbox("Estimate p1, p2", initial_value=True)
                self.fix_aspect = gui.add_checkbox("Fix aspect (fx = fy)", initial_value=False)
                self.board_flex = gui.add_checkbox("Solve the board's flex", initial_value=True,
                                                   hint="mrcal's calobject_warp: the board's bow, solved with the lens")
                self.reject_corners = gui.add_checkbox("Reject outlier corners", initial_value=True)
                self.drop_outliers = gui.add_checkbox("Drop outlier views and re-solve", initial_value=False)
                self.solve_button = gui.add_button("Solve", color="blue")
                self.jobs = JobPanel(ctx, [self.solve_button], cancel_label="Cancel solve")
            with gui.add_folder("Result"):
                self.history = gui.add_dropdown("History", options=["(none)"],
                                                hint="every solve of this camera; accepting an older one reverts")
                self.card = ResultCard(ctx)
                self.parameters_text = gui.add_markdown("")
                self.checks_text = gui.add_markdown("")
                self.rms_plot = gui.add_image(to_rgb(view_rms_bars("", None, RMS_PLOT_WIDTH_IN)), label="Per-view RMS")
                self.uncertainty_plot = gui.add_image(NO_MAPS, label="Projection σ and cross-validation (px)")
            with gui.add_folder("Export"):
                self.export_ros = gui.add_button("Download ROS camera_info YAML")
                self.export_opencv = gui.add_button("Download OpenCV YAML")
                self.export_json = gui.add_button("Download camera JSON", hint="any model, the photogrammetric one "
                                                  "included, with its sigmas and correlations")
                self.export_rig = gui.add_button("Download rig transforms YAML")
            self.exterior = ExteriorPanel(ctx)

        self.camera.on_update(lambda _: self._select_camera())
        self.start_button.on_click(ctx.after_switch(self._start_live))
        self.stop_button.on_click(lambda _: self.stop_live())
        self.auto.on_update(lambda _: setattr(self.live, "auto_capture", self.auto.value) if self.live else None)
        self.capture_button.on_click(lambda _: self._capture_now())
        self.import_button.on_upload(lambda _: self._import(self.import_button.value))
        self.solve_button.on_click(lambda _: self._solve())
        self.wave_button.on_click(lambda _: self._wave_board())
        self.model.on_update(lambda _: self._model_chosen())
        self.history.on_update(lambda _: self._show_result(self.history.value))
        self.export_ros.on_click(lambda event: self.ctx.download(event, "camera_info", self.sensor))
        self.export_opencv.on_click(lambda event: self.ctx.download(event, "opencv", self.sensor))
        self.export_json.on_click(lambda event: self.ctx.download(event, "camera-json", self.sensor))
        self.export_rig.on_click(lambda event: self.ctx.download(event, "rig", self.sensor))
        ctx.on_session_closing(self.stop_live)
        ctx.on_session_changed(self._on_session)

    # -- session and camera -------------------------------------------------------------
    def _on_session(self, session) -> None:
        cameras = [f.name for f in session.rig.sensors("camera")] or [NO_CAMERA]
        self.camera.options = cameras
        if self.camera.value not in cameras:
            self.camera.value = cameras[0]
        self._select_camera()

    @property
    def sensor(self) -> str | None:
        return None if self.camera.value == NO_CAMERA or self.ctx.session is None else self.camera.value

    def _select_camera(self) -> None:
        self.stop_live()
        session, sensor = self.ctx.session, self.sensor
        board, no_board = None, ""
        try:
            board = None if sensor is None else session_board(session)
        except InputError as exc:  # a session made without a board (the API allows it): step 1 sets one
            no_board = f"\n\n{WARNING} {exc.message} in step 1."
        coverage = None if board is None else coverage_from_captures(session, sensor, board)
        self._show_coverage(coverage)
        self.coverage_text.content += no_board
        last = None if sensor is None else last_capture(session, sensor)
        if last is not None:
            image, detection = last
            detection = detection if board is not None else None
            self.preview.image = live_view(image, board, detection, coverage.heatmap if coverage else None)
            self.ctx.scene.show_camera_image(sensor, image)
        else:  # not the previous camera's (or session's) last frame
            self.preview.image = np.full((270, 480, 3), 40, np.uint8)
        self.wave_button.visible = sensor is not None and simulated_board_motion(session, sensor) in ("scene",
                                                                                                     "carried")
        results = [] if sensor is None else session.results(sensor, "intrinsics")
        self.history.options = [r["id"] for r in reversed(results)] or ["(none)"]
        self.history.value = self._accepted(results) or self.history.options[0]
        self._show_result(self.history.value)
        self.exterior.show(sensor)

    def _wave_board(self) -> None:
        """Simulation only: the person waves the board close in front of the camera (its device's motion)."""
        self.stop_live()
        try:
            move_simulated_board(self.ctx.session, self.sensor, "wave")
        except InputError as exc:
            self.ctx.notify("Cannot move the simulated board", exc.message, error=True)
            return
        self.wave_button.visible = False
        self.coverage_text.content = (f"The board is now {BOARD_MOTIONS['wave']}: *Start live capture*. Step 7 "
                                      f"puts it back in the yard for the rig.\n\n" + self._coverage_summary())
        self.ctx.rig_changed()

    # -- live capture ---------------------------------------------------------------------
    def _start_live(self) -> None:
        if self.sensor is None:
            self.ctx.notify("No camera", "Add a camera in step 2 first.", error=True)
            return
        self.ctx.show_step(STEP)
        self.stop_live()
        live: LiveCapture | None = None

        def current(callback):
            """``callback`` for this capture while it is the live one: a stopped capture's last frame (its thread can
            outlive ``stop``'s wait on a loaded machine) never lands in another camera's or session's panel."""
            return lambda *args: callback(*args) if live is not None and self.live is live else None

        try:
            live = LiveCapture(self.ctx.session, self.sensor, LiveCallbacks(
                frame=current(self._on_frame), captured=current(self._on_captured), status=current(self._on_status)),
                auto_capture=self.auto.value)
        except InputError as exc:
            self.ctx.notify("Cannot start", exc.message, error=True)
            return
        self.live = live
        live.start()
        self.toggle.started([live])

    def stop_live(self) -> None:
        """Stop the live capture, if any, and show Start."""
        live, self.live = self.live, None
        self.toggle.stopped()
        if live is not None:
            live.stop()
            self.ctx.scene.clear_boards("intrinsics", live=True)

    def _on_ended(self, run: tuple) -> None:
        """The live capture ended by itself (it failed to open, or its device went away): it is no longer live."""
        if self.live in run:
            self.live = None
            self.ctx.scene.clear_boards("intrinsics", live=True)

    def _capture_now(self) -> None:
        if self.live is None:
            self.ctx.notify("Not live", "Start live capture first.", error=True)
        else:
            self.live.capture_now()

    def _import(self, upload) -> None:
        """Add an uploaded image as a capture; a corrupt file or a missing board is reported by name."""
        if self.sensor is None:
            self.ctx.notify("No camera", "Pick a camera first.", error=True)
            return
        try:
            report = intrinsics_service.import_images(self.ctx.session, self.sensor, [(upload.name, upload.content)])
        except InputError as exc:
            self.ctx.notify("Image not added", exc.message, error=True)
            return
        self.ctx.notify("Image added", f"{upload.name} is capture {report.added[0].id} of {self.sensor}.")
        self._select_camera()

    def _on_frame(self, frame: LiveFrame) -> None:
        now = time.monotonic()
        if now - self._last_preview < 0.1:  # 10 Hz is plenty for the panel and keeps the socket free
            return
        self._last_preview = now
        board = self.live.board if self.live else session_board(self.ctx.session)
        heatmap = frame.coverage.heatmap if frame.coverage else None
        self.preview.image = live_view(frame.image, board, frame.detection, heatmap)
        self.ctx.scene.show_camera_image(self.sensor, frame.image)
        if frame.T_camera_board is not None:
            self.ctx.scene.show_boards("intrinsics", self.ctx.session.rig, self.sensor, board,
                                       [frame.T_camera_board], live=True)

    def _on_captured(self, record: CaptureRecord, coverage: Coverage) -> None:
        self._show_coverage(coverage)
        self.exterior.list_images()

    def _on_status(self, message: str, error: bool) -> None:
        self.coverage_text.content = f"{WARNING + ' ' if error else ''}{message}\n\n" + self._coverage_summary()
        if error:
            self.ctx.notify("Capture", message, error=True)

    def _coverage_summary(self, coverage: Coverage | None = None) -> str:
        coverage = coverage or (self.live.coverage if self.live else None)
        if coverage is None:
            return "No views yet."
        latest = self.ctx.session.results(self.sensor, "intrinsics")[-1:] if self.sensor else []
        enough, missing = data_enough(self.ctx.session, self.sensor, coverage)
        state = (f"{mark('Enough data', 'good')} - full coverage and the last solve's projection σ is within "
                 "tolerance."
                 if enough else "Not enough data yet: " + "; ".join(missing) + ".")
        solved = f" (last solve: {latest[0]['id']})" if latest else ""
        return (f"**{len(coverage.params)} views** · {coverage.cells_seen:.0%} of the image seen by corners · "
                f"{state}{solved}")

    def _show_coverage(self, coverage: Coverage | None) -> None:
        progress = coverage.progress if coverage else dict.fromkeys(PARAM_NAMES, 0.0)
        for name, bar in self.bars.items():
            bar.value = 100.0 * progress[name]
            bar.color = "green" if progress[name] >= 1.0 else "teal"
        labels = " · ".join(f"{name.upper()} {progress[name]:.0%}" for name in PARAM_NAMES)
        self.coverage_text.content = f"{labels}\n\n{self._coverage_summary(coverage)}"

    # -- solve ------------------------------------------------------------------------------
    def _settings(self) -> IntrinsicsSettings:
        return IntrinsicsSettings(model=self.model.value, auto_for=AUTO_FOR[self.auto_for.value],
                                  estimate_k3=self.k3.value,
                                  estimate_tangential=self.tangential.value, fix_aspect=self.fix_aspect.value,
                                  drop_outliers=self.drop_outliers.value, board_flex=self.board_flex.value,
                                  reject_corners=self.reject_corners.value,
                                  pixel_size_um=float(self.pixel_size.value) or None,
                                  spline_knots=(tuple(int(k) for k in self.spline_knots.value)
                                                if all(self.spline_knots.value) else None),
                                  spline_fov_x_deg=float(self.spline_fov.value) or None)

    def _model_chosen(self) -> None:
        """Show the options of the chosen model: the photogrammetric model always estimates its ten parameters."""
        self.auto_for.visible = self.model.value == "auto"
        self.pixel_size.visible = self.model.value in ("photogrammetric", "auto")
        self.spline_knots.visible = self.spline_fov.visible = self.model.value == "splined-stereographic"
        for option in (self.k3, self.tangential, self.fix_aspect):
            option.visible = self.model.value not in ("photogrammetric", "splined-stereographic")
        self.board_flex.visible = self.model.value != "photogrammetric"

    def _solve(self) -> None:
        session, sensor = self.ctx.session, self.sensor
        if sensor is None:
            self.ctx.notify("No camera", "Pick a camera first.", error=True)
            return
        settings = self._settings()
        self.ctx.show_step(STEP)
        self.jobs.run(f"intrinsics of {sensor}",
                      lambda progress: intrinsics_service.solve_session(session, sensor, settings,
                                                                        progress=progress)[0],
                      self._solved, done_message="Solved in {seconds:.2f} s.")

    def _solved(self, result_id: str) -> None:
        self.history.options = [r["id"] for r in reversed(self.ctx.session.results(self.sensor, "intrinsics"))]
        self.history.value = result_id
        self._show_result(result_id)
        self._show_coverage(self.live.coverage if self.live else coverage_from_captures(
            self.ctx.session, self.sensor, session_board(self.ctx.session)))

    def _show_result(self, result_id: str) -> None:
        session = self.ctx.session
        if session is None or result_id in (None, "(none)"):
            # Nothing solved for this camera: drop the previous camera's plots and boards too.
            self.card.show(None, None)
            self.parameters_text.content = ""
            self.checks_text.content = ""
            self.rms_plot.image = to_rgb(view_rms_bars("", None, RMS_PLOT_WIDTH_IN))
            self.uncertainty_plot.image = NO_MAPS
            self.ctx.scene.clear_boards("intrinsics")
            return
        record = session.result(result_id)
        self.card.show(record, self._accepted([record]))
        self.parameters_text.content = parameters_markdown(record)
        self.checks_text.content = checks_markdown(record)
        views = record["views"]
        self.rms_plot.image = to_rgb(view_rms_bars(self.sensor, record, RMS_PLOT_WIDTH_IN))
        maps = projection_maps(record)
        self.uncertainty_plot.image = to_rgb(maps) if maps else NO_MAPS
        board = session_board(session)
        poses = [np.array(v["T_camera_board"]) for v in views if v["used"] and v["T_camera_board"]]
        self.ctx.scene.show_boards("intrinsics", session.rig, self.sensor, board, poses)

    def _accepted(self, results: list[dict]) -> str | None:
        """The result the camera's intrinsics slot holds (every intrinsics result of one camera fills the same)."""
        return self.ctx.session.accepted(rig_service.slot_of(results[-1])) if results else None


def parameters_markdown(record: dict) -> str:
    """Beside the result card: each parameter with its 1-sigma, strong correlations, outliers and the projection
    uncertainty."""
    camera, std = record["camera"], record["std"]
    K = camera["K"]
    if "photogrammetric" in record:
        table = photogrammetric_markdown(record["photogrammetric"])
    elif "splined" in record:
        table = splined_markdown(record["splined"], K)
    else:
        rows = [("fx", K[0][0], std["fx"]), ("fy", K[1][1], std["fy"]), ("cx", K[0][2], std["cx"]),
                ("cy", K[1][2], std["cy"])]
        rows += list(zip(DIST_NAMES[camera["model"]], camera["dist"], std["dist"], strict=True))
        table = "| param | value | σ |\n|---|---|---|\n" + "\n".join(f"| {n} | {v:.6g} | {s:.2g} |" for n, v, s in rows)
    corr = record["correlation"]
    matrix = np.array(corr["matrix"])
    strong = [f"{corr['names'][i]}–{corr['names'][j]} {matrix[i, j]:+.2f}"
              for i in range(len(matrix)) for j in range(i + 1, len(matrix)) if abs(matrix[i, j]) > 0.9]
    used = sum(v["used"] for v in record["views"])
    outliers = [v["image"] for v in record["views"] if v["outlier"]]
    rejected = [f"{v['image']} {len(v['rejected']['ids'])}" + (" (view dropped)" if v["rejected"]["view_dropped"]
                                                               else "")
                for v in record["views"] if v.get("rejected")]
    unc = record["projection_uncertainty"]
    reach = (f"worst {unc['max_covered_px']:.3f} px where the boards reach ({unc['covered_share']:.0%} of the "
             "image), " if unc.get("max_covered_px") is not None else "")
    return (
        f"{used} views used\n\n{table}\n\n"
        f"Strong correlations: {', '.join(strong) or 'none above 0.9'}\n\n"
        f"Outlier views: {', '.join(outliers) or 'none'}\n\n"
        f"Corners rejected as outliers: {', '.join(rejected) or 'none'}\n\n"
        f"Board flex: {flex_phrase(record.get('board_flex'))}\n\n"
        f"Projection σ (far points, mrcal's noise model): {reach}mean {unc['mean_px']:.3f} px, "
        f"max {unc['max_px']:.3f} px"
    )


def flex_phrase(flex: dict | None) -> str:
    """The board's bow as a result gives it (``board_flex``), in mm with its sigma, or why it was not solved."""
    if flex is None:
        return "not solved (an older result)"
    if flex["status"] != "solved":
        return f"{flex['status']}: {flex['detail']}"
    (x, y), (sx, sy) = flex["warp_mm"], flex["std_mm"]
    return f"x {x:+.3f} ± {sx:.3f} mm, y {y:+.3f} ± {sy:.3f} mm"


def splined_markdown(block: dict, K: list[list[float]]) -> str:
    """The splined model: its knots and field, fx, fy, cx, cy (held), where no corner reaches, and the OpenCV model
    fitted to it."""
    opencv = block["opencv"]
    grid = "\n".join(f"    {row}" for row in block["unconstrained_map"])
    return (f"mrcal's model:\n\n    {block['lensmodel']}\n\n"
            f"{block['knots'][0]}×{block['knots'][1]} knots over {block['fov_x_deg']:g}° "
            f"across, {block['spline_values']} spline values, {block['measurements_per_value']:g} measurements each. "
            f"fx {K[0][0]:.2f}, fy {K[1][1]:.2f}, cx {K[0][2]:.2f}, cy {K[1][2]:.2f} px (held, as mrcal holds them)."
            f"\n\nKnots (# reached by corners, . under the image but unreached):\n\n{grid}\n\n{block['detail']}."
            "\n\nAs OpenCV's pinhole-radtan (for exports that cannot carry the spline; fitted at the views' "
            f"corners): within {opencv['max_residual_px']:.3g} px there (RMS {opencv['rms_residual_px']:.3g} px; its "
            f"frame turned {opencv['rotation_deg']:.2f}°), {opencv['max_residual_over_image_px']:.3g} px over the "
            f"{opencv['image_share_inverting']:.0%} of the image where it inverts")


def photogrammetric_markdown(block: dict) -> str:
    """The photogrammetric parameters in px and (with the pixel size) mm, with sigmas, and the largest correlation
    of each interior parameter with a view's exterior orientation."""
    in_mm = block["pixel_size_um"] is not None
    header = "| param | in px | σ |" + (" in mm | σ |" if in_mm else "")
    rows = [header, "|---|---|---|" + ("---|---|" if in_mm else "")]
    for name, p in block["parameters"].items():
        mm = f" {p['value_mm']:.6g} {_unit(p['unit_mm'])} | {p['sigma_mm']:.2g} |" if in_mm else ""
        rows.append(f"| {name} | {p['value_px']:.6g} {_unit(p['unit_px'])} | {p['sigma_px']:.2g} |{mm}")
    if in_mm:
        rows.append(f"\nPixel size {block['pixel_size_um']:g} µm; in mm, xp and yp are from the image centre.")
    cross = block["interior_exterior"]
    largest = np.array(cross["largest"])
    pairs = [f"{cross['interior'][i]}–{cross['exterior'][j]} {largest[i, j]:+.2f}"
             for i, j in zip(*np.nonzero(np.abs(largest) > 0.9), strict=True)]
    conversion = block["opencv"]
    return ("\n".join(rows) + f"\n\nInterior–exterior correlations above 0.9 (largest over the views): "
            f"{', '.join(pairs) or 'none'}\n\nAs OpenCV's pinhole-radtan: "
            f"{'exact' if conversion['exact'] else 'within ' + format(conversion['max_residual_px'], '.3g') + ' px'}")


def _unit(unit: str) -> str:
    """A unit as the report's JSON spells it (``px^-2``, ``1``) written for reading (px⁻², none)."""
    return "" if unit == "1" else unit.replace("^-", "⁻").translate(str.maketrans("1246", "¹²⁴⁶"))


def checks_markdown(record: dict) -> str:
    """The corner set solved with, the two-halves cross-validation and (``auto``) the model comparison."""
    lines = []
    corners = record.get("corners")
    if corners and corners.get("rms_px"):
        fits = ", ".join(f"{name} {rms:.3f} px" for name, rms in corners["rms_px"].items())
        lines.append(f"**Corners:** {corners['chosen']} (fit on these views: {fits})")
    cv = record.get("cross_validation")
    if cv:
        lines.append(f"**Cross-validation (two halves):** {cv['status']}: {cv['detail']}")
    comparison = record.get("model_comparison")
    if comparison:
        lines.append(f"**Model:** {comparison['reason']}")
        if comparison["candidates"]:
            rows = "\n".join(
                f"| {c['model']}{' ' + mark('recommended', 'good') if c.get('recommended') else ''} | "
                f"{'—' if c['n_dist'] is None else c['n_dist']} | "
                f"{'—' if c['held_out_rms_px'] is None else format(c['held_out_rms_px'], '.3f')} |"
                for c in comparison["candidates"])
            lines.append(f"| model | dist coeffs | held-out RMS (px) |\n|---|---|---|\n{rows}")
    return "\n\n".join(lines)
