"""The guided procedure's advice on the simulated cell: the four steps in order reach 10 mm, and each step says
what stops it (no such capture, tables at one distance, an unknown step)."""

from dataclasses import replace

import numpy as np
import pytest

from backend.calib.depth.features import DepthObservation
from backend.calib.depth.guided import GUIDED_STEPS, advise
from backend.core.depth import KINECT_V2, pose_from_row, pose_row
from backend.core.depth_cell import default_cell_layout
from backend.core.errors import InputError
from backend.core.transforms import transform_error
from backend.sim.depth_cell import CellScene, node_pose, table_placements

NODES = ("sn1", "sn4")
TARGET_M = 0.010
"""The issue's target for the guided procedure: within 10 mm."""


@pytest.fixture(scope="module")
def cell():
    """Two nodes' captures (tables behind, beside, none), rendered once, and a tape-measure guess of each: every
    pose-row value off by about 5 cm or 2 deg."""
    layout = default_cell_layout()
    rng = np.random.default_rng(21)
    nodes = {}
    for k, node in enumerate(NODES):
        observations = []
        for i, arrangement in enumerate(("behind", "beside", "free")):
            placements = table_placements(node, arrangement, layout) if arrangement != "free" else []
            frame = CellScene(layout, placements).render(node_pose(node), np.random.default_rng(10 * k + i))
            points, index = KINECT_V2.unproject(frame.depth_m)
            observations.append(DepthObservation(f"c{i}", points, frame.amplitude.ravel()[index], index,
                                                 list(layout.tables) if placements else [], arrangement))
        row = np.array(pose_row(node_pose(node))) + np.r_[rng.normal(0, 0.05, 3), rng.normal(0, 2.0, 3)]
        nodes[node] = {"observations": observations, "guess": pose_from_row(row)}
    return {"layout": layout, "nodes": nodes}


@pytest.mark.slow
def test_four_steps_in_order_reach_10_mm(cell):
    for node, data in cell["nodes"].items():
        T = data["guess"]
        for _ in range(2):  # a second pass takes out what each tilt left of the other
            for step in GUIDED_STEPS:
                advice = advise(step, data["observations"], cell["layout"], T)
                assert not advice.problems, (node, step, advice.problems)
                T = advice.T_suggested
        error_m, error_deg = transform_error(T, node_pose(node))
        assert np.linalg.norm(error_m) < TARGET_M, (node, error_m)
        assert np.linalg.norm(error_deg) < 0.05, (node, error_deg)
        if node == NODES[0]:  # once is enough: every step's criterion holds at the pose reached
            final = {step: advise(step, data["observations"], cell["layout"], T) for step in GUIDED_STEPS}
            assert all(advice.done for advice in final.values()), node
            assert all(abs(r["error_m"]) <= 0.005 for r in final["tables_behind"].residuals)


def test_each_step_changes_its_own_fields_in_order(cell):
    data = cell["nodes"]["sn1"]
    T = data["guess"]
    changed = {}
    for step in GUIDED_STEPS:
        advice = advise(step, data["observations"], cell["layout"], T)
        changed[step] = list(advice.suggestion)
        assert advice.criterion and advice.why
        assert np.allclose(advice.T_suggested, pose_from_row([advice.suggestion.get(c, v) for c, v in
                                                              zip(("X", "Y", "Z", "RotZ", "RotY", "RotX"),
                                                                  pose_row(T), strict=True)]))
        T = advice.T_suggested
    assert changed == {"initial": [], "tables_behind": ["RotX", "Z"], "tables_beside": ["RotY", "Z"],
                       "lines": ["RotZ", "X", "Y"]}
    behind = advise("tables_behind", data["observations"], cell["layout"], data["guess"])
    assert not behind.done and {r["name"] for r in behind.residuals} == {"table1@c0", "table2@c0", "table3@c0"}


def test_missing_evidence_is_named(cell):
    data = cell["nodes"]["sn4"]
    layout = cell["layout"]
    only_free = data["observations"][2:]
    advice = advise("tables_behind", only_free, layout, data["guess"])
    assert advice.suggestion == {} and not advice.done
    assert advice.problems == ["no capture with tables behind each other (bottom, middle and top of the view): "
                               "stand three tables so and capture"]
    # tables standing beside each other, declared as behind: one distance, no leverage on RotX
    beside_as_behind = [replace(data["observations"][1], arrangement="behind")]
    advice = advise("tables_behind", beside_as_behind, layout, data["guess"])
    assert advice.suggestion == {} and any("no leverage on RotX" in p for p in advice.problems)
    no_lines = replace(layout, lines=[])
    advice = advise("lines", only_free, no_lines, data["guess"])
    assert advice.suggestion == {} and advice.problems[-1].startswith("no floor line seen")
    with pytest.raises(InputError, match="unknown guided step"):
        advise("tables_diagonal", only_free, layout, data["guess"])
