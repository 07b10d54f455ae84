"""The result card every step shows: which exports carry a solved lens, said with the result, and *Accept* that
previews (a reject too, saying why it cannot be accepted) before *Confirm accept*, each button keeping its label."""

from __future__ import annotations

import numpy as np
import viser

from backend.core.rig import Frame
from backend.services.jobs import JobRunner
from backend.sim.demo_rig import CAM_WIDE
from backend.store.session import SessionStore
from studio.context import StudioContext
from studio.result_card import ResultCard, card_markdown
from studio.scene import RigScene


def intrinsics_record(k3: float, level: str) -> dict:
    camera = CAM_WIDE.to_dict() | {"dist": [-0.28, 0.09, 0.0005, -0.0003, k3]}
    return {"id": "r0001", "sensor": "cam_wide", "kind": "intrinsics", "camera": camera, "rms_px": 0.2,
            "verdict": {"level": level, "reasons": ["a test record"]}, "converged": True, "seconds": 1.0}


def test_the_card_says_which_exports_carry_the_lens():
    with_k3 = card_markdown(intrinsics_record(-0.03, "trusted"), None)
    assert "Exports that carry this lens: camera_info, opencv" in with_k3
    assert "- not kalibr: cam_wide: k3 = -0.03 moves the farthest image corner by" in with_k3
    assert "Exports that carry this lens: camera_info, opencv, camera-json, mrcal, kalibr" in card_markdown(
        intrinsics_record(0.0, "trusted"), None)
    photogrammetric = intrinsics_record(0.0, "trusted")
    photogrammetric["camera"] |= {"model": "photogrammetric", "dist": [-1e-6, 0, 0, 0, 0, 1e-4, 0]}
    card = card_markdown(photogrammetric, None)
    assert "Exports that carry this lens: opencv, camera-json\n" in card
    assert "- not mrcal: mrcal's .cameramodel cannot carry the photogrammetric model" in card
    assert "- not camera_info: camera_info cannot carry the photogrammetric model" in card
    assert "- not kalibr: cam_wide: Kalibr's camchain cannot carry the photogrammetric model" in card


def test_accept_previews_first_and_a_reject_is_previewed_then_refused(tmp_path, free_port):
    store = SessionStore(tmp_path)
    session = store.create("s")
    session.add_sensor(Frame("cam_wide", "base_link", kind="camera"))
    record = intrinsics_record(0.0, "reject")
    record["id"] = session.add_result("cam_wide", {k: v for k, v in record.items() if k not in ("id", "sensor")},
                                      inputs=[])
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    jobs = JobRunner()
    try:
        ctx = StudioContext(server, store, jobs, RigScene(server))
        ctx.session = session
        card = ResultCard(ctx)
        assert card.accept_button.disabled  # no result yet: nothing to accept
        card.show(session.result(record["id"]), None)
        assert not card.accept_button.disabled  # a reject is previewed, to say why it cannot be accepted
        card.preview()
        assert f"Accepting {record['id']} would:" in card.preview_text.content
        assert "It cannot be accepted: its verdict is reject (a test record)." in card.preview_text.content
        assert not card.apply_button.visible and card.accept_button.label == "Accept"
        card.accept()  # nothing previewed that can be accepted: nothing happens
        assert session.accepted("cam_wide/intrinsics") is None and session.acceptance_log == []
        np.testing.assert_equal(session.rig.get("cam_wide").intrinsics, None)
        card.show(None, None)
        assert card.accept_button.disabled
    finally:
        jobs.shutdown()
        server.stop()


def test_the_intrinsics_panel_gives_the_photogrammetric_parameters_in_px_and_mm():
    """The step's parameter table of a photogrammetric solve (a simulated Blackfly's, at its 4.8 um pixels)."""
    from backend.calib.intrinsics.solver import IntrinsicsSettings, calibrate_intrinsics
    from studio.wizard.intrinsics_step import parameters_markdown
    from tests.calib.intrinsics.test_photogrammetric import BOARD, noisy_views

    result = calibrate_intrinsics(noisy_views(8, 2), BOARD, (1280, 1024), IntrinsicsSettings(
        model="photogrammetric", pixel_size_um=4.8, jackknife=False, cross_validate=False))
    table = parameters_markdown(result.to_record())
    assert "| param | in px | σ | in mm | σ |" in table
    c = result.photogrammetric["parameters"]["c"]
    assert f"| c | {c['value_px']:.6g} px | {c['sigma_px']:.2g} | {c['value_mm']:.6g} mm |" in table
    assert "| K1 | " in table and " px⁻² | " in table and " mm⁻² | " in table
    assert "Pixel size 4.8 µm; in mm, xp and yp are from the image centre." in table
    assert "As OpenCV's pinhole-radtan: within " in table and "Interior–exterior correlations above 0.9" in table
