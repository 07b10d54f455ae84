"""Per-step layers in the 3D view: which step is in view, and one checkbox per step's layer group.

Every step draws its scene nodes under its own group (``/steps/<step>/...``, the rig tree under
``/rig_tree/...``; :meth:`studio.scene.RigScene.group`), so a group shows or hides as one.

viser 1.1.1 tells the server nothing when the user opens a folder or picks a tab: a folder's open
state (``components/Folder.tsx``, ``useDisclosure``) and a tab group's active tab (``TabGroup.tsx``,
``setActiveTab``) live in the page only, and neither handle has an event. So the studio keeps its
own *current step*: the **Step in view** dropdown at the top of the wizard, which a step also sets
through :meth:`StudioContext.show_step` when the user starts working in it. Picking a step shows
its layers and hides every other step's; the checkboxes of the *Layers* folder then override group
by group. *All steps* (the start) shows every group.
"""

from __future__ import annotations

from studio.context import StudioContext

STEPS: dict[str, str] = {
    "session": "Step 1 · Session",
    "sensors": "Step 2 · Sensors",
    "intrinsics": "Step 3 · Camera intrinsics",
    "lidar": "Step 4 · LiDARs",
    "sweep": "Step 5 · Swept scanner",
    "lidar_camera": "Step 6 · LiDAR to camera",
    "multicam": "Step 7 · Multi-camera",
    "rig": "Step 8 · Rig",
    "depth_network": "Step 9 · Depth network",
}
"""Every wizard step by its layer-group name, with how the step selector names it."""
LAYER_GROUPS: dict[str, str] = {
    "intrinsics": "Boards (step 3)",
    "lidar": "LiDAR clouds (step 4)",
    "sweep": "Sweep (step 5)",
    "lidar_camera": "Coloured cloud (step 6)",
    "multicam": "Solved cameras (step 7)",
    "rig": "Rig tree (step 8)",
    "depth_network": "Depth network (step 9)",
}
"""The steps that draw layers of their own, with their checkbox labels."""
ALL_STEPS = "All steps"


class Layers:
    """The *Step in view* selector and the *Layers* folder; keeps the scene's group visibility in step with them."""

    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        gui = ctx.server.gui
        self.step = gui.add_dropdown("Step in view", options=[ALL_STEPS, *STEPS.values()], initial_value=ALL_STEPS,
                                     hint="the 3D view shows this step's layers only (clouds, boards, solved "
                                          "cameras, the rig tree); the sensors' frames always show")
        with gui.add_folder("Layers", expand_by_default=False):
            gui.add_markdown("One group per step; picking a step above shows its group and hides the others.")
            self.checkboxes = {step: gui.add_checkbox(label, initial_value=True)
                               for step, label in LAYER_GROUPS.items()}
        for step, checkbox in self.checkboxes.items():
            ctx.scene.group(step)
            checkbox.on_update(lambda _, step=step: self._toggle(step))
        self.step.on_update(lambda _: self._follow_selector())
        ctx.on_step_shown(self.show_step)

    @property
    def current(self) -> str | None:
        """The step in view (a key of :data:`STEPS`), None for *All steps*."""
        return next((step for step, label in STEPS.items() if label == self.step.value), None)

    def show_step(self, step: str) -> None:
        """Put ``step`` in view: its group shows, every other step's hides (a group the user ticked back on since
        hides again)."""
        self.step.value = STEPS[step]
        self._follow_selector()

    def _follow_selector(self) -> None:
        current = self.current
        for step, checkbox in self.checkboxes.items():
            checkbox.value = current is None or step == current  # fires its toggle when it changes

    def _toggle(self, step: str) -> None:
        self.ctx.scene.set_group_visible(step, bool(self.checkboxes[step].value))
