"""The LiDAR step's import panel: a cloud file uploaded from the laptop, or a whole recording replayed in.

A LiDAR whose device is a recording (a ROS 2 bag topic, a Velodyne pcap, a folder of cloud
files; set in *2 · Sensors*) can be imported whole: every n-th scan becomes a capture, as a
background job with progress and cancel (:func:`backend.services.recordings.import_recording`).
"""

from __future__ import annotations

from collections.abc import Callable

from backend.calib.lidar_lidar import service as lidar_service
from backend.core.errors import InputError
from backend.devices.cloud_files import CLOUD_EXTENSIONS
from backend.services import recordings
from studio.context import StudioContext
from studio.job_panel import JobPanel

NONE = "(no LiDAR)"


class CloudImportPanel:
    """Upload and recording import for one chosen LiDAR; ``on_imported()`` runs after captures were added."""

    def __init__(self, ctx: StudioContext, on_imported: Callable[[], None]):
        self.ctx = ctx
        self.on_imported = on_imported
        gui = ctx.server.gui
        with gui.add_folder("Import", expand_by_default=False):
            self.sensor = gui.add_dropdown("Into LiDAR", options=[NONE])
            self.upload = gui.add_upload_button("Upload a cloud file", hint=" ".join(CLOUD_EXTENSIONS))
            self.every = gui.add_number("Every n-th scan", initial_value=1, min=1, max=1000, step=1)
            self.limit = gui.add_number("At most (scans)", initial_value=recordings.DEFAULT_LIMIT, min=1,
                                        max=10_000, step=1)
            self.recording_text = gui.add_markdown("")
            self.import_button = gui.add_button("Import its recording")
            self.jobs = JobPanel(ctx, [self.import_button])
        self.sensor.on_update(lambda _: self._describe())
        self.upload.on_upload(lambda _: self._upload(self.upload.value))
        self.import_button.on_click(lambda _: self._import())

    def set_lidars(self, lidars: list[str]) -> None:
        self.sensor.options = lidars or [NONE]
        if self.sensor.value not in self.sensor.options:
            self.sensor.value = self.sensor.options[0]
        self._describe()

    @property
    def current(self) -> str | None:
        return None if self.ctx.session is None or self.sensor.value == NONE else self.sensor.value

    def _describe(self) -> None:
        """Say what *Import its recording* would read for the chosen LiDAR."""
        sensor = self.current
        device = {} if sensor is None else self.ctx.session.rig.get(sensor).device
        if device.get("driver") in recordings.RECORDING_DRIVERS:
            where = ", ".join(f"{k} {v}" for k, v in device.items() if k != "driver")
            self.recording_text.content = f"Recording: **{device['driver']}** · {where}"
        else:
            self.recording_text.content = (f"{sensor or 'This LiDAR'} streams live ({device.get('driver', 'no device')}"
                                           "); to import a bag, pcap or cloud folder, add a sensor with that device "
                                           "in step 2, *Sensors*.")

    def _upload(self, upload) -> None:
        sensor = self.current
        if sensor is None:
            self.ctx.notify("No LiDAR", "Pick the LiDAR the file belongs to first.", error=True)
            return
        try:
            [record] = lidar_service.import_clouds(self.ctx.session, sensor, [(upload.name, upload.content)])
        except InputError as exc:
            self.ctx.notify("Cloud not added", exc.message, error=True)
            return
        self.ctx.notify("Cloud added", f"{upload.name}: capture {record.id} of {sensor} ({record.n_points:,} pts).")
        self.on_imported()

    def _import(self) -> None:
        session, sensor = self.ctx.session, self.current
        if sensor is None:
            return
        every, limit = int(self.every.value), int(self.limit.value)

        def done(summary: recordings.ImportSummary) -> None:
            skipped = f"; {len(summary.skipped)} skipped (first: {summary.skipped[0]['message']})" \
                if summary.skipped else ""
            self.ctx.notify("Recording imported", f"{len(summary.added)} scans into {sensor}{skipped}; "
                            f"{summary.ended}.", error=not summary.complete)
            self.on_imported()

        self.jobs.run(f"Import into {sensor}", lambda progress: recordings.import_recording(
            session, sensor, every=every, limit=limit, progress=progress), done)
