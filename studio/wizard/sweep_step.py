"""Step 5: the swept scanner - capture a sweep, calibrate its geometry, inspect, accept.

A 2D scanner on a servo gives one 3D cloud per sweep (:mod:`backend.core.sweep_geometry`). Its
geometry (the optical centre's offset from the servo axis, the scanner's tilt on the
horn, the servo's zero) decides how flat walls and floor come out. The step captures a
sweep as a background job, draws it in the step's layer (``/steps/sweep/<sensor>/cloud``)
coloured by height, calibrates the geometry (a job, cancellable), and redraws the same sweep
and its LiDAR image with whichever result is picked, so the user sees the planes sharpen
before accepting. The result card (:class:`~studio.result_card.ResultCard`) shows the scanner's pose at
servo zero with its sigma and the verdict, and accepts through the rig service, which writes the
geometry into the sensor's device (not a rig edge); accepting an older result reverts. The
geometry panel beside it holds the sweep's own numbers.

Its *Board corners → camera* panel (:class:`~studio.wizard.sweep_corners_panel.SweepCornersPanel`) solves a camera
from the board's corners in the scanner's intensity image, and a camera's pan axis, from the session's image + sweep
pairs; its coloured sweep takes the place of the height-coloured one while shown.
"""

from __future__ import annotations

import cv2
import numpy as np

from backend.calib.rig import service as rig_service
from backend.calib.sweep import service as sweep_service
from backend.calib.sweep.service import LABELS, SweepCalibrationSettings
from backend.core.errors import InputError
from backend.core.sweep_geometry import SweepGeometry
from backend.core.transforms import to_xyz_ypr, transform_points
from studio import cloud_colours as cc
from studio.context import StudioContext
from studio.job_panel import JobPanel
from studio.result_card import ResultCard
from studio.result_history import ResultHistory
from studio.wizard.sweep_corners_panel import SweepCornersPanel

NONE = "(no swept scanner)"
STEP = "sweep"
"""The step's layer group in the 3D view (:meth:`studio.scene.RigScene.group`): the sweep drawn in the root
frame under ``<group>/<sensor>/cloud``."""
POINT_SIZE_M = 0.02
HELP = ("Keep the rig still where the scanner sees the **floor** and two or three **walls** or other large flat "
        "surfaces at different angles. **Capture sweep** turns the servo once through its range (a few seconds), "
        "then **Calibrate** makes those surfaces flat. The floor, level with `base_link`, fixes the servo's zero.")
BLANK_IMAGE = np.full((90, 480, 3), 235, np.uint8)


class SweepStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self._cloud = None
        self._T_root_mount: np.ndarray | None = None
        """The sensor's pose in the root frame the drawn cloud was placed with (m)."""
        gui = ctx.server.gui
        with gui.add_folder("5 · Swept scanner", expand_by_default=False):
            gui.add_markdown(HELP)
            self.sensor = gui.add_dropdown("Swept scanner", options=[NONE])
            self.capture_button = gui.add_button("Capture sweep", color="green")
            self.capture_jobs = JobPanel(ctx, [self.capture_button])
            self.captures_text = gui.add_markdown("")
            self.estimate_tilt = gui.add_checkbox("Estimate the scanner's tilt", initial_value=True)
            self.calibrate_button = gui.add_button("Calibrate", color="blue")
            self.jobs = JobPanel(ctx, [self.capture_button, self.calibrate_button])
            self.capture_jobs.also_disable(self.calibrate_button)
            self.history = ResultHistory(gui, lambda _: self._pick(),
                                         hint="every calibration of this scanner; the sweep is redrawn with it")
            self.card = ResultCard(ctx, empty_text="No sweep calibration yet.")
            self.geometry_text = gui.add_markdown("")
            self.image_mode = gui.add_dropdown("Image", options=["intensity", "range"])
            self.image = gui.add_image(BLANK_IMAGE, label="The sweep as a LiDAR image (a row per servo step)")
            self.corners = SweepCornersPanel(ctx, STEP, self._drop_cloud)
        self.sensor.on_update(lambda _: self._select())
        self.capture_button.on_click(lambda _: self._capture())
        self.calibrate_button.on_click(lambda _: self._calibrate())
        self.image_mode.on_update(lambda _: self._draw())
        ctx.on_session_closing(self._drop_cloud)
        ctx.on_session_changed(self._on_session)
        ctx.on_rig_changed(lambda _: self._follow_rig())

    # -- session and sensor --------------------------------------------------------------------
    @property
    def current(self) -> str | None:
        return None if self.ctx.session is None or self.sensor.value == NONE else self.sensor.value

    @property
    def result_id(self) -> str | None:
        return self.history.selected

    def _drop_cloud(self) -> None:
        """Remove the sweep drawn in 3D, if any."""
        if self._cloud is not None:
            self._cloud.remove()
            self._cloud = None
            self._T_root_mount = None

    def _on_session(self, session) -> None:
        swept = [f.name for f in session.rig.sensors() if sweep_service.is_swept(session, f.name)]
        self.sensor.options = swept or [NONE]
        self.sensor.value = self.sensor.options[0]
        self._select()

    def _select(self) -> None:
        session, sensor = self.ctx.session, self.current
        if sensor is None:
            self.captures_text.content = ("No swept scanner in this rig: add one in step 2, *Sensors* "
                                          "(device swept_scanner).")
            self._show_history(None)
            self.corners.show(None)
            return
        captures = sweep_service.swept_captures(session, sensor)
        self.captures_text.content = (f"{len(captures)} sweep(s) captured; the latest, {captures[-1].id}, is used."
                                      if captures else "No sweep captured yet.")
        self._show_history(self._accepted())
        self.corners.show(sensor)

    def _results(self) -> list[dict]:
        """The current scanner's stored sweep results, oldest first."""
        sensor = self.current
        return [] if sensor is None else self.ctx.session.results(sensor, sweep_service.KIND)

    def _accepted(self) -> str | None:
        """The result the scanner's acceptance slot holds (every sweep result of one scanner fills the same)."""
        results = self._results()
        return self.ctx.session.accepted(rig_service.slot_of(results[-1])) if results else None

    def _show_history(self, result_id: str | None) -> None:
        """Fill the result dropdown (newest first) and show ``result_id`` (or the newest)."""
        self.history.fill([r["id"] for r in reversed(self._results())], result_id)
        self._show()

    # -- jobs --------------------------------------------------------------------------------------
    def _capture(self) -> None:
        session, sensor = self.ctx.session, self.current
        if sensor is None:
            self.ctx.notify("No swept scanner", "Add a sensor with the swept_scanner device first.", error=True)
            return
        self.ctx.show_step(STEP)
        self.capture_jobs.run(f"Sweep of {sensor}", lambda progress: sweep_service.capture_sweep(session, sensor,
                                                                                                 progress),
                              lambda record: self._select(), done_message="{title}: captured in {seconds:.1f} s.")

    def _calibrate(self) -> None:
        session, sensor = self.ctx.session, self.current
        if sensor is None:
            return
        settings = SweepCalibrationSettings(estimate_tilt=bool(self.estimate_tilt.value))
        self.ctx.show_step(STEP)
        self.jobs.run(f"Sweep geometry of {sensor}", lambda progress: sweep_service.solve_session(
            session, sensor, settings=settings, progress=progress), self._show_history)

    # -- showing a sweep and a result --------------------------------------------------------------
    def _pick(self) -> None:
        """The user picked a result: this step's layer comes into view, drawn with it."""
        self.ctx.show_step(STEP)
        self._show()

    def _follow_rig(self) -> None:
        """An accept or a revert re-fitted the rig: redraw the sweep if its sensor moved."""
        sensor = self.current
        if self._T_root_mount is not None and sensor is not None and not np.allclose(
                self.ctx.session.rig.T_root_frame(sensor), self._T_root_mount, atol=1e-9):
            self._draw()

    def _show(self) -> None:
        """The picked result's card and numbers, and the latest sweep drawn with its geometry."""
        result_id = self.result_id
        record = None if result_id is None else self.ctx.session.result(result_id)
        self.card.show(record, self._accepted())
        self.geometry_text.content = "" if record is None else geometry_markdown(record)
        self._draw()

    def _draw(self) -> None:
        """Redraw the latest sweep (cloud, in the root frame, and image) with the picked result's geometry."""
        session, sensor, result_id = self.ctx.session, self.current, self.result_id
        self._drop_cloud()
        self.corners.drop_cloud()
        if sensor is None or not sweep_service.swept_captures(session, sensor):
            self.image.image = BLANK_IMAGE
            return
        try:
            view = sweep_service.sweep_view(session, sensor, result_id=result_id, mode=self.image_mode.value)
        except InputError as exc:
            self.ctx.notify("Cannot show the sweep", exc.message, error=True)
            return
        self.image.image = cv2.cvtColor(view.image, cv2.COLOR_GRAY2RGB)
        T_root_mount = session.rig.T_root_frame(sensor)
        colours = cc.colour_points("height", view.points_mount, None, T_root_mount, 0)
        self._cloud = self.ctx.server.scene.add_point_cloud(
            f"{self.ctx.scene.group(STEP)}/{sensor}/cloud",
            transform_points(T_root_mount, view.points_mount).astype(np.float32), colours, point_size=POINT_SIZE_M,
            precision="float32")
        self._T_root_mount = T_root_mount


def geometry_markdown(record: dict) -> str:
    """The sweep's own numbers beside the result card: the geometry found (optical centre in the servo frame,
    the scanner's tilt, the servo's zero) with each estimated parameter's 1-sigma, the planes, the flatness."""
    geometry = SweepGeometry.from_dict(record["geometry"])
    centre_m, ypr = to_xyz_ypr(geometry.T_servo_scanner)
    sigmas = " · ".join(
        f"{LABELS[name]} ± " + ("undetermined" if sigma is None else
                                f"{1000 * sigma:.2f} mm" if name.endswith("_m") else f"{np.degrees(sigma):.3f}°")
        for name, sigma in record["parameter_std"].items())
    u, v = (", ".join(f"{c:.2f}" for c in record[k]) for k in ("u", "v"))
    return (
        f"**Sweep geometry** · {record['planes']} planes{'' if record.get('floor_found') else ' (no floor found)'}"
        f" · plane RMS {1000 * record['rms_before_m']:.1f} mm before → **{1000 * record['rms_after_m']:.1f} mm** "
        f"after\n\n"
        f"Optical centre in the servo frame (mm): {', '.join(f'{1000 * c:.1f}' for c in centre_m)} · "
        f"tilt yaw / pitch / roll (°): {', '.join(f'{np.degrees(a):.3f}' for a in ypr)} · "
        f"servo zero offset (°): {np.degrees(geometry.zero_offset_rad):.3f}\n\n"
        f"Estimated (1σ): {sigmas}; the offset along the servo axis and anything else not named is kept "
        f"(u = [{u}], v = [{v}] in the mount frame)"
    )
