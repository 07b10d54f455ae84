"""Verdicts: the builder's levels and reasons, records without one, and the session's acceptance rules (a
'reject' is refused, a 'check' needs a confirmation that the log records); the sweep's verdict on doctored
results."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from backend.calib.sweep.checks import sweep_verdict
from backend.core.errors import InputError
from backend.core.rig import Frame, Rig
from backend.core.verdict import NO_VERDICT_REASON, Verdict, VerdictBuilder, judge_transform_sigmas
from backend.store.session import Session


def test_trusted_needs_sigmas_within_tolerance_and_a_passed_cross_check():
    judge = VerdictBuilder()
    judge_transform_sigmas(judge, {"trans_m": [0.001, 0.002, 0.003], "rot_deg": [0.01, 0.02, 0.05]})
    judge.cross_check("two halves", True, "they agree within 1.2 sigma")
    verdict = judge.verdict()
    assert verdict.level == "trusted"
    assert verdict.reasons[0] == "translation sigma 3 mm is within the tolerance 10 mm"
    assert verdict.reasons[-1] == "cross-check two halves: they agree within 1.2 sigma"


def test_no_cross_check_is_never_trusted_and_says_which_is_missing():
    judge = VerdictBuilder()
    judge.sigma("fx", 0.5, 1.0, "px")
    assert judge.verdict() == Verdict("check", ["fx sigma 0.5 px is within the tolerance 1 px",
                                                "no independent cross-check was made"])
    judge = VerdictBuilder()
    judge.missing_check("across scenes", "only one scene")
    assert judge.verdict() == Verdict("check", ["no cross-check across scenes: only one scene"])


def test_loose_and_undetermined_sigmas_and_failed_checks():
    judge = VerdictBuilder()
    judge.cross_check("halves", True, "ok")
    judge.sigma("rotation", 0.3, 0.2, "deg")
    assert judge.verdict().level == "check"
    judge.sigma("translation", None, 10, "mm")
    assert judge.verdict().level == "reject"
    assert "translation is not determined by the data (no finite sigma)" in judge.verdict().reasons
    judge = VerdictBuilder()
    judge.sigma("rotation", 2.5, 0.2, "deg")  # beyond 10x the tolerance
    assert judge.verdict().level == "reject"
    judge = VerdictBuilder()
    judge.cross_check("another method", False, "they differ by 9 sigma", fail_level="reject")
    assert judge.verdict().level == "reject"


@pytest.mark.parametrize(("sigmas", "level"), [(0.4, "trusted"), (3.0, "trusted"), (3.01, "check"), (5.0, "check"),
                                               (5.9, "reject"), (float("inf"), "reject"), (float("nan"), "reject")])
def test_the_cross_check_rule(sigmas, level):
    """Within 3 of its sigmas a cross-check passes; failed by up to 5 it is 'check', beyond (or undetermined)
    'reject': the rule every problem's verdict uses (the README's)."""
    judge = VerdictBuilder()
    judge.cross_check_sigmas("leave one of the poses out", sigmas, "the re-solves spread")
    verdict = judge.verdict()
    assert verdict.level == level
    assert verdict.reasons[0].startswith("cross-check leave one of the poses out" + (":" if level == "trusted"
                                                                                     else " failed:"))
    assert f"({sigmas:.1f} sigma" in verdict.reasons[0]


def test_records_without_a_verdict_and_per_camera_verdicts():
    assert Verdict.from_record({}) == Verdict("check", [NO_VERDICT_REASON])
    assert Verdict.from_record({"verdict": {"level": "maybe"}}).level == "check"
    per_camera = {"verdict": {"a": {"level": "trusted", "reasons": ["fine"]},
                              "b": {"level": "check", "reasons": ["loose"]}}}
    assert Verdict.from_record(per_camera) == Verdict("check", ["a: fine", "b: loose"])


def _apply(rig: Rig, record: dict) -> None:
    rig.get("cam").T_parent_child = np.array(record["T"])


def _session_with(tmp_path, level: str | None) -> tuple[Session, str]:
    rig = Rig()
    rig.add(Frame("cam", "base_link", np.eye(4), kind="camera"))
    session = Session.create(tmp_path / "s", "s", rig)
    T = np.eye(4)
    T[0, 3] = 0.5
    record = {"kind": "test", "T": T.tolist()}
    if level is not None:
        record["verdict"] = {"level": level, "reasons": [f"judged {level}"]}
    return session, session.add_result("cam", record, inputs=[])


def test_session_refuses_a_reject_and_wants_confirmation_for_a_check(tmp_path):
    session, result_id = _session_with(tmp_path, "reject")
    with pytest.raises(InputError, match="judged 'reject' and cannot be accepted: judged reject") as refused:
        session.accept("cam/test", result_id, _apply, confirm=True)
    assert refused.value.status_code == 409 and session.accepted("cam/test") is None
    assert session.rig.get("cam").T_parent_child[0, 3] == 0.0

    session, result_id = _session_with(tmp_path / "2", "check")
    with pytest.raises(InputError, match="judged 'check' \\(judged check\\); confirm") as refused:
        session.accept("cam/test", result_id, _apply)
    assert refused.value.input == "confirm" and session.accepted("cam/test") is None
    session.accept("cam/test", result_id, _apply, confirm=True)
    assert session.accepted("cam/test") == result_id and session.rig.get("cam").T_parent_child[0, 3] == 0.5
    entry = Session.load(session.path).acceptance_log[-1]
    assert (entry.verdict, entry.confirmed) == ("check", True)


def test_a_trusted_result_is_accepted_without_confirmation(tmp_path):
    session, result_id = _session_with(tmp_path, "trusted")
    session.accept("cam/test", result_id, _apply)
    assert (session.acceptance_log[-1].verdict, session.acceptance_log[-1].confirmed) == ("trusted", False)


def _sweep(**changes) -> SimpleNamespace:
    result = SimpleNamespace(converged=True, rms_before_m=0.02, rms_after_m=0.004,
                             estimated=["offset_u_m", "tilt_u_rad"],
                             parameter_std={"offset_u_m": 0.0005, "tilt_u_rad": np.radians(0.02)},
                             covariance=np.eye(2) * 1e-8,
                             halves_difference=np.array([0.0004, np.radians(0.01)]),
                             halves_std=np.array([0.0007, np.radians(0.03)]))
    return SimpleNamespace(**(vars(result) | changes))


def test_sweep_verdict_weighs_sigmas_and_the_halves():
    assert sweep_verdict(_sweep()).level == "trusted"
    disagree = sweep_verdict(_sweep(halves_difference=np.array([0.0028, 0.0])))  # 4 sigma: beyond 3
    assert disagree.level == "check" and "differ most in offset u (4.0 sigma" in disagree.reasons[-1]
    far = sweep_verdict(_sweep(halves_difference=np.array([0.004, 0.0])))  # 5.7 sigma: beyond 5
    assert far.level == "reject" and "differ most in offset u (5.7 sigma" in far.reasons[-1]
    assert sweep_verdict(_sweep(halves_difference=None)).reasons[-1].startswith("no cross-check of the sweep's halves")
    assert sweep_verdict(_sweep(parameter_std={"offset_u_m": 0.003, "tilt_u_rad": 0.0})).level == "check"
    assert sweep_verdict(_sweep(converged=False)).level == "reject"
    assert sweep_verdict(_sweep(rms_after_m=0.03)).level == "reject"
