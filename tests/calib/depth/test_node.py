"""The depth-node solvers on the simulated cell: features of a capture, the automatic six-DoF solve of every
node against the truth, what an undetermined solve says, and pairwise ICP as the worse baseline."""

from dataclasses import replace

import numpy as np
import pytest

from backend.calib.depth.features import DepthObservation, extract_features, feature_residuals
from backend.calib.depth.icp import icp_network, pairwise_icp
from backend.calib.depth.node import solve_depth_node
from backend.core.depth import KINECT_V2
from backend.core.depth_cell import PAPER_NODE_POSES, TableSpec, default_cell_layout
from backend.core.errors import InputError
from backend.core.transforms import apply_params, transform_error
from backend.sim.depth_cell import CellScene, node_pose, node_visibility, table_placements

ARRANGEMENTS = ("behind", "beside", "free")
"""Captures per node: three tables behind each other, three beside each other, none (floor and lines)."""
GUESS_OFF_M, GUESS_OFF_DEG = 0.05, 2.0
TOLERANCE_M, TOLERANCE_DEG = 0.005, 0.05
"""The issue's target: every node within 5 mm and 0.05 deg of the truth."""


def observe(scene: CellScene, node: str, arrangement: str, capture_id: str, seed: int,
            with_pixels: bool = True) -> DepthObservation:
    """One noisy capture of ``node`` as the solvers take it."""
    frame = scene.render(node_pose(node), np.random.default_rng(seed))
    points, index = KINECT_V2.unproject(frame.depth_m)
    tables = list(scene.layout.tables) if scene.placements else []
    return DepthObservation(capture_id, points, frame.amplitude.ravel()[index], index if with_pixels else None,
                            tables, arrangement)


def off_guess(T: np.ndarray, rng: np.random.Generator, off_m: float, off_deg: float) -> np.ndarray:
    """``T`` moved ``off_m`` and turned ``off_deg`` in random directions."""
    direction, axis = rng.normal(size=3), rng.normal(size=3)
    return apply_params(T, np.r_[off_m * direction / np.linalg.norm(direction),
                                 np.radians(off_deg) * axis / np.linalg.norm(axis)])


@pytest.fixture(scope="module")
def cell():
    """Every node's three captures (rendered once), its truth and a guess 5 cm / 2 deg off."""
    layout = default_cell_layout()
    empty = CellScene(layout, [])
    rng = np.random.default_rng(11)
    nodes = {}
    for k, node in enumerate(PAPER_NODE_POSES):
        scenes = {"behind": CellScene(layout, table_placements(node, "behind", layout)),
                  "beside": CellScene(layout, table_placements(node, "beside", layout)), "free": empty}
        nodes[node] = {"truth": node_pose(node),
                       "guess": off_guess(node_pose(node), rng, GUESS_OFF_M, GUESS_OFF_DEG),
                       "observations": [observe(scenes[a], node, a, f"c{i}", 100 * k + i)
                                        for i, a in enumerate(ARRANGEMENTS)],
                       "scenes": scenes}
    return {"layout": layout, "nodes": nodes, "empty": empty}


@pytest.fixture(scope="module")
def solved(cell):
    """The automatic solve of every node from its guess."""
    return {node: solve_depth_node(node, data["observations"], cell["layout"], data["guess"])
            for node, data in cell["nodes"].items()}


@pytest.mark.slow
def test_every_node_within_5_mm_and_0_05_deg(cell, solved):
    for node, result in solved.items():
        error_m, error_deg = transform_error(result.T_parent_child, cell["nodes"][node]["truth"])
        assert np.linalg.norm(error_m) < TOLERANCE_M, (node, error_m)
        assert np.linalg.norm(error_deg) < TOLERANCE_DEG, (node, error_deg)
        assert (result.kind, result.method, result.parent, result.child) == ("depth_node", "constraints", "world",
                                                                             node)
        assert result.converged and result.verdict.level != "reject", result.verdict.reasons
        assert all(s is not None and s < TOLERANCE_M for s in result.std["trans_m"])
        # honest sigmas: every axis's error within 4 of its 1-sigma (the tape lines' pixel sampling included)
        assert (np.abs(np.r_[error_m, np.radians(error_deg)]) < 4 * result.std_vector).all(), (node, error_m)
        # the floor and tables fit to their known heights within the noise, every capture's
        rows = result.diagnostics["features"]
        assert all(abs(r["error_m"]) < 0.003 for r in rows if r["kind"] in ("floor", "table")), node
        assert {r["capture_id"] for r in rows} == {"c0", "c1", "c2"}
        assert result.residuals["n_captures"] == 3 and result.residuals["line_rms_m"] < 0.03


@pytest.mark.slow
def test_features_of_a_capture_at_a_tape_measure_guess(cell):
    """From a guess 10 cm / 5 deg off: the floor, the three tables (named near to far), the lines the node
    sees over more than a metre, and whole crosses, each matching the truth."""
    data = cell["nodes"]["sn4"]
    guess = off_guess(data["truth"], np.random.default_rng(3), 0.10, 5.0)
    features, problems = extract_features(data["observations"][0], guess, cell["layout"])
    assert problems == []
    rows = {r["name"]: r for r in feature_residuals(features, data["truth"])}
    assert {"table1@c0", "table2@c0", "table3@c0", "floor"} <= set(rows)
    assert all(abs(rows[n]["error_m"]) < 0.003 for n in ("floor", "table1@c0", "table2@c0", "table3@c0"))
    ranges = [np.linalg.norm(f.points.mean(axis=0)) for f in features if f.kind == "table"]
    assert ranges == sorted(ranges)  # behind each other: named near to far
    seen = node_visibility(data["scenes"]["behind"], data["truth"])
    assert {n for n, length in seen["lines"].items() if length > 1.0} <= {r["name"] for r in rows.values()
                                                                         if r["kind"] == "line"}
    assert all(abs(r["error_m"]) < 0.005 for r in rows.values() if r["kind"] == "line")
    crosses = [r for r in rows.values() if r["kind"] == "point"]
    assert crosses and all(r["error_m"] < 0.02 for r in crosses)


@pytest.mark.slow
def test_tables_without_pixel_index(cell):
    """Without the image structure the tables are cut apart by DBSCAN instead, to the same heights."""
    obs = observe(cell["nodes"]["sn1"]["scenes"]["beside"], "sn1", "beside", "c9", 7, with_pixels=False)
    features, problems = extract_features(obs, cell["nodes"]["sn1"]["truth"], cell["layout"])
    tables = [r for r in feature_residuals(features, cell["nodes"]["sn1"]["truth"]) if r["kind"] == "table"]
    assert problems == [] and len(tables) == 3
    assert all(abs(r["error_m"]) < 0.003 for r in tables)


@pytest.mark.slow
def test_missing_table_and_empty_depth_are_problems(cell):
    obs = cell["nodes"]["sn2"]["observations"][0]
    extra = replace(obs, tables=[*obs.tables, TableSpec("table9", 1.10)])
    _, problems = extract_features(extra, cell["nodes"]["sn2"]["truth"], cell["layout"])
    assert problems == ["table9 not found in capture c0 (no horizontal plane 1.10 +- 0.15 m above the floor)"]
    empty = replace(obs, points=obs.points[:50], amplitude=obs.amplitude[:50], pixel_index=obs.pixel_index[:50])
    features, problems = extract_features(empty, cell["nodes"]["sn2"]["truth"], cell["layout"])
    assert features == [] and "empty" in problems[0]
    with pytest.raises(InputError, match="nothing to solve from"):
        solve_depth_node("sn2", [empty], cell["layout"], cell["nodes"]["sn2"]["truth"])


@pytest.mark.parametrize(("lines", "message"), [
    ((), "no floor line seen: X, Y and RotZ are not determined"),
    (("x2", "x7"), r"no floor line Y = const seen \(only X = 2 m, X = 7 m\): Y is not determined"),
])
@pytest.mark.slow
def test_undetermined_solve_names_what_is_missing(cell, lines, message):
    layout = cell["layout"]
    partial = replace(layout, lines=[ln for ln in layout.lines if ln.name in lines])
    data = cell["nodes"]["sn4"]
    with pytest.raises(InputError, match=message):
        solve_depth_node("sn4", data["observations"][2:], partial, data["guess"])


@pytest.mark.slow
def test_surveyed_crosses_fix_the_position_without_lines(cell):
    """Crosses surveyed in the cell's frame are known points: with no tape line, they fix X, Y and RotZ."""
    layout = cell["layout"]
    surveyed = replace(layout, lines=[], crosses=[replace(c, surveyed=True) for c in layout.crosses])
    data = cell["nodes"]["sn4"]
    result = solve_depth_node("sn4", data["observations"][2:], surveyed, data["guess"])
    error_m, error_deg = transform_error(result.T_parent_child, data["truth"])
    assert np.linalg.norm(error_m) < 0.01 and np.linalg.norm(error_deg) < 0.05, (error_m, error_deg)
    assert (np.abs(np.r_[error_m, np.radians(error_deg)]) < 4 * result.std_vector).all()
    assert len(result.diagnostics["crosses"]) >= 3 and result.verdict.level != "reject"
    assert not any("cross-check crosses" in reason for reason in result.verdict.reasons)  # used, so no check


@pytest.mark.slow
def test_pairwise_icp_alone_is_far_worse(cell, solved):
    """The paper's finding: the nodes' views share mostly floor, so ICP chained from sn1 (held at the truth)
    slides; the constraint solve of the same nodes is millimetres. Its edges' verdicts say they are undetermined."""
    nodes = ("sn1", "sn3", "sn5")
    clouds = {n: cell["nodes"][n]["observations"][2].points for n in nodes}
    poses, edges = icp_network("sn1", cell["nodes"]["sn1"]["truth"], clouds,
                               {n: cell["nodes"][n]["guess"] for n in nodes})
    assert [(e.parent, e.child) for e in edges] and {e.child for e in edges} == {"sn3", "sn5"}
    icp_worst = max(np.linalg.norm(transform_error(poses[n], cell["nodes"][n]["truth"])[0]) for n in nodes[1:])
    solve_worst = max(np.linalg.norm(transform_error(solved[n].T_parent_child, cell["nodes"][n]["truth"])[0])
                      for n in nodes[1:])
    assert icp_worst > 0.05 and icp_worst > 20 * solve_worst, (icp_worst, solve_worst)
    assert all(e.kind == "depth_node" and e.method == "icp" and e.verdict.level == "reject" for e in edges)


@pytest.mark.slow
def test_pairwise_icp_refuses_bad_clouds(cell):
    with pytest.raises(InputError, match="points of sn3"):
        pairwise_icp("sn1", np.zeros((500, 3)), "sn3", np.zeros((5, 3)), np.eye(4), np.eye(4))
