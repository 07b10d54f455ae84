"""Step 2: add sensors to the rig, with their mounting guess and capture device."""

from __future__ import annotations

import numpy as np

from backend.core.errors import InputError
from backend.core.rig import Frame
from backend.core.transforms import from_xyz_ypr
from studio.context import StudioContext

DRIVERS = {
    "uvc": "USB camera (index or /dev/videoN)",
    "folder": "folder of images (path)",
    "simulated": "simulated camera (cam_front or cam_wide)",
}


def device_settings(driver: str, source: str, width: int, height: int) -> dict:
    """Capture settings for the rig from the form fields."""
    if driver == "uvc":
        device: int | str = int(source) if source.strip().isdigit() else source.strip()
        return {"driver": "uvc", "device": device, "width": width or None, "height": height or None}
    if driver == "folder":
        return {"driver": "folder", "path": source.strip()}
    return {"driver": "simulated", "camera": source.strip() or "cam_front", "seed": 0}


class SensorsStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        gui = ctx.server.gui
        with gui.add_folder("2 · Sensors", expand_by_default=False):
            self.listing = gui.add_markdown("Open a session first.")
            self.name = gui.add_text("Name", initial_value="cam_new")
            self.kind = gui.add_dropdown("Kind", options=["camera", "lidar3d", "lidar2d", "depth", "imu", "frame"])
            self.parent = gui.add_dropdown("Parent", options=["base_link"])
            self.xyz = gui.add_vector3("xyz (m)", initial_value=(0.0, 0.0, 0.0), step=0.001)
            self.ypr = gui.add_vector3("yaw pitch roll (°)", initial_value=(0.0, 0.0, 0.0), step=0.1)
            self.driver = gui.add_dropdown("Device", options=list(DRIVERS), initial_value="uvc")
            self.source = gui.add_text("Source", initial_value="0", hint=" | ".join(DRIVERS.values()))
            self.size = gui.add_vector2("Resolution (px)", initial_value=(1280, 720), step=1)
            self.add_button = gui.add_button("Add sensor")
        self.add_button.on_click(lambda _: self._add())
        ctx.on_session_changed(self._show)

    def _add(self) -> None:
        session = self.ctx.session
        if session is None:
            self.ctx.notify("No session", "Open or create a session first.", error=True)
            return
        T = from_xyz_ypr(np.array(self.xyz.value), np.radians(self.ypr.value))
        device = device_settings(self.driver.value, self.source.value, int(self.size.value[0]),
                                 int(self.size.value[1])) if self.kind.value == "camera" else {}
        try:
            session.add_sensor(Frame(self.name.value.strip(), self.parent.value, T, kind=self.kind.value,
                                     device=device))
        except InputError as exc:
            self.ctx.notify("Cannot add sensor", exc.message, error=True)
            return
        self.ctx.open_session(session)

    def _show(self, session) -> None:
        self.parent.options = list(session.rig.frames)
        lines = [f"- `{f.name}` ({f.kind}) under `{f.parent}`"
                 f"{' · ' + f.device.get('driver', '') if f.device else ''}" for f in session.rig.sensors()]
        self.listing.content = "\n".join(lines) or "No sensors yet."
