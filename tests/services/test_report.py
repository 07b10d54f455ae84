"""The calibration report: every section with the records' own numbers, plots inline, nothing fetched."""

from __future__ import annotations

import base64
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient
from markupsafe import escape

from backend.api.app import create_app
from backend.calib._session import store_cloud
from backend.calib.intrinsics import service as intrinsics_service
from backend.calib.intrinsics.solver import IntrinsicsSettings
from backend.calib.lidar_camera import service as lidar_camera_service
from backend.calib.lidar_lidar import service as lidar_lidar_service
from backend.calib.rig import service as rig_service
from backend.devices.base import create_device
from backend.reports.gather import camera_report, gather
from backend.reports.template import SECTIONS, fixed, number
from backend.services.report import render_report
from backend.store.session import Session, SessionStore
from studio.cli import main
from tests.conftest import built_once, fresh_demo

pytestmark = pytest.mark.slow


def build_report_session(template: Path, root: Path, *, lidar_camera: bool = True) -> Session:
    """A copy of the demo in ``root`` with its cam_front intrinsics solved again and accepted through the rig
    service, a LiDAR-LiDAR edge (lidar_front into lidar_top, from one fresh scan of each) and, if asked, the
    target LiDAR-camera edge of the demo's pairs (cam_front, lidar_top), all accepted."""
    shutil.copytree(template, root)
    session = SessionStore(root).get("demo")
    result_id, _ = intrinsics_service.solve_session(session, "cam_front", IntrinsicsSettings())
    rig_service.accept(session, result_id, confirm=True)
    scans = {}
    for lidar in ("lidar_front", "lidar_top"):
        settings = {k: v for k, v in session.rig.get(lidar).device.items() if k not in ("board_poses", "board_hold_s")}
        with create_device(settings) as device:
            scans[lidar] = store_cloud(session, lidar, device.read(), device=device.describe()).id
    result_id, _ = lidar_lidar_service.solve_session(session, "lidar_front", "lidar_top",
                                                     pairs=[(scans["lidar_front"], scans["lidar_top"])])
    rig_service.accept(session, result_id, confirm=True)
    if lidar_camera:
        result_id, _ = lidar_camera_service.solve_session(session, "cam_front", "lidar_top", method="target")
        rig_service.accept(session, result_id, confirm=True)
    return session


def report_template(demo_template: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder holding :func:`build_report_session`'s sessions folder (``sessions``) and its report
    (``report.html``), built once per run (:func:`~tests.conftest.built_once`) for this module and the browser's."""
    def build(folder: Path) -> None:
        (folder / "report.html").write_text(render_report(build_report_session(demo_template, folder / "sessions")))

    return built_once(tmp_path_factory, "report_template", build)


@pytest.fixture(scope="module")
def template(demo_template: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return report_template(demo_template, tmp_path_factory)


@pytest.fixture(scope="module")
def session(template: Path, tmp_path_factory: pytest.TempPathFactory) -> Session:
    """A copy of the template's session, for the module to read and write."""
    return SessionStore(fresh_demo(template / "sessions", tmp_path_factory.mktemp("report") / "sessions")).get("demo")


@pytest.fixture(scope="module")
def html(template: Path) -> str:
    """:func:`~backend.services.report.render_report` of the template's session."""
    return (template / "report.html").read_text()


def accepted(session: Session, kind: str) -> dict:
    (record,) = [session.result(r) for r in session.accepted_slots().values() if session.result(r)["kind"] == kind]
    return record


def section(html: str, section_id: str) -> str:
    """The HTML of one ``<section id=...>``, each run of white space as one space (as a browser shows it)."""
    match = re.search(rf'<section id="{section_id}">(.*?)</section>', html, re.S)
    assert match, f"no section {section_id!r}"
    return re.sub(r"\s+", " ", match.group(1))


def test_every_section_is_there_in_order(html: str) -> None:
    positions = [html.index(f'<section id="{section_id}">') for section_id, _ in SECTIONS]
    assert positions == sorted(positions)
    for section_id, title in SECTIONS:
        assert f"<h2>{title}</h2>" in section(html, section_id)


def test_intrinsics_section_holds_the_accepted_numbers(session: Session, html: str) -> None:
    record = accepted(session, "intrinsics")
    text = section(html, "intrinsics")
    assert record["id"] in text and "cam_front" in text
    used = sum(v["used"] for v in record["views"])
    assert f"{used} of {len(record['views'])} views used" in text
    assert f"{fixed(record['rms_px'], 4)} px" in text
    assert number(record["camera"]["K"][0][0], 6) in text and number(record["std"]["fx"], 3) in text
    assert f"max {fixed(record['projection_sigma_px']['max'], 3)} px" in text
    assert f"{record['rejected_corners']} rejected as outliers" in text
    projection, flex = record["projection_uncertainty"], record["board_flex"]
    assert (f"worst {fixed(projection['max_covered_px'], 3)} px where the boards reach "
            f"({round(100 * projection['covered_share'])} % of the image)") in " ".join(text.split())
    assert flex["status"] == "solved"
    assert (f"x {fixed(flex['warp_mm'][0], 3)} ± {fixed(flex['std_mm'][0], 3)} mm, y "
            f"{fixed(flex['warp_mm'][1], 3)} ± {fixed(flex['std_mm'][1], 3)} mm") in " ".join(text.split())
    assert record["cross_validation"]["status"] in text
    assert f'badge {record["verdict"]["level"]}' in text
    for reason in record["verdict"]["reasons"]:
        assert str(escape(reason)) in text
    assert "cam_wide: no intrinsics solve yet" in text  # the demo leaves it for the user
    assert text.count('<img src="data:image/svg+xml;base64,') == 4  # RMS bars, vectors, coverage, maps


def test_every_accepted_edge_has_its_section(session: Session, html: str) -> None:
    tree = rig_service.solve_rig(session)
    measured = [r for r in tree.edges if r.edge.kind != "prior"]
    assert {r.edge.kind for r in measured} == {"lidar_lidar", "lidar_camera"}
    text = section(html, "edges")
    for residual in measured:
        record = session.result(residual.edge.result_id)
        assert f"{residual.edge.parent} &rarr; {residual.edge.child}: {residual.edge.kind}" in text
        assert f"{record['id']} (slot {residual.edge.slot})" in text
        assert f"{fixed(residual.trans_m, 2, 1000)} mm, {fixed(residual.rot_deg, 3)}" in text
        std = record["std"]
        assert ", ".join(fixed(v, 2, 1000) for v in std["trans_m"]) + " mm" in text
        for reason in record["verdict"]["reasons"]:
            assert str(escape(reason)) in text
    lidar_lidar = accepted(session, "lidar_lidar")
    assert f"{len(lidar_lidar['inputs'])} cloud pair(s): {lidar_lidar['inputs'][0]}" in text
    assert number(lidar_lidar["residuals"]["fitness"]) in text
    assert "Cloud-to-cloud distances recomputed" in text
    lidar_camera = accepted(session, "lidar_camera")
    assert f"{len(lidar_camera['inputs'])} image + cloud pair(s)" in text


def test_rig_section_lists_every_graph_edge_and_frame(session: Session, html: str) -> None:
    tree = rig_service.solve_rig(session)
    rig_text, sensors_text = section(html, "rig"), section(html, "sensors")
    assert rig_text.count("<tr><td>") == len(tree.edges)
    for name, frame in tree.frames.items():
        assert f"<td><b>{name}</b></td>" in sensors_text
        assert f'<td class="n">{fixed(frame.T_parent_child[0, 3], 4)}</td>' in sensors_text
    assert f'<td class="n">{len(session.captures("cam_front"))}</td>' in sensors_text
    overview = section(html, "overview")
    assert f"<td>{len(session.accepted_slots())}</td>" in overview
    assert f"{len([r for r in tree.edges if r.edge.kind != 'prior'])} (and" in overview


def test_plots_are_inline_svg_and_nothing_is_fetched(html: str) -> None:
    images = re.findall(r'<img src="([^"]+)"', html)
    assert len(images) == 4 + 3 + 2  # the camera's; LiDAR-LiDAR C2C, LiDAR-camera per-pose bars and poses; graph, rig
    for src in images:
        assert src.startswith("data:image/svg+xml;base64,")
        assert b"<svg" in base64.b64decode(src.split(",", 1)[1])[:2000]
    outside = re.sub(r'src="data:[^"]+"', "", html)
    assert not re.search(r'(src|href)="(?!#)|url\(|@import', outside)
    assert "default-src 'none'" in html


def test_a_target_edge_shows_each_pose_at_the_result(session: Session, html: str) -> None:
    (edge,) = [e for e in gather(session).edges if e.result.kind == "lidar_camera"]
    fits = edge.result.diagnostics["poses"]
    assert [p.name for p in edge.poses] == [fit["name"] for fit in fits] == edge.record["inputs"]
    for pose, fit in zip(edge.poses, fits, strict=True):
        assert pose.fit == fit and pose.missing is None
        # found again at the result as the solve found them: the demo's points on its plate, within its outline
        assert abs(len(pose.face_board) - fit["plane_points"]) <= 0.05 * fit["plane_points"]
        assert np.sqrt(np.mean(pose.face_board[:, 2] ** 2)) == pytest.approx(fit["plane_rms_m"], rel=0.1)
        inside = np.all(np.abs(pose.face_board[:, :2] - pose.plate_centre) <= pose.plate_half + 0.01, axis=1)
        assert inside.mean() > 0.97  # 0.986 at worst: a few points of a tilted ring at a corner
        assert len(pose.edges_board) == fit["edge_points"]
    assert edge.result.diagnostics["plate_margin_m"] == pytest.approx(0.04, abs=0.01)  # one square, estimated
    assert 'alt="per-pose evidence"' in section(html, "edges")


def test_residuals_missing_from_a_record_are_recomputed(session: Session) -> None:
    record = accepted(session, "intrinsics")
    stored = camera_report(session, record)
    stripped = {**record, "views": [{k: v for k, v in view.items() if k != "residuals_px"} for view in record["views"]]}
    recomputed = camera_report(session, stripped)
    kept = [(a, b) for a, b in zip(stored.views, recomputed.views, strict=True) if b.residuals_px is not None]
    assert kept and all(b.recomputed for _, b in kept)
    for a, b in kept:
        np.testing.assert_allclose(b.residuals_px, a.residuals_px, atol=2e-3)
        assert np.sqrt(np.mean(np.sum(b.residuals_px**2, axis=1))) == pytest.approx(a.rms_px, rel=0.02)


def test_cloud_to_cloud_distances_agree_with_the_solve(session: Session) -> None:
    (edge,) = [e for e in gather(session).edges if e.result.kind == "lidar_lidar"]
    c2c = edge.result.residuals["c2c_m"]
    assert edge.c2c_m.max() <= edge.result.settings["max_correspondence_m"]
    assert edge.c2c_m.mean() == pytest.approx(c2c["mean"], rel=0.05)
    assert np.median(edge.c2c_m) == pytest.approx(c2c["median"], rel=0.05)


def test_an_empty_session_renders_and_its_text_is_escaped(tmp_path: Path) -> None:
    session = SessionStore(tmp_path).create("bare", title="<script>alert(1)</script> & co")
    page = render_report(session)
    assert "<script>" not in page and "&lt;script&gt;alert(1)&lt;/script&gt; &amp; co" in page
    assert "No camera has accepted intrinsics." in page
    assert "the rig holds only its mounting priors" in page


def test_api_serves_the_report_as_a_download(session: Session) -> None:
    with TestClient(create_app(session.path.parent)) as client:
        response = client.get("/api/sessions/demo/report")
        assert response.status_code == 200
        assert response.headers["content-type"].startswith("text/html")
        assert 'filename="demo-report.html"' in response.headers["content-disposition"]
        for _, title in SECTIONS:
            assert f"<h2>{title}</h2>" in response.text
        missing = client.get("/api/sessions/nosuch/report")
        assert missing.status_code == 404 and "nosuch" in missing.json()["error"]["message"]


def test_cli_writes_the_report(session: Session, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "report.html"
    assert main(["report", str(session.path), "--out", str(out)]) == 0
    text = out.read_text()
    assert text.startswith("<!DOCTYPE html>") and accepted(session, "intrinsics")["id"] in text
    assert main(["report", str(session.path), "--out", str(tmp_path / "no" / "report.html")]) == 2
    assert "error:" in capsys.readouterr().err
    assert main(["report", str(tmp_path / "nosession"), "--out", str(out)]) == 2
