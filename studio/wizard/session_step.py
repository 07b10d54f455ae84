"""Step 1: choose or create a session and set its targets (the board or a wall test field with its survey, the
V-target); print them."""

from __future__ import annotations

import threading

from backend.core.boards import BoardSpec
from backend.core.errors import InputError
from backend.core.targets import parse_target
from backend.core.test_field import SESSION_SURVEY, TestField
from backend.core.v_target import VTarget
from backend.exports.target_pdf import PAPERS_MM, target_sheet, v_target_sheet
from backend.services.jobs import Job
from studio.context import StudioContext
from studio.marks import WARNING

NEW_SESSION = "(new session)"
BUILD_POLL_S = 0.5
"""How often the progress line of a session being built is refreshed (s)."""


class SessionStep:
    def __init__(self, ctx: StudioContext):
        self.ctx = ctx
        gui = ctx.server.gui
        with gui.add_folder("1 · Session"):
            self.choice = gui.add_dropdown("Session", options=[NEW_SESSION], initial_value=NEW_SESSION)
            self.open_button = gui.add_button("Open session")
            self.new_name = gui.add_text("New name", initial_value="")
            self.new_board = gui.add_text("Board", initial_value="checkerboard:9x6:0.025",
                                          hint="checkerboard:COLSxROWS:SQUARE_M or "
                                               "charuco:COLSxROWS:SQUARE_M:MARKER_M:DICT")
            self.create_button = gui.add_button("Create session")
            self.summary = gui.add_markdown("No session open.")
            with gui.add_folder("Targets", expand_by_default=False):
                self.survey_button = gui.add_upload_button(
                    "Upload a test field's survey", mime_type="text/*", disabled=True,
                    hint="a line of id, X, Y, Z (m) per marker centre, in the wall's frame; then set the board to "
                         f"testfield:DICT:MARKER:{SESSION_SURVEY}")
                self.board = gui.add_text("Session board", initial_value="", disabled=True,
                                          hint="a board spec, or testfield:DICT:MARKER:survey.csv (the uploaded "
                                               "survey)")
                self.board_button = gui.add_button("Set the board", disabled=True)
                self.test_field = gui.add_text("Test field beside the board", initial_value="", disabled=True,
                                               hint=f"testfield:DICT:MARKER:{SESSION_SURVEY} (the uploaded survey): "
                                                    "the cameras' pose in the wall's frame (step 3) while the board "
                                                    "stays the target of the other steps")
                self.test_field_button = gui.add_button("Set the test field", disabled=True)
                self.v_target = gui.add_text("V-target", initial_value="", disabled=True,
                                             hint="vtarget:WxH:ANGLE:COLSxROWS:MARKER:DICT, e.g. "
                                                  "vtarget:1.0x0.6:120:3x2:0.15:DICT_4X4_50 (LiDAR-camera, step 6)")
                self.v_target_button = gui.add_button("Set the V-target", disabled=True)
                self.print_v_target = gui.add_button("Print the V-target", disabled=True,
                                                     hint="its two faces as a PDF at exact scale, a page each")
            self.paper = gui.add_dropdown("Paper", options=["auto", *PAPERS_MM], initial_value="auto",
                                          hint="auto: the first paper the board fits, in this list's order")
            self.print_target = gui.add_button("Print the target", disabled=True,
                                               hint="the session's board as a PDF at exact scale: print it at 100 % "
                                                    "/ actual size and check its 100 mm bar")
            self.broken = gui.add_markdown("")
        self._refresh()
        self.open_button.on_click(lambda _: self._open())
        self.create_button.on_click(lambda _: self._create())
        self.print_target.on_click(self._download_target)
        self.survey_button.on_upload(lambda _: self._upload_survey())
        self.board_button.on_click(lambda _: self._set_target("board", self.board.value))
        self.test_field_button.on_click(lambda _: self._set_target("test field", self.test_field.value))
        self.v_target_button.on_click(lambda _: self._set_target("V-target", self.v_target.value))
        self.print_v_target.on_click(self._download_v_target)
        ctx.on_session_changed(self._show)

    def _refresh(self) -> None:
        """List the sessions that open in the dropdown, and those that cannot below it with their reason."""
        listing = self.ctx.store.listing()
        self.choice.options = [NEW_SESSION, *(entry["name"] for entry in listing if not entry["broken"])]
        broken = [f"- `{entry['name']}`: {entry['broken']['message']}" for entry in listing if entry["broken"]]
        self.broken.content = "\n".join(["**Broken sessions** (repair their session.json):", "", *broken] if broken
                                         else [])

    def _open(self) -> None:
        if self.choice.value == NEW_SESSION:
            self.ctx.notify("Pick a session", "Choose a session in the list, or create one below.")
            return
        try:
            self.ctx.open_session(self.ctx.store.get(self.choice.value))
        except InputError as exc:
            self.ctx.notify("Cannot open session", exc.message, error=True)

    def _create(self) -> None:
        try:
            board = str(BoardSpec.parse(self.new_board.value))
            session = self.ctx.store.create(self.new_name.value.strip(), board=board)
        except InputError as exc:
            self.ctx.notify("Cannot create session", exc.message, error=True)
            return
        self.new_name.value = ""  # the name is taken now; the board stays for the next session
        self._refresh()
        self.ctx.open_session(session)

    def _upload_survey(self) -> None:
        upload, session = self.survey_button.value, self.ctx.session
        try:
            session.set_survey(upload.content, upload.name)
        except InputError as exc:
            self.ctx.notify("Survey not kept", exc.message, error=True)
            return
        self.ctx.notify("Survey kept", f"{upload.name} is the session's {SESSION_SURVEY}.")
        self._show(session)

    def _set_target(self, what: str, spec: str) -> None:
        """Set the open session's board (a board or a test field), its test field beside the board or its V-target
        from ``spec``."""
        session = self.ctx.session
        try:
            if what == "board":
                session.set_board(str(parse_target(spec, session.path)))
            elif what == "test field":
                session.set_test_field(str(TestField.parse(spec, session.path, field="test_field")))
            else:
                session.set_v_target(str(VTarget.parse(spec)))
        except InputError as exc:
            self.ctx.notify(f"Cannot set the {what}", exc.message, error=True)
            return
        self.ctx.notify(f"{what.capitalize()} set", spec)
        self._show(session)

    def _download_v_target(self, event) -> None:
        """Send the open session's V-target as a printable PDF to the page that clicked."""
        session = self.ctx.session
        try:
            sheet = v_target_sheet(session.v_target or "", self.paper.value)
        except InputError as exc:
            self.ctx.notify("Cannot print the V-target", exc.message, error=True)
            return
        event.client.send_file_download(sheet.filename, sheet.pdf)

    def _download_target(self, event) -> None:
        """Send the open session's board as a printable PDF to the page that clicked (a toast says why not)."""
        session = self.ctx.session
        if session is None or not session.board:
            self.ctx.notify("No board", "Open a session with a board spec first.", error=True)
            return
        try:
            sheet = target_sheet(session.board, self.paper.value, folder=session.path)
        except InputError as exc:
            self.ctx.notify("Cannot print the target", exc.message, error=True)
            return
        event.client.send_file_download(sheet.filename, sheet.pdf)

    def _show(self, session) -> None:
        self._refresh()
        self.print_target.disabled = not session.board
        if self.choice.value != session.name:
            self.choice.value = session.name
        sensors = ", ".join(f"`{f.name}` ({f.kind})" for f in session.rig.sensors()) or "none yet"
        survey = " (survey uploaded)" if (session.path / SESSION_SURVEY).exists() else ""
        self.summary.content = (f"**{session.name}** {session.title}\n\n"
                                f"Board: `{session.board}`{survey}  \n"
                                + (f"Test field beside it: `{session.test_field}`  \n" if session.test_field else "")
                                + f"V-target: `{session.v_target}`  \n"
                                f"Sensors: {sensors}")
        for handle in (self.survey_button, self.board, self.board_button, self.test_field, self.test_field_button,
                       self.v_target, self.v_target_button):
            handle.disabled = False
        self.print_v_target.disabled = not session.v_target
        self.board.value, self.v_target.value = session.board or "", session.v_target or ""
        self.test_field.value = session.test_field or ""

    def open_when_built(self, job: Job) -> None:
        """Open the session ``job`` builds (e.g. the demo) once it is done, showing its progress meanwhile.

        A job done within one poll (a session already built) opens before this returns. The session opens only if
        the user has not opened another in the meantime; a failed build is shown with its reason.
        """
        if not job.wait(BUILD_POLL_S):
            threading.Thread(target=self._follow_build, args=(job,), name="session-build", daemon=True).start()
            return
        self._built(job)

    def _follow_build(self, job: Job) -> None:
        while not job.wait(BUILD_POLL_S):
            if self.ctx.session is None:
                self.summary.content = f"{job.title.capitalize()} … {100 * job.fraction:.0f} %  \n{job.message}"
        self._built(job)

    def _built(self, job: Job) -> None:
        if job.state != "done":
            self.summary.content = f"{WARNING} {job.title.capitalize()} failed: {job.message}"
            self.ctx.notify(f"{job.title} failed", job.message, error=True)
        elif self.ctx.session is None:
            self.ctx.open_session(job.result)
        else:
            self._refresh()
