"""Shared fixtures: paths to the real data sets in ../shared/data."""

from __future__ import annotations

import base64
import contextlib
import fcntl
import io
import os
import queue
import re
import shutil
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import cv2
import httpx
import numpy as np
import pytest
from playwright.sync_api import Browser, Locator, Page, expect, sync_playwright

import backend.sim.devices  # noqa: F401  (as the front-ends do through backend.services: simulated drivers and endpoints)

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
STEREO_CHESSBOARD = SHARED_DATA / "opencv_stereo_chessboard"
OPENCALIB = SHARED_DATA / "opencalib_lidar2camera"
T = TypeVar("T")


@dataclass
class OpenCalibFrame:
    """The real OpenCalib LiDAR + camera frame (see its README): BGR image, cloud, camera, reference extrinsic."""

    image: Any
    points: Any
    """(N, 3) float64 LiDAR points (m)."""
    intensity: Any
    """(N,) return intensity."""
    camera: Any
    """The camera's :class:`~backend.core.camera.CameraIntrinsics`."""
    T_camera_lidar: Any
    """The authors' reference ``T_camera_lidar`` (4x4, m)."""


def opencalib_frame() -> OpenCalibFrame:
    """Read the OpenCalib frame; fails (not skips) the test when the data set is missing."""
    import json

    import numpy as np

    from backend.core.camera import CameraIntrinsics
    from backend.devices.cloud_files import read_cloud
    from backend.devices.image_io import read_image

    if not OPENCALIB.is_dir():
        pytest.fail(f"real data missing: {OPENCALIB}")
    intrinsic = json.loads((OPENCALIB / "center_camera-intrinsic.json").read_text())["center_camera-intrinsic"]["param"]
    camera = CameraIntrinsics("pinhole-radtan", intrinsic["img_dist_w"], intrinsic["img_dist_h"],
                              np.array(intrinsic["cam_K"]["data"]), np.array(intrinsic["cam_dist"]["data"][0]))
    extrinsic = json.loads((OPENCALIB / "top_center_lidar-to-center_camera-extrinsic.json").read_text())
    T = np.array(extrinsic["top_center_lidar-to-center_camera-extrinsic"]["param"]["sensor_calib"]["data"])
    cloud = read_cloud(OPENCALIB / "calib.pcd")
    return OpenCalibFrame(read_image(OPENCALIB / "calib.png"), cloud.points, cloud.intensity, camera, T)


CLI_TIMEOUT_S = 300
"""How long one ``calib-studio`` subprocess may run: the longest, a multicam or depth-network solve, takes about a
minute on a loaded machine."""


def cli_subprocess(*args: str | Path, cwd: Path = ROOT,
                   env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``calib-studio ARGS`` as a user runs it, a process of its own started in ``cwd``, with ``env`` added to this
    process's environment: its exit code, stdout and stderr. For the contracts a process answers for (one JSON line
    on stdout, progress on stderr, the exit code, the environment); everything else runs in process
    (:func:`cli_in_process`)."""
    return subprocess.run([sys.executable, "-m", "studio.cli", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=CLI_TIMEOUT_S, env={**os.environ, **(env or {})})


def cli_in_process(*args: str | Path, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """``calib-studio ARGS`` through :func:`studio.cli.main` in this process, run in ``cwd``: its exit code, stdout
    and stderr. It is the code ``python -m studio.cli`` runs (its ``__main__`` exits with what ``main`` returns), less
    the interpreter and the imports, a few seconds of start-up per call; for the refusals, where that start-up is
    nearly all the time. The contracts themselves keep a real subprocess."""
    from studio import cli

    out, err = io.StringIO(), io.StringIO()
    with contextlib.chdir(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = cli.main([str(arg) for arg in args])
        except SystemExit as exc:  # what the process would exit with, had anything called sys.exit
            code = exc.code if isinstance(exc.code, int) else 1
    return subprocess.CompletedProcess(["calib-studio", *map(str, args)], code, out.getvalue(), err.getvalue())


@pytest.fixture(scope="session")
def stereo_chessboard() -> Path:
    if not STEREO_CHESSBOARD.is_dir():
        pytest.fail(f"real data missing: {STEREO_CHESSBOARD} (shared/data must sit beside the checkout)")
    return STEREO_CHESSBOARD


@pytest.fixture(scope="session")
def left_images(stereo_chessboard: Path) -> list[Path]:
    return sorted(stereo_chessboard.glob("left*.jpg"))


STEREO_BOARD = "checkerboard:9x6:0.025"
"""The stereo set's board: 9x6 inner corners, 25 mm squares."""


@pytest.fixture(scope="session")
def stereo_detections(stereo_chessboard: Path) -> dict[str, dict[str, Any]]:
    """The board found (:func:`~backend.calib.board.detection.detect_board`) in every image of the stereo set, by
    side (``left``, ``right``) and file name in name order: detected once per test process (0.2 s an image) for the
    tests whose input they are. Not to be changed."""
    from backend.calib.board.detection import detect_board
    from backend.core.boards import BoardSpec
    from backend.devices.image_io import read_image

    board = BoardSpec.parse(STEREO_BOARD)
    return {side: {path.name: detect_board(read_image(path, grayscale=True), board)
                   for path in sorted(stereo_chessboard.glob(f"{side}*.jpg"))} for side in ("left", "right")}


ARTIFACTS = Path(__file__).parent / "artifacts"
"""Screenshots the browser tests leave for a person to look at."""
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless=new", "--no-sandbox", "--use-gl=angle", "--use-angle=gl-egl",
                 "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist", "--disable-gpu-compositing",
                 "--disable-background-networking", "--disable-component-update", "--no-first-run"]
"""Debian's chromium (Playwright cannot fetch its own) with software WebGL: Mesa's llvmpipe through ANGLE's EGL back
end where Mesa's drivers are installed (chromium recommends ``libgl1-mesa-dri``), else chromium's own SwiftShader,
which it falls back to by itself. llvmpipe first because the studio's point clouds are drawn from their vertices, and
SwiftShader's GPU process spent 611 of the browser tests' 1,085 busy core-seconds on them (3 workers, 2 cores), where
llvmpipe's spends 168 of 750 (``../shared/stack-notes.md`` names SwiftShader only). The page itself is composited in
software (``--disable-gpu-compositing``; the 3D view still draws through WebGL): compositing every frame of a
1600x2000 page through llvmpipe kept the GPU process busier than the 3D view did, and without it the browser tests
(one process, one after another) took 376 core-seconds instead of 462, the pages and screenshots alike."""


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@pytest.fixture(scope="session")
def free_port() -> Callable[[], int]:
    """A function returning a free TCP port on 127.0.0.1."""
    return _free_port


@pytest.fixture(scope="session")
def browser() -> Iterator[Browser]:
    """One headless Debian chromium for the whole run, driven by Playwright."""
    ARTIFACTS.mkdir(exist_ok=True)
    with sync_playwright() as playwright:
        # llvmpipe draws in one thread: the test processes already fill the cores, and with its default (one per
        # core) the LiDAR step streaming two clouds kept 1.10 cores busy drawing 9 frames/s, with one 0.92 at 6.8
        chromium = playwright.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS,
                                              env={**os.environ, "LP_NUM_THREADS": "1"})
        try:
            yield chromium
        finally:
            chromium.close()


def stop_process(process: subprocess.Popen) -> None:
    """Ask a server process to stop, and kill it if it has not within 15 s."""
    process.terminate()
    try:
        process.wait(timeout=15)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait(timeout=10)


UI_WAIT_S = 60.0
"""The longest a browser test waits for the page to show what a click or a server event caused. A bound for
failing, never a delay (every wait returns as soon as its condition holds): generous, because a 2-core machine
under load draws the page, runs the studio and solves at once."""
UI_WAIT_MS = int(UI_WAIT_S * 1000)
""":data:`UI_WAIT_S` in Playwright's milliseconds."""
expect.set_options(timeout=UI_WAIT_MS)  # Playwright's ``expect`` keeps its own 5 s default beside the page's
START_WAIT_S = 180.0
"""The longest a studio or agent process may take to start (print its URL, build a session, connect): about 10 s
on a quiet 2-core machine, but one took more than 90 s with 4 busy processes beside the suite (load 13)."""


def poll(check: Callable[[], T], failure: str | Callable[[], str], timeout_s: float = UI_WAIT_S,
         interval_s: float = 0.2) -> T:
    """Call ``check`` every ``interval_s`` until it returns something true; that value. Fail with ``failure`` (or
    what it returns, called then) once ``timeout_s`` has passed. Every wait in the suite is one of these (or
    :func:`steady`): it returns as soon as its condition holds, and its bound is for failing, never a delay."""
    deadline = time.monotonic() + timeout_s
    while not (value := check()):
        assert time.monotonic() < deadline, failure() if callable(failure) else failure
        time.sleep(interval_s)
    return value


def steady(read: Callable[[], T], failure: str, quiet_polls: int, interval_s: float,
           timeout_s: float = UI_WAIT_S) -> T:
    """Call ``read`` every ``interval_s`` until it has returned the same value ``quiet_polls`` times running (a
    burst of updates has landed); that value. Fail with ``failure`` once ``timeout_s`` has passed."""
    deadline = time.monotonic() + timeout_s
    value, same = read(), 0
    while same < quiet_polls:
        assert time.monotonic() < deadline, failure
        time.sleep(interval_s)
        now = read()
        same = same + 1 if now == value else 0
        value = now
    return value


def wait_job(client, job_id: str, timeout_s: float = UI_WAIT_S) -> dict:
    """Poll ``/api/jobs/{job_id}`` through an HTTP client until the job has finished; its last status."""
    last: dict = {}

    def finished() -> dict | None:
        nonlocal last
        response = client.get(f"/api/jobs/{job_id}")
        assert response.status_code == 200, response.text
        last = response.json()  # the whole answer: a key of an earlier one must not linger
        return None if last["state"] == "running" else last

    return poll(finished, lambda: f"job still running after {timeout_s:.0f} s: {last}", timeout_s, interval_s=0.05)


@dataclass
class Studio:
    url: str
    api: str
    process: subprocess.Popen
    log: Path

    def log_tail(self, lines: int = 30) -> str:
        return "\n".join(self.log.read_text(errors="replace").splitlines()[-lines:])

    def get(self, path: str) -> dict | list:
        response = httpx.get(f"{self.api}{path}", timeout=10)
        assert response.status_code == 200, f"GET {path}: {response.status_code} {response.text}"
        return response.json()


def built_once(tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], object]) -> Path:
    """The folder ``name`` that ``build(folder)`` fills once per run, for every test process: under pytest-xdist
    the first worker to need it builds it in the run's common temp folder while holding a lock, the others wait
    and read it. It is built in a staging folder and renamed, so a build that fails leaves nothing half made."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    shared = tmp_path_factory.getbasetemp() if worker is None else tmp_path_factory.getbasetemp().parent
    folder = shared / name
    # fcntl rather than the filelock package (not a dependency): one POSIX lock file, released when closed
    with (shared / f"{name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not folder.exists():
            staging = shared / f"{name}.building"
            shutil.rmtree(staging, ignore_errors=True)
            staging.mkdir()
            build(staging)
            staging.rename(folder)
    return folder


@pytest.fixture(scope="session")
def demo_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A sessions folder holding the demo session, built once per run (about 35 s, :func:`built_once`) and copied
    by every test that wants a demo of its own (:func:`fresh_demo`)."""
    from backend.services.demo import ensure_demo_session
    from backend.store.session import SessionStore

    return built_once(tmp_path_factory, "demo_template", lambda root: ensure_demo_session(SessionStore(root)))


def disaster_response_template(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A sessions folder holding the disaster-response demo session, built once per run (about 15 s,
    :func:`built_once`), for a test to copy (:func:`fresh_demo`)."""
    from backend.services.demo_disaster_response import ensure_disaster_response_session
    from backend.store.session import SessionStore

    return built_once(tmp_path_factory, "disaster_response_template",
                      lambda root: ensure_disaster_response_session(SessionStore(root)))


LENS_VIEWS = 15
"""Views of the waved board a test captures when it needs a camera's lens solved, not its coverage (the first 15
frames of the simulated wave are spread over the image)."""


def capture_lens_views(session, camera: str, device_settings: dict) -> None:
    """Store the board views of the first :data:`LENS_VIEWS` frames of ``device_settings`` (a simulated camera
    waving the board) as ``camera``'s lens views, detected as a capture is."""
    from backend.calib._session import session_board
    from backend.calib.board.detection import detect_board
    from backend.calib.intrinsics import service as intrinsics_service
    from backend.devices.base import create_device

    board = session_board(session)
    with create_device(device_settings) as device:
        for _ in range(LENS_VIEWS):
            sample = device.read()
            detection = detect_board(sample.image, board)
            if detection is not None:
                intrinsics_service.store_capture(session, camera, sample.image, detection, device=device.describe(),
                                                 timestamp_s=sample.timestamp_s)


def fresh_demo(template: Path, sessions: Path) -> Path:
    """Copy the template's demo session into ``sessions`` (created); returns ``sessions``."""
    shutil.copytree(template, sessions)
    return sessions


def start_demo(sessions: Path, free_port: Callable[[], int], log: Path, command: tuple[str, ...] = ("demo",)
               ) -> tuple[subprocess.Popen, int, int]:
    """``calib-studio demo`` (or another serving ``command``: ``("serve",)``, ``("demo", "--rig", "depth-cell")``)
    on ``sessions`` in a subprocess (stdout piped, stderr into ``log``), on two free ports: the process, the API's
    port and the viewer's."""
    api_port, viewer_port = free_port(), free_port()
    while viewer_port == api_port:
        viewer_port = free_port()
    with log.open("wb") as stderr:
        process = subprocess.Popen(
            [sys.executable, "-m", "studio.cli", *command, "--sessions", str(sessions), "--port", str(api_port),
             "--viewer-port", str(viewer_port)], cwd=ROOT, stdout=subprocess.PIPE, stderr=stderr, text=True)
    return process, api_port, viewer_port


@contextlib.contextmanager
def serving(sessions: Path, free_port: Callable[[], int], log: Path, command: tuple[str, ...] = ("demo",)
            ) -> Iterator[Studio]:
    """The studio :func:`start_demo` starts with ``command`` on ``sessions``, once it has printed its URL and answers
    ``/api/health``; stopped afterwards."""
    process, api_port, viewer_port = start_demo(sessions, free_port, log, command)
    lines: queue.Queue[str] = queue.Queue()

    def drain() -> None:  # keep reading so the studio never blocks on a full pipe
        for line in process.stdout:
            lines.put(line)

    threading.Thread(target=drain, daemon=True).start()
    studio = Studio("", f"http://127.0.0.1:{api_port}", process, log)
    try:
        try:
            first = lines.get(timeout=START_WAIT_S)
        except queue.Empty:
            pytest.fail(f"the studio printed no URL (exit code {process.poll()}):\n{studio.log_tail()}")
        studio.url = first.strip()
        assert studio.url == f"http://127.0.0.1:{viewer_port}/", studio.url
        wait_health(studio.api, process, studio.log_tail)
        yield studio
    finally:
        stop_process(process)


@pytest.fixture(scope="module")
def studio(tmp_path_factory: pytest.TempPathFactory, free_port: Callable[[], int], demo_template: Path
           ) -> Iterator[Studio]:
    """``calib-studio demo`` in a subprocess, on a copy of the run's demo session (so it starts in seconds)."""
    tmp = tmp_path_factory.mktemp("studio")
    fresh_demo(demo_template, tmp / "sessions")
    with serving(tmp / "sessions", free_port, tmp / "studio.log") as studio:
        yield studio


def wait_health(api: str, process: subprocess.Popen, log_tail: Callable[[], str], timeout_s: float = UI_WAIT_S
                ) -> None:
    """Wait until ``api``'s ``/api/health`` answers 200; fail with the studio's log if it exits or never answers."""
    def healthy() -> bool:
        assert process.poll() is None, f"the studio exited with {process.returncode}:\n{log_tail()}"
        try:
            return httpx.get(f"{api}/api/health", timeout=5).status_code == 200
        except httpx.TransportError:
            return False

    poll(healthy, lambda: f"/api/health never answered 200:\n{log_tail()}", timeout_s)


def dismiss_webgl_warning(page: Page) -> None:
    """Close viser's "Software WebGL rendering detected" toast (SwiftShader) so it hides nothing."""
    toast = page.locator(".mantine-Notification-root", has_text="Software WebGL")
    try:
        toast.wait_for(timeout=3_000)
        toast.locator("button").first.click()
        toast.wait_for(state="hidden", timeout=3_000)
    except Exception:  # noqa: BLE001 - cosmetic only: absent on GPU machines, harmless if it stays
        pass


@contextlib.contextmanager
def studio_page(browser: Browser, url: str, viewport: dict[str, int]) -> Iterator[Page]:
    """The studio page in a fresh browser context, connected, with the WebGL toast dismissed."""
    context = browser.new_context(viewport=viewport)
    try:
        page = context.new_page()
        page.set_default_timeout(UI_WAIT_MS)
        page.goto(f"{url}?fixedDpr=0.5")
        expect(page.get_by_text("Connected", exact=True)).to_be_visible()
        expect(page.get_by_text("Calibration Studio", exact=True)).to_be_visible()
        dismiss_webgl_warning(page)
        yield page
    finally:
        context.close()


def button(page: Page, name: str):
    """The page's button labelled exactly ``name``."""
    return page.get_by_role("button", name=name, exact=True)


def text_input(page: Page, label: str):
    """The text box of the GUI row labelled ``label`` (viser 1.1's text inputs are not tied to their label)."""
    row = page.locator(".mantine-Flex-root", has=page.locator("label", has_text=re.compile(f"^{re.escape(label)}$")))
    return row.locator("input").last


def choose(page: Page, label: str, option: str) -> None:
    """Pick ``option`` in the dropdown labelled ``label``."""
    box = page.get_by_label(label, exact=True)
    box.scroll_into_view_if_needed()
    box.click()
    choice = page.get_by_role("option", name=option, exact=True)
    choice.scroll_into_view_if_needed()  # the list can open partly off screen near the panel's bottom
    choice.click()
    expect(box).to_have_value(option)


def unfold(page: Page, folder: str, inside: Locator) -> None:
    """Unfold the GUI folder titled ``folder`` until ``inside`` shows; a click that lands while the page is still
    laying out the panel (slow on a loaded machine) is tried again. A folder already open (viser's default) is left
    so: a click would fold it, while ``inside`` still showed during the folding."""
    if inside.is_visible():
        return
    for _ in range(3):
        page.get_by_text(folder, exact=True).click()
        try:
            expect(inside).to_be_visible(timeout=10_000)
            return
        except AssertionError:
            continue
    expect(inside).to_be_visible()


COVERED_JS = """el => { el.scrollIntoView({block: "center"}); const r = el.getBoundingClientRect();
    const hit = document.elementFromPoint(r.x + r.width / 2, r.y + r.height / 2);
    return hit === null || !(el === hit || el.contains(hit)); }"""
"""Whether something else than the element (or a child of it) is under the element's centre (scrolled into view)."""


def assert_uncovered(row: Locator, timeout_s: float = UI_WAIT_S) -> None:
    """Fail unless ``row`` shows and, within ``timeout_s``, nothing covers its centre.

    A viser 1.1.1 folder (Mantine 9's ``Collapse``) that went empty and was filled again while a folder around it
    was closed stays at height 0 for good: its opening transition ran under ``display: none``, so no
    ``transitionend`` came to let it grow. Its rows are then "visible" to Playwright (they keep their own size) but
    the folder's frame covers them ("... mantine-Paper-root intercepts pointer events"), for a user too. A folder
    still opening covers its rows for a moment (seconds on a loaded machine), hence the wait."""
    expect(row).to_be_visible()
    poll(lambda: not row.evaluate(COVERED_JS), f"{row} is covered by its folder's frame (a folder stuck at height 0?)",
         timeout_s)


def close_toast(page: Page, title: str) -> None:
    """Close the notification titled ``title`` with its close button, as a user would rather than wait the 8 s it
    floats over the panel, and wait until it has gone."""
    toast = page.locator(".mantine-Notification-root", has=page.get_by_text(title, exact=True))
    toast.locator(".mantine-Notification-closeButton").click()
    expect(toast).to_have_count(0)


def wait_still(locator: Locator, timeout_s: float = UI_WAIT_S) -> None:
    """Wait until ``locator``'s box stops moving (an animation such as a notification sliding in has ended)."""
    steady(locator.bounding_box, f"{locator} still moving after {timeout_s:g} s", 1, 0.1, timeout_s)


def wait_settled(image: Locator, timeout_s: float = UI_WAIT_S, quiet_polls: int = 5) -> str:
    """Wait until ``image``'s source has stopped changing (the same blob URL over ``quiet_polls`` polls 0.2 s
    apart: the last redraw of a burst has landed); its source. viser swaps the blob URL on every update."""
    return steady(lambda: image.get_attribute("src"), f"the image kept changing for {timeout_s:g} s", quiet_polls,
                  0.2, timeout_s)


def wait_frame(page: Page) -> None:
    """Wait until the page has drawn its next animation frame (the 3D view's latest state is on screen)."""
    page.wait_for_function("() => new Promise(done => requestAnimationFrame(() => done(true)))")


def wait_body(page: Page, pattern: re.Pattern, timeout_s: float = UI_WAIT_S) -> re.Match:
    """Poll the page's text until ``pattern`` matches; fail with the text's tail after ``timeout_s``."""
    return poll(lambda: pattern.search(page.inner_text("body")),
                lambda: f"{pattern.pattern!r} never appeared:\n{page.inner_text('body')[-2000:]}", timeout_s, 0.5)


def wait_new_source(image: Locator, old_source: str | None, what: str, timeout_s: float = UI_WAIT_S) -> str:
    """Wait until ``image`` shows a new picture (viser swaps the blob URL on every update); the new source."""
    return poll(lambda: (source := image.get_attribute("src")) != old_source and source,
                f"the image did not change after {what}", timeout_s)


BLOB_BYTES_JS = """async img => {
    const bytes = new Uint8Array(await (await fetch(img.src)).arrayBuffer());
    let text = ""; for (const b of bytes) text += String.fromCharCode(b);
    return btoa(text);
}"""
"""The bytes of an <img>'s (blob) source, base64: the image as the server sent it, at full size."""


def labelled_image(page: Page, label: str) -> Locator:
    """The image under the GUI label ``label`` (viser puts the label in a <p> beside the image's box)."""
    return page.locator("div", has=page.locator("> p", has_text=re.compile(f"^{re.escape(label)}$"))).locator(
        "img").last


def decoded_image(image: Locator) -> np.ndarray:
    """The image an <img> shows, decoded at its full size (BGR)."""
    data = base64.b64decode(image.evaluate(BLOB_BYTES_JS))
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    assert decoded is not None, f"the image is not a JPEG/PNG ({len(data)} bytes)"
    return decoded
