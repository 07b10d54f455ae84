"""Step 5's *Board corners → camera* panel: the camera from a board's corners in the swept scanner's intensity image,
and a camera on a pan head.

The session's image + sweep pairs (:mod:`backend.calib.lidar_camera.sweep_corners_service`) are listed by the pan
head's reading. *Solve corners* solves ``T_camera_lidar`` by the corners method from the pairs at the chosen
reading, *Solve pan axis* the camera's pose at reading 0 and its axis from every reading; each is a job whose
progress shows beneath, kept in the result history with its verdict. The result card
(:class:`~studio.result_card.ResultCard`) shows the picked result with its sigma and verdict and accepts it into the
rig as the camera's edge; beside it, the corners method's placements or the pan axis and each position's
cross-check. For the chosen placement the panel shows the sweep's intensity image with the board's corners found
marked, and draws the sweep in 3D coloured by the camera's image through the picked result (under the step's layer
group, ``/steps/sweep/<sensor>/coloured``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from backend.calib.lidar_camera import sweep_corners_service as corners_service
from backend.calib.rig import service as rig_service
from backend.core.errors import InputError
from backend.core.result import StoredResult
from backend.core.transforms import transform_points
from studio.context import StudioContext
from studio.job_panel import JobPanel
from studio.marks import WARNING
from studio.result_card import ResultCard
from studio.result_history import ResultHistory

NONE = "(none)"
POINT_SIZE_M = 0.02
BLANK_IMAGE = np.full((90, 480, 3), 235, np.uint8)
HELP = ("The board's corners, found in each sweep's intensity image and in the camera's image, give the camera's "
        "pose. Store image + sweep pairs of the board held still 0.6-0.9 m away (its squares must span three servo "
        "steps), turned every way; with the camera on a pan head, at each of its positions (each image keeps the "
        "head's reading). **Solve corners** solves the camera at the chosen reading, **Solve pan axis** its pose at "
        "reading 0 and the axis, from every reading.")


def pan_label(reading_deg: float, count: int) -> str:
    """How the pan dropdown names a reading: ``+45° (4 pairs)``."""
    return f"{reading_deg:+g}° ({count} pair{'s' if count != 1 else ''})"


def method_markdown(record: dict) -> str:
    """What a corners or pan-axis result holds beside its card: the placements (corners, fit) or the pan axis and
    each position's cross-check (markdown)."""
    transform = StoredResult(record).edges[0]
    diagnostics = transform.diagnostics
    if transform.method == "pan_axis":
        axis = diagnostics["pan_axis"]
        rows = ["| pan | corners | own solve from the axis |", "|---|---|---|"]
        rows += [f"| {p['pan_deg']:+g}° | {p['corners']} | {p['from_prediction_mm']:.1f} mm, "
                 f"{p['from_prediction_deg']:.3f}° ({p['sigmas']:.1f} σ){'' if p['agrees'] else ' ' + WARNING} |"
                 for p in diagnostics["positions"]]
        return (f"**Pan axis** ({transform.child} frame): {', '.join(f'{v:.5f}' for v in axis['axis'])} through "
                f"{', '.join(f'{1000 * v:.1f}' for v in axis['axis_point_m'])} mm · 1σ "
                f"{axis['axis_sigma_deg']:.3f}° and {1000 * axis['axis_point_sigma_m']:.2f} mm\n\n" + "\n".join(rows))
    rows = ["| placement | corners | RMS px | plane mm |", "|---|---|---|---|"]
    rows += [f"| {name} | {p['corners']} | {p['rms_px']:.2f} | {1000 * p['lidar_plane_rms_m']:.1f} |"
             for name, p in diagnostics["placements"].items()]
    return f"**Corners** at pan {diagnostics.get('pan_deg', 0.0):+g}°\n\n" + "\n".join(rows)


class SweepCornersPanel:
    """The panel, built inside step 5's folder; :meth:`show` follows the step's swept scanner."""

    def __init__(self, ctx: StudioContext, step: str, on_coloured: Callable[[], None]):
        """``step``: the layer group the coloured sweep is drawn under; ``on_coloured()`` runs once it is drawn (the
        step drops its own drawing of the sweep)."""
        self.ctx = ctx
        self.step = step
        self.on_coloured = on_coloured
        self.sensor: str | None = None
        self._readings: dict[str, float] = {}
        self._pairs: dict[str, tuple[str, str]] = {}
        """Placement label -> (image capture id, sweep capture id)."""
        self._cloud = None
        gui = ctx.server.gui
        with gui.add_folder("Board corners → camera", expand_by_default=True):
            gui.add_markdown(HELP)
            self.camera = gui.add_dropdown("Paired camera", options=[NONE],
                                           hint="a camera with image + sweep pairs of this scanner")
            self.pan = gui.add_dropdown("Pan reading", options=[NONE], hint="the pairs taken at this reading of the "
                                        "pan head are solved by the corners method")
            self.pairs_text = gui.add_markdown("")
            self.corners_button = gui.add_button("Solve corners", color="blue")
            self.pan_button = gui.add_button("Solve pan axis", color="blue")
            self.jobs = JobPanel(ctx, [self.corners_button, self.pan_button])
            self.history = ResultHistory(gui, lambda _: self._show_result(), label="Corners result",
                                         hint="every corners and pan-axis solve of this scanner")
            self.card = ResultCard(ctx, empty_text="No corners or pan-axis result yet.")
            self.method_text = gui.add_markdown("")
            self.placement = gui.add_dropdown("Placement", options=[NONE], hint="its sweep's corners below, and its "
                                              "sweep coloured by its image in 3D")
            self.placement_text = gui.add_markdown("")
            self.image = gui.add_image(BLANK_IMAGE, label="The board's corners in the sweep's intensity image")
        self._filling = False
        """Set while the panel fills its dropdowns (setting one's value fires its callback)."""
        self.camera.on_update(lambda _: self._filling or self._pick_camera())
        self.pan.on_update(lambda _: self._filling or self._pick_pan())
        self.placement.on_update(lambda _: self._filling or self._draw_placement())
        self.corners_button.on_click(lambda _: self._solve("corners"))
        self.pan_button.on_click(lambda _: self._solve("pan_axis"))
        ctx.on_session_closing(self.drop_cloud)

    def show(self, sensor: str | None) -> None:
        """Follow the swept scanner ``sensor`` of the open session (None: the rig has none)."""
        self.sensor = sensor
        session = self.ctx.session
        cameras = [] if sensor is None else [f.name for f in session.rig.sensors("camera")
                                             if corners_service.sweep_pairs(session, f.name, sensor)]
        self._fill(self.camera, cameras)
        self._pick_camera()

    def drop_cloud(self) -> None:
        """Remove the coloured sweep from the 3D view, if drawn."""
        if self._cloud is not None:
            self._cloud.remove()
            self._cloud = None

    @property
    def _camera(self) -> str | None:
        return None if self.sensor is None or self.camera.value == NONE else self.camera.value

    def _fill(self, dropdown, options: list[str], value: str | None = None) -> None:
        """List ``options`` in ``dropdown`` (``(none)`` when empty) and choose ``value`` (default the first), without
        its callback."""
        self._filling = True
        try:
            dropdown.options = options or [NONE]
            dropdown.value = value if value in options else dropdown.options[0]
        finally:
            self._filling = False

    def _pick_camera(self) -> None:
        """The chosen camera's pan readings (rising; the one nearest 0, the centre, chosen), its pairs there and its
        results, the newest shown."""
        camera = self._camera
        readings = {} if camera is None else corners_service.pan_readings(self.ctx.session, camera, self.sensor)
        self._readings = {pan_label(r, n): r for r, n in readings.items()}
        self._fill(self.pan, list(self._readings),
                   min(self._readings, key=lambda label: abs(self._readings[label]), default=None))
        self.pairs_text.content = (f"{sum(readings.values())} image + sweep pair(s) of {camera} at "
                                   f"{len(readings)} pan reading(s)." if camera else
                                   "No image + sweep pairs of a camera and this scanner yet.")
        self._list_placements()
        self._fill_history(None)

    def _pick_pan(self) -> None:
        self._list_placements()
        self._draw_placement()

    def _list_placements(self) -> None:
        """The pairs at the chosen reading, for the placement dropdown."""
        camera, reading = self._camera, self._readings.get(self.pan.value)
        pairs = [] if camera is None or reading is None else corners_service.sweep_pairs(
            self.ctx.session, camera, self.sensor, pan_deg=reading)
        self._pairs = {pair.name: (pair.image.id, pair.cloud.id) for pair in pairs}
        self._fill(self.placement, list(self._pairs))

    def _fill_history(self, result_id: str | None) -> None:
        """List the camera's corners and pan-axis results with this scanner (newest first) and show ``result_id`` (or
        the newest)."""
        camera = self._camera
        results = [] if camera is None else corners_service.corners_results(self.ctx.session, camera, self.sensor)
        self.history.fill([r["id"] for r in reversed(results)], result_id)
        self._show_result()

    def _solve(self, method: str) -> None:
        session, camera, sensor = self.ctx.session, self._camera, self.sensor
        if camera is None:
            self.ctx.notify("No pairs", "Store image + sweep pairs of a camera and this scanner first.", error=True)
            return
        self.ctx.show_step(self.step)
        if method == "corners":
            reading = self._readings.get(self.pan.value, 0.0)
            self.jobs.run(f"Corners of {camera} at pan {reading:+g}°", lambda progress: (
                corners_service.solve_corners_session(session, camera, sensor, pan_deg=reading, progress=progress)[0]),
                self._fill_history)
        else:
            self.jobs.run(f"Pan axis of {camera}", lambda progress: corners_service.solve_pan_session(
                session, camera, sensor, progress=progress)[0], self._fill_history)

    def _show_result(self) -> None:
        """The picked result's card and its method's numbers, then the chosen placement drawn through it."""
        result_id = self.history.selected
        record = None if result_id is None else self.ctx.session.result(result_id)
        accepted = None if record is None else self.ctx.session.accepted(rig_service.slot_of(record))
        self.card.show(record, accepted)
        self.method_text.content = "" if record is None else method_markdown(record)
        self._draw_placement()

    def _draw_placement(self) -> None:
        """The chosen placement's corners in its sweep's intensity image, and its sweep coloured by its image
        through the picked result in 3D."""
        self.drop_cloud()
        chosen = self._pairs.get(self.placement.value)
        if chosen is None:
            self.image.image = BLANK_IMAGE
            self.placement_text.content = ""
            return
        image_id, sweep_id = chosen
        session, sensor = self.ctx.session, self.sensor
        try:
            self.image.image = corners_service.sweep_corners_image(session, sensor, sweep_id)
            self.placement_text.content = ""
        except InputError as exc:
            self.image.image = BLANK_IMAGE
            self.placement_text.content = f"{WARNING} {exc.message}"
        result_id = self.history.selected
        if result_id is None:
            return
        try:
            coloured = corners_service.coloured_sweep(session, sensor, result_id, image_id)
        except InputError as exc:
            self.placement_text.content += f"\n\n{WARNING} cannot colour the sweep: {exc.message}"
            return
        self._cloud = self.ctx.server.scene.add_point_cloud(
            f"{self.ctx.scene.group(self.step)}/{sensor}/coloured",
            transform_points(session.rig.T_root_frame(sensor), coloured.points_m).astype(np.float32), coloured.colours,
            point_size=POINT_SIZE_M, precision="float32")
        self.placement_text.content += (f"\n\n{len(coloured.points_m):,} of {coloured.total:,} points of the sweep "
                                         f"coloured by {image_id}'s image through {result_id}")
        self.on_coloured()
