"""Step 10, *Camera or LiDAR to IMU*: the extrinsic and time offset between a camera or a LiDAR and an IMU.

The IMU's samples are an uploaded CSV or recorded live from the IMU's device (*Record the IMU*): while it records,
the excitation bars grow with the motion, and on *Stop* the run becomes the step's IMU file (its samples are stored
as captures as they come, :mod:`backend.services.imu_recording`). For a camera the user picks it (its intrinsics in
the rig) and the IMU, names the board, uploads the recording's two files (the IMU's samples and the board's detected
corners, as CSV) and clicks *Solve*; the fit runs as a job with progress and Cancel
(:mod:`backend.calib.camera_imu.service`). For a 3D LiDAR the scans are its captures (taken while the rig turned in
a static scene) and only the IMU's samples are uploaded (:mod:`backend.calib.lidar_imu.service`: the rotation and
the time offset; the translation stays the mounting guess). The result shows the time offset with its sigma, the
motion's excitation per axis against what the fit needs, and (camera-IMU) the IMU's measured signals with the fitted
ones; it is kept in the session's history and accepted as the rig's edge on the shared result card, which also sets
the IMU's clock offset.
"""

from __future__ import annotations

import threading

import numpy as np
from scipy.spatial.transform import Rotation

from backend.calib.camera_imu import service as camera_imu_service
from backend.calib.lidar_imu import service as lidar_imu_service
from backend.core.errors import InputError
from backend.core.rig import edge_slot
from backend.devices.imu_csv import format_imu_csv
from backend.plots.camera_imu import excitation_bars, fitted_signals
from backend.plots.render import to_rgb
from backend.services.imu_recording import ImuRecorder
from backend.store.session import Session
from studio.context import StudioContext
from studio.job_panel import JobPanel
from studio.live_toggle import LiveToggle
from studio.result_card import ResultCard
from studio.result_history import ResultHistory

NONE = "(none)"
EXCITATION_PERIOD_S = 0.5
"""How often the live excitation bars are redrawn while the IMU records (s)."""
DEFAULT_BOARD = "aprilgrid:6x6:0.088:0.3"
HELP = ("Wave the rig in front of the board, turning it about every axis and moving it along each, while the camera "
        "and the IMU record. Upload the IMU's samples (CSV `t_ns,wx,wy,wz,ax,ay,az`, rad/s and m/s²) and the board's "
        "corners the camera detected (CSV `t_ns,u_px,v_px,x_m,y_m,z_m,tag_id,corner`), then solve. The time offset "
        "follows Kalibr: `t_imu = t_cam + offset`. For a LiDAR, capture its scans in step 4 while turning the rig "
        "about every axis in a static scene, and upload the IMU's samples only.")


class CameraImuStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        self._files: dict[str, tuple[str, bytes]] = {}
        gui = ctx.server.gui
        with gui.add_folder("10 · Camera or LiDAR to IMU", expand_by_default=False):
            gui.add_markdown(HELP)
            self.camera = gui.add_dropdown("Camera or LiDAR", options=[NONE],
                                           hint="a camera seeing the board, or a 3D LiDAR in a static scene")
            self.imu = gui.add_dropdown("IMU", options=[NONE])
            self.board = gui.add_text("Board", initial_value=DEFAULT_BOARD)
            self.imu_model = gui.add_dropdown(
                "IMU model", options=camera_imu_service.IMU_MODELS,
                hint="calibrated: the IMU's axes as they are; scale-misalignment: also fit their scale and "
                     "misalignment (a MEMS IMU without a factory calibration). The other model is fitted as a "
                     "cross-check either way (Kalibr's --imu-models)")
            self.imu_upload = gui.add_upload_button("IMU samples (CSV)", mime_type="text/csv")
            self.record_button = gui.add_button("Record the IMU", color="green",
                                                hint="read the IMU's device live; its samples become the IMU file")
            self.stop_button = gui.add_button("Stop recording", color="red", visible=False)
            self.toggle = LiveToggle(self.record_button, self.stop_button, on_ended=lambda _: self._recorded())
            self.live_text = gui.add_markdown("")
            self.detections_upload = gui.add_upload_button("Board corners (CSV)", mime_type="text/csv")
            self.files_text = gui.add_markdown("No recording uploaded yet.")
            self.solve_button = gui.add_button("Solve to IMU", color="blue")
            self.jobs = JobPanel(ctx, [self.solve_button])
            self.history = ResultHistory(gui, lambda _: self._show_result(), label="IMU result")
            self.offset_text = gui.add_markdown("")
            self.excitation_image = gui.add_image(to_rgb(excitation_bars(None)), label="Excitation")
            self.signals_image = gui.add_image(to_rgb(fitted_signals(None)), label="IMU signals and the fit")
            self.card = ResultCard(ctx, empty_text="No camera-IMU or LiDAR-IMU result yet.")
        self.imu_upload.on_upload(lambda _: self._keep("imu", self.imu_upload.value))
        self.detections_upload.on_upload(lambda _: self._keep("detections", self.detections_upload.value))
        self.solve_button.on_click(lambda _: self._solve())
        self.record_button.on_click(lambda _: self._record())
        self.stop_button.on_click(lambda _: self._stop_recording())
        self.recorder: ImuRecorder | None = None
        self._recorded_lock = threading.Lock()
        self.imu.on_update(lambda _: self._fill_history(None))
        ctx.on_session_changed(self._session_changed)
        ctx.on_rig_changed(lambda _: self._list_sensors())

    def _session_changed(self, session: Session) -> None:
        self._stop_recording()
        self._files = {}
        self.files_text.content = "No recording uploaded yet."
        self._list_sensors()

    def _list_sensors(self) -> None:
        rig = self.ctx.session.rig
        for dropdown, kinds in ((self.camera, ("camera", "lidar3d")), (self.imu, ("imu",))):
            names = [frame.name for kind in kinds for frame in rig.sensors(kind)] or [NONE]
            dropdown.options = names
            if dropdown.value not in names:
                dropdown.value = names[0]
        self._fill_history(None)

    def _record(self) -> None:
        """*Record the IMU*: stream the chosen IMU's device, redrawing the excitation bars as the run grows."""
        session, imu = self.ctx.session, self.imu.value
        if session is None or imu == NONE:
            self.ctx.notify("No IMU", "Add an IMU with its device in the Sensors step first.", error=True)
            return
        self._stop_recording()
        recorder = ImuRecorder(session, imu, self._on_status)
        self.recorder = recorder
        recorder.start()
        self.toggle.started([recorder])
        threading.Thread(target=self._show_excitation, args=(recorder,), name="imu-excitation", daemon=True).start()

    def _on_status(self, message: str, error: bool) -> None:
        if error:
            self.ctx.notify("IMU", message, error=True)
        self.live_text.content = message

    def _show_excitation(self, recorder: ImuRecorder) -> None:
        while self.recorder is recorder and recorder.running:
            motion = recorder.excitation()
            samples = recorder.samples()
            if motion is not None:
                self.excitation_image.image = to_rgb(excitation_bars(motion.to_dict()))
                self.live_text.content = (f"Recording {recorder.device_name}: {samples.t_s[-1] - samples.t_s[0]:.1f} s,"
                                          f" {len(samples.t_s)} samples")
            recorder.wait_stopped(EXCITATION_PERIOD_S)

    def _stop_recording(self) -> None:
        """*Stop recording*: the run's last samples are stored and the run becomes the step's IMU file."""
        if self.recorder is None:
            return
        self.recorder.stop()
        self.toggle.stopped()
        self._recorded()

    def _recorded(self) -> None:
        """The run ended (stopped, or by itself): its last samples are stored and it becomes the IMU file; the
        recorder is let go only then, so whoever sees it gone finds the file in place."""
        with self._recorded_lock:
            recorder = self.recorder
            if recorder is None:
                return
            recorder.flush()
            samples = recorder.samples()
            if samples is None:
                self.live_text.content = "The IMU gave no samples."
            else:
                self._files["imu"] = (f"{recorder.sensor} {recorder.run}.csv", format_imu_csv(samples))
                self._show_files()
                self.live_text.content = (f"Recorded {samples.t_s[-1] - samples.t_s[0]:.1f} s ({len(samples.t_s)} "
                                          f"samples) as {recorder.run}; it is the IMU file now.")
            self.recorder = None

    def _keep(self, role: str, upload) -> None:
        self._files[role] = (upload.name, upload.content)
        self._show_files()

    def _show_files(self) -> None:
        self.files_text.content = " · ".join(f"{role}: `{name}` ({len(data) / 1e6:.1f} MB)"
                                             for role, (name, data) in sorted(self._files.items()))

    def _solve(self) -> None:
        session, camera, imu = self.ctx.session, self.camera.value, self.imu.value
        if camera != NONE and session.rig.get(camera).kind == "lidar3d":
            self._solve_lidar(session, camera, imu)
            return
        if set(self._files) != {"imu", "detections"}:
            self.ctx.notify("Recording missing", "Upload both files: the IMU's samples and the board's corners.",
                            error=True)
            return
        imu_csv, detections_csv, board = self._files["imu"], self._files["detections"], self.board.value.strip()
        try:
            camera_imu_service.read_recording(session, imu, camera, imu_csv, detections_csv, board)
        except InputError as exc:
            self.ctx.notify("Cannot solve camera to IMU", exc.message, error=True)
            return
        settings = camera_imu_service.CameraImuSettings(imu_model=self.imu_model.value)
        self.jobs.run(f"camera-IMU of {camera} and {imu}", lambda progress: camera_imu_service.solve_session(
            session, imu, camera, imu_csv, detections_csv, board, settings, progress), self._fill_history)

    def _solve_lidar(self, session: Session, lidar: str, imu: str) -> None:
        if "imu" not in self._files:
            self.ctx.notify("Recording missing", "Upload the IMU's samples; the LiDAR's scans are its captures.",
                            error=True)
            return
        imu_csv = self._files["imu"]
        try:
            lidar_imu_service.read_session_inputs(session, imu, lidar, imu_csv)
        except InputError as exc:
            self.ctx.notify("Cannot solve LiDAR to IMU", exc.message, error=True)
            return
        self.jobs.run(f"LiDAR-IMU of {lidar} and {imu}", lambda progress: lidar_imu_service.solve_session(
            session, imu, lidar, imu_csv, progress), self._fill_history)

    def _fill_history(self, result_id: str | None) -> None:
        session, imu = self.ctx.session, self.imu.value
        records = [] if session is None or imu == NONE else [
            r for r in session.results(imu) if r.get("kind") in (camera_imu_service.KIND, lidar_imu_service.KIND)]
        self.history.fill([r["id"] for r in reversed(records)], result_id)
        self._show_result()

    def _show_result(self) -> None:
        result_id = self.history.selected
        record = None if result_id is None else self.ctx.session.result(result_id)
        slot_holder = None if record is None else self.ctx.session.accepted(edge_slot(record["parent"],
                                                                                       record["child"]))
        self.card.show(record, slot_holder)
        diagnostics = {} if record is None else record["diagnostics"]
        offset_ms, offset_std_ms = (1e3 * diagnostics.get(key, 0.0) for key in ("time_offset_s", "time_offset_std_s"))
        used = ("" if "frames_used" not in diagnostics else f" · {diagnostics['frames_used']} of "
                f"{diagnostics['frames_total']} frames, {diagnostics['corners_dropped']} corners dropped as outliers")
        self.offset_text.content = "" if record is None else (
            f"Time offset **{offset_ms:.3f} ms** ± {offset_std_ms:.3f} (t_imu = t_{record['parent']} + offset){used}"
            + imu_model_text(record))
        self.excitation_image.image = to_rgb(excitation_bars(diagnostics.get("excitation")))
        self.signals_image.image = to_rgb(fitted_signals(diagnostics.get("signals")))


def imu_model_text(record: dict) -> str:
    """The IMU model a camera-IMU result used and, for ``scale-misalignment``, what it found (markdown)."""
    model = record.get("settings", {}).get("imu_model")
    if model is None:
        return ""  # a LiDAR-IMU result (or a camera-IMU result kept before the choice existed)
    intrinsics = record["diagnostics"]["imu_intrinsics"]
    if intrinsics is None:
        return f"\n\nIMU model **{model}** (the IMU's axes taken as they are)"
    accel, gyro = np.array(intrinsics["accel_M"]), np.array(intrinsics["gyro_M"])
    turn_deg = np.degrees(Rotation.from_matrix(intrinsics["R_gyro_accel"]).magnitude())
    return ("\n\nIMU model **scale-misalignment**: accelerometer scale "
            f"{' / '.join(f'{v:.4f}' for v in np.diag(accel))}, misalignment up to "
            f"{np.degrees(np.abs(np.tril(accel, -1)).max()):.2f}°; gyro scale "
            f"{' / '.join(f'{v:.4f}' for v in np.diag(gyro))}, misalignment up to "
            f"{np.degrees(np.abs(np.tril(gyro, -1)).max()):.2f}°, its triad turned {turn_deg:.2f}° from the "
            "accelerometer's")
