"""``calib-studio depth-network SESSION_DIR [--solve] [--json]`` as a subprocess on a simulated one-node session: the
JSON contract of ../shared/conventions.md, the solve it runs, the verification rows, the text table and errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from backend.calib.depth import service
from backend.store.session import Session
from studio.cli import main
from tests.calib.depth.conftest import build_cell_session, pose_error
from tests.conftest import cli_subprocess

NODE = "sn4"


@pytest.fixture(scope="module")
def solved(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict]:
    folder = tmp_path_factory.mktemp("cli") / "cell"
    build_cell_session(folder, [NODE], seed=11)
    run = cli_subprocess("depth-network", folder, "--solve", "--json")
    assert run.returncode == 0, run.stderr
    return folder, json.loads(run.stdout)


@pytest.mark.slow
def test_solve_prints_the_contract(solved) -> None:
    _, body = solved
    assert {"nodes", "verification"} <= set(body)
    node = body["nodes"][NODE]
    assert {"T_world_node", "std", "verdict"} <= set(node)
    assert set(node["std"]) == {"trans_m", "rot_deg"} and all(len(v) == 3 for v in node["std"].values())
    assert set(node["verdict"]) == {"level", "reasons"} and node["verdict"]["level"] in ("trusted", "check")
    assert len(node["T_world_node"]) == 4 and all(len(row) == 4 for row in node["T_world_node"])
    trans_m, rot_deg = pose_error(node["T_world_node"], NODE)
    assert trans_m < 0.005 and rot_deg < 0.05, (trans_m, rot_deg)
    assert body["verification"] == []


@pytest.mark.slow
def test_verification_rows_the_text_table_and_errors(solved, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture) -> None:
    """In process (the subprocess above is the real command; these reuse its imports)."""
    folder, _ = solved
    added = service.verify_layout_distances(Session.load(folder))
    assert added, "sn4 sees both crosses of at least one measured distance"
    assert main(["depth-network", str(folder), "--json"]) == 0
    body = json.loads(capsys.readouterr().out)
    assert [set(r) >= {"a", "b", "measured_m", "estimated_m", "error_m"} for r in body["verification"]] == \
        [True] * len(added)
    assert all(abs(r["error_m"]) < 0.010 for r in body["verification"]), body["verification"]
    assert main(["depth-network", str(folder)]) == 0
    text = capsys.readouterr().out
    assert text.splitlines()[1].startswith(NODE) and f"{added[0]['a']:<14}{added[0]['b']:<14}" in text
    assert main(["depth-network", str(tmp_path / "nope"), "--json"]) != 0
    out, err = capsys.readouterr()
    assert set(json.loads(out)["error"]) == {"message", "input"} and err.strip().startswith("error:")
