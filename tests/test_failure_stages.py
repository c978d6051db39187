"""Every failure traced to the stage it failed in (docs/DESIGN.md, "Trial end"): crafted situations on
``tiny`` where each system fails in a known stage, checked through the trial record's
``failure_stage`` and ``detail``; the stage of the endings the runner decides; the summary's counts
and Table 1's text.

The maps are crafted from the ground truth, so the answer is known: the baseline's map is the GT
raster (a room sealed, a cabinet left out, or no wall at all); NavTopo's graph is made of locations
whose grids are true scans at known poses (two locations left unjoined, or a wall stamped across
the corridor between them, or a location that is nowhere in the building).
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import faulty_system  # noqa: F401 - registers the "faulty" system in this process
import numpy as np
import pytest
from crafted_run import write_crafted_run

from baselines.metric_grid.map_folder import FORMAT, MANIFEST, MAP_YAML
from baselines.metric_grid.occupancy import GridMap
from baselines.metric_grid.system import MetricGrid, MetricGridConfig
from navkit import geometry as se2
from navkit.raster import FREE, OCCUPIED, UNKNOWN
from navkit.scan_grid import GridConfig, grid_frame, grid_from_points
from navkit.types import FailureStage, NavStatus, Status
from navtopo.graph import TopologicalGraph
from navtopo.local_grid import CroppedGrid
from navtopo.place_recognition import make_descriptor
from navtopo.system import NavTopo, NavTopoConfig
from reports.records import TrialRecord
from reports.results import Run
from reports.tables import cells, table_rows, to_csv
from runners.metrics import failure_stage, summarize, trial_record
from runners.navigation import ending_detail, run_one_trial
from runners.protocol import TrialProtocol, context_for
from runners.sim import Simulator
from runners.systems import get_system
from scenarios import load_scenario
from scenarios.trials import Trial

EXACT = TrialProtocol(initial_pose_error_xy=0.0, initial_pose_error_yaw_deg=0.0)  # the given pose is the truth
CABINET = (10.95, 11.45, 2.5, 3.5)  # tiny's cabinet, x0 x1 y0 y1 (scenario frame)
SIDE_ROOM_DOORWAY = (12.95, 13.3, 3.3, 6.7)  # where tiny's side room (x 13.0-14.8, y 3.5-6.5) opens


@pytest.fixture(scope="module")
def tiny():
    return load_scenario("tiny")


@pytest.fixture(scope="module")
def sim(tiny):
    with Simulator(tiny, seed=0, with_changes=True) as simulator:
        yield simulator


def _trial(start: list[float], goal: list[float], shortest_m: float = 20.0) -> Trial:
    """A trial of our own (start [x, y, yaw_deg], goal [x, y], scenario frame)."""
    pose = np.array([start[0], start[1], np.radians(start[2])])
    return Trial(0, pose, np.asarray(goal, dtype=np.float64), np.zeros((0, 2)), shortest_m)


def _run(tiny, sim, name: str, system, trial: Trial, protocol: TrialProtocol = EXACT) -> TrialRecord:
    record, _, _ = run_one_trial(tiny, sim, get_system(name), system, trial, 0, 0, protocol)
    json.dumps(record.as_json(), allow_nan=False)
    return record


# --- the baseline on maps made from the ground truth ------------------------------------------------


def _box(xy: np.ndarray, box: tuple[float, float, float, float]) -> np.ndarray:
    return (xy[:, 0] >= box[0]) & (xy[:, 0] <= box[1]) & (xy[:, 1] >= box[2]) & (xy[:, 1] <= box[3])


def _metric_map(tiny, folder: Path, obstacles: bool = True, walls: bool = True, sealed=None) -> Path:
    """A saved metric_grid folder whose map (0.1 m, map frame) is the GT raster: free cells FREE, the
    rest OCCUPIED; without ``obstacles`` the boxes standing in the corridors are left out, without
    ``walls`` every cell is FREE; ``sealed`` (x0, x1, y0, y1, scenario frame) is made OCCUPIED."""
    world = tiny.world
    corners = np.array([[x, y] for x in world.bounds[0::2] for y in world.bounds[1::2]])
    in_map = se2.transform_points(se2.inverse(tiny.route_start), corners)
    origin = np.floor(in_map.min(axis=0)) - 1.0
    shape = tuple(int(v) for v in np.ceil((in_map.max(axis=0) + 1.0 - origin) / 0.1)[::-1])
    grid_map = GridMap(np.zeros(shape, np.uint8), origin, 0.1)
    centres = se2.transform_points(tiny.route_start, grid_map.centres(np.ones(shape, bool)))
    raster = world.free if obstacles else world.structure_free
    cells = world.to_cell(centres)
    inside = world.inside(cells)
    free = np.zeros(len(centres), bool)
    free[inside] = raster[cells[inside, 0], cells[inside, 1]]
    if not walls:
        free[:] = True
    if sealed is not None:
        free &= ~_box(centres, sealed)
    grid_map.cells[:] = np.where(free, FREE, OCCUPIED).reshape(shape)
    folder.mkdir(parents=True, exist_ok=True)
    grid_map.save(folder / MAP_YAML)
    (folder / MANIFEST).write_text(json.dumps({"format": FORMAT, "map": MAP_YAML}))
    return folder


def _metric_grid(tiny, sim, folder: Path, **config) -> MetricGrid:
    entry = get_system("metric_grid")
    return MetricGrid.load(folder, MetricGridConfig.model_validate(config), context_for(entry, tiny, sim))


def test_the_baseline_given_a_goal_in_a_room_its_map_shows_sealed_fails_in_global_planning(tiny, sim, tmp_path):
    """The side room's doorway walled up in the map: no level of the grid search reaches the goal."""
    folder = _metric_map(tiny, tmp_path / "sealed", sealed=SIDE_ROOM_DOORWAY)
    system = _metric_grid(tiny, sim, folder)
    record = _run(tiny, sim, "metric_grid", system, _trial([1.0, 0.0, 0.0], [14.2, 5.0]))
    assert (record.success, record.reason, record.failure_stage) == (False, "no_path", "global_plan")
    levels = len(system.planner.attempts)  # margin, radius, medial axis; then the same through unknown cells
    assert levels == 6 and record.detail.startswith("no path from (")
    assert f"in the map frame, {levels} levels tried" in record.detail and "on the medial axis" in record.detail
    assert record.detail.endswith("no way joins the start and the goal")  # both ends are in free space
    # a goal in the solid block inside the L, 2.9 m from either corridor: no passable cell near it
    record = _run(tiny, sim, "metric_grid", _metric_grid(tiny, sim, folder), _trial([1.0, 0.0, 0.0], [8.0, 4.0]))
    assert record.failure_stage == "global_plan" and record.detail.endswith("the goal had no passable cell within 1 m")


def test_the_baseline_that_finds_no_fit_on_its_map_in_time_fails_at_start_up(tiny, sim, tmp_path):
    """A map without a wall: no scan fits it anywhere, so the pose is never found (timeout 2 s)."""
    folder = _metric_map(tiny, tmp_path / "blank", walls=False)
    system = _metric_grid(tiny, sim, folder, relocalization={"timeout": 2.0, "global_search": False})
    record = _run(tiny, sim, "metric_grid", system, _trial([1.0, 0.0, 0.0], [10.0, 0.0]))
    assert (record.reason, record.failure_stage) == ("not_localized", "startup")
    assert record.detail.startswith("no fit on the map around (") and record.detail.endswith("in 2 s")
    assert record.sim_time_s == pytest.approx(2.2, abs=0.25)


def test_the_kidnapped_baseline_that_confirms_no_place_in_time_says_why_at_start_up(tiny, sim, tmp_path):
    """Kidnapped on a map without a wall (kidnapped timeout 2 s): no place ever fits, and the detail
    says so, with the looks made."""
    folder = _metric_map(tiny, tmp_path / "blank", walls=False)
    system = _metric_grid(tiny, sim, folder, relocalization={"kidnapped_timeout": 2.0})
    record = _run(tiny, sim, "metric_grid", system, _trial([1.0, 0.0, 0.0], [10.0, 0.0]), TrialProtocol(initial_pose="none"))
    assert (record.reason, record.failure_stage) == ("not_localized", "startup")
    assert record.detail.startswith("no pose confirmed on the map in 2 s: no place fits the scan after ")
    assert system.tracker.counters["global_searches"] >= 2 and not system.tracker.hypotheses


def test_the_baseline_driving_into_a_cabinet_its_map_lacks_fails_in_the_follower(tiny, sim, tmp_path):
    """The boxes left out of the map, no return taken for a new obstacle and no scan guard: the path
    cuts the inner corner of the L through the pillar or the cabinet, and the robot hits one."""
    folder = _metric_map(tiny, tmp_path / "no_obstacles", obstacles=False)
    system = _metric_grid(tiny, sim, folder, planning={"new_obstacle_distance": 50.0, "scan_guard": False})
    record = _run(tiny, sim, "metric_grid", system, tiny.trials[0])
    assert (record.reason, record.failure_stage, record.collisions) == ("collision", "follower", 1)
    assert record.detail.startswith("collided at (") and "in the scenario frame" in record.detail
    assert "; following a " in record.detail  # the system's words: what it was doing


def test_the_baseline_that_believes_itself_at_the_goal_elsewhere_fails_in_localization(tiny, sim, tmp_path):
    """Given a start 0.8 m ahead of the truth and no registration to correct it, the robot stops
    where it believes the goal is: 0.8 m short by the truth."""
    folder = _metric_map(tiny, tmp_path / "map")
    system = _metric_grid(tiny, sim, folder, localization={"enabled": False}, relocalization={"enabled": False})
    given = system.set_initial_pose
    along = se2.inverse(tiny.route_start)[2]  # the scenario's +x in the map frame
    system.set_initial_pose = lambda pose: given(np.asarray(pose) + [0.8 * np.cos(along), 0.8 * np.sin(along), 0.0])
    record = _run(tiny, sim, "metric_grid", system, _trial([2.0, 0.0, 0.0], [10.0, 0.0]))
    assert (record.reason, record.failure_stage) == ("reached_wrong_place", "localization")
    assert 0.75 < record.final_distance_m < 0.8 + 0.4  # short by the offset, plus up to its stop tolerance
    assert record.detail.startswith(f"declared reached {record.final_distance_m:.2f} m from the goal; its pose estimate (")


# --- NavTopo on graphs of true scans ---------------------------------------------------------------

GRID = GridConfig()
QUICK = {  # commit at the first look that verifies one location only: the start is not what is tested
    "descriptor": "scan_context",
    "startup": {
        "confirm_looks": 1,
        "confirm_distance": 0.0,
        "confirm_places": 1,
        "confirm_distance_one_place": 0.0,
        "confirm_alone_looks": 1,
        "confirm_alone_distance": 0.0,
    },
}


def _navtopo(tiny, sim, poses: list[list[float]], edges: list[tuple[int, int]], grids=None, **config) -> NavTopo:
    """NavTopo on a graph of locations made at ``poses`` ([x, y, yaw_deg], scenario frame) from true
    scans (or ``grids``), joined by ``edges`` with their true relative poses."""
    descriptor = make_descriptor(config.get("descriptor", "scan_context"))
    graph = TopologicalGraph(descriptor.dim)
    in_map = []
    for i, (x, y, yaw) in enumerate(poses):
        pose = np.array([x, y, np.radians(yaw)])
        points = sim.scan(pose)
        grid = grids[i] if grids is not None and grids[i] is not None else grid_from_points(points, GRID)
        in_map.append(se2.between(tiny.route_start, pose))
        graph.add_vertex(CroppedGrid.from_grid(grid), descriptor.embed(points), in_map[-1], float(i))
    for u, v in edges:
        graph.add_edge(u, v, se2.between(in_map[u], in_map[v]))
    entry = get_system("navtopo")
    return NavTopo(NavTopoConfig.model_validate(config), graph, mapping=False, context=context_for(entry, tiny, sim))


def _stamped(sim, pose: list[float], box: tuple[float, float, float, float]) -> np.ndarray:
    """The true scan's grid at ``pose`` with every cell in ``box`` (scenario frame) OCCUPIED."""
    at = np.array([pose[0], pose[1], np.radians(pose[2])])
    grid = grid_from_points(sim.scan(at), GRID)
    frame = grid_frame(GRID)
    rows, cols = np.indices(grid.shape)
    cells = np.stack([rows.ravel(), cols.ravel()], axis=1)
    world = se2.transform_points(at, frame.to_world(cells))
    grid.reshape(-1)[_box(world, box)] = OCCUPIED
    return grid


START, GOAL_CORRIDOR = [1.0, 0.0, 0.0], [12.0, 6.5, 90.0]  # tiny's trial 0 starts at the one, ends beside the other


def test_navtopo_whose_graph_does_not_join_the_robot_and_the_goal_fails_in_global_planning(tiny, sim):
    """Two locations, at the start and at the goal, never joined (a room the map keeps apart)."""
    system = _navtopo(tiny, sim, [START, GOAL_CORRIDOR], [], **QUICK)
    record = _run(tiny, sim, "navtopo", system, tiny.trials[0])
    assert (record.reason, record.failure_stage) == ("no_path", "global_plan")
    assert record.detail.startswith("no route over the graph from location 0 to the goal's location 1: not joined, ")
    distance = float(record.detail.split(", ")[-1].split(" m ")[0])
    assert distance == pytest.approx(np.hypot(12.0 - 1.0, 7.0 - 0.0), abs=0.3)  # by the locations' map poses


def test_navtopo_with_no_local_path_across_its_only_edge_fails_in_local_planning(tiny, sim):
    """The same two locations joined, but the goal's location saw a wall across the corridor at
    x = 8 (a door shut after mapping): the local plan to it fails, the edge goes, no route is left."""
    wall = _stamped(sim, GOAL_CORRIDOR, (7.9, 8.1, -20.0, 20.0))
    config = {**QUICK, "planning": {"smoothing": "none"}}
    system = _navtopo(tiny, sim, [START, GOAL_CORRIDOR], [(0, 1)], [None, wall], **config)
    record = _run(tiny, sim, "navtopo", system, tiny.trials[0])
    assert (record.reason, record.failure_stage) == ("no_path", "local_plan")
    assert record.detail.startswith("no route left from location 0 to the goal's location 1, edges removed 0-1 (no local path), ")
    assert system.stats()["counters"]["edges_removed"] == 1


def test_navtopo_that_recognises_no_location_in_time_fails_at_start_up(tiny, sim):
    """The graph's one location is a round room the building does not have: nothing verifies, and
    after the start-up's time (3 s) the trial fails."""
    ring = np.full((GRID.size, GRID.size), UNKNOWN, np.uint8)
    rows, cols = np.indices(ring.shape)
    radius = np.hypot(rows - GRID.size / 2, cols - GRID.size / 2) * GRID.resolution
    ring[radius < 1.5] = FREE
    ring[(radius >= 1.5) & (radius < 1.7)] = OCCUPIED
    system = _navtopo(tiny, sim, [[6.0, -3.0, 0.0]], [], [ring], descriptor="scan_context", startup={"timeout": 3.0})
    record = _run(tiny, sim, "navtopo", system, tiny.trials[0])
    assert (record.reason, record.failure_stage) == ("not_localized", "startup")
    assert record.detail.startswith("no commitment in 3 s: 0 hypotheses alive (0 found), ")
    assert record.startup_localization is None


# --- the oracle and the runner's own stages -------------------------------------------------------------


def test_the_oracle_given_a_goal_inside_a_cabinet_fails_in_global_planning(tiny, sim):
    entry = get_system("oracle")
    oracle = entry.cls(entry.config_model(), context_for(entry, tiny, sim))
    record = _run(tiny, sim, "oracle", oracle, _trial([1.0, 0.0, 0.0], [11.2, 3.0]))
    assert (record.reason, record.failure_stage) == ("no_path", "global_plan")
    assert record.detail.startswith("no path on the ground-truth raster from (1.00, 0.00) to (11.20, 3.00)")


def test_an_exception_in_a_system_fails_the_trial_in_the_runner_stage(tiny, sim):
    entry = get_system("faulty")
    trial = tiny.trials[0]
    goal_in_map = se2.transform_points(se2.inverse(tiny.route_start), trial.goal[None])[0]
    config = entry.config_model.model_validate({"raise_at": [goal_in_map.tolist()]})
    record = _run(tiny, sim, "faulty", entry.cls(config, context_for(entry, tiny, sim)), trial)
    assert (record.reason, record.failure_stage, record.detail) == ("error", "runner", "RuntimeError: faulty: raised on purpose")


@pytest.mark.parametrize(
    ("ending", "success", "reason", "status_stage", "expected"),
    [
        ("reached", True, "", None, None),
        ("reached", False, "reached_wrong_place", None, "localization"),  # it believed it was there
        ("failed", False, "no_path", "local_plan", "local_plan"),  # the system's own word
        ("failed", False, "no_path", None, "global_plan"),  # a system that names none: by its reason
        ("failed", False, "gave_up", None, None),  # ... a reason the runner does not know: none
        ("collision", False, "collision", None, "follower"),
        ("collision", False, "collision", "startup", "startup"),  # not localized yet
        ("stuck", False, "stuck", "localization", "localization"),  # lost
        ("timeout", False, "timeout", None, "follower"),
        ("timeout", False, "timeout", "global_plan", "follower"),  # an active status names startup or lost only
    ],
)
def test_the_stage_of_each_ending(ending, success, reason, status_stage, expected):
    assert failure_stage(ending, success, reason, status_stage) == expected


def test_the_detail_of_a_timeout_says_which_clock_ran_out():
    doing = "following a local path in location 3 toward location 4"
    text = ending_detail("timeout", NavStatus(Status.ACTIVE, detail=doing), np.array([1.0, 2.0, 0.0]), 123.4, 7.25)
    assert text == f"passed its simulated-time limit of 123 s, 7.2 m from the goal; {doing}"  # the system's words after
    assert ending_detail("failed", NavStatus(Status.FAILED, "no_path"), np.zeros(3), 10.0, 1.0) is None
    assert len(ending_detail("failed", NavStatus(Status.FAILED, "x", detail="a\nb " * 200), np.zeros(3), 1.0, 1.0)) == 300


# --- the summary's counts and Table 1 --------------------------------------------------------------------


def test_the_summary_counts_failures_by_stage_beside_their_reasons():
    trial = _trial([0.0, 0.0, 0.0], [5.0, 0.0], 5.0)
    ends = [("", None), ("no_path", "local_plan"), ("no_path", "local_plan"), ("no_path", "global_plan")]
    ends += [("collision", "startup"), ("crashed", None)]
    records = [
        trial_record("navtopo", i, trial, 1, success=not reason, reason=reason, failure_stage=stage, travelled_m=5.0)
        for i, (reason, stage) in enumerate(ends)
    ]
    assert [r.failure_stage for r in records] == [None, "local_plan", "local_plan", "global_plan", "startup", "runner"]
    summary = summarize(records, {})["navtopo"]
    assert summary.failure_reasons == {"no_path": 3, "collision": 1, "crashed": 1}
    assert summary.failure_stages == {"local_plan": 2, "global_plan": 1, "startup": 1, "runner": 1}
    assert set(FailureStage) >= {FailureStage(s) for s in summary.failure_stages}


def test_table_1_shows_each_reasons_stages_and_a_run_from_before_stages_its_reasons_alone(tmp_path):
    before = write_crafted_run(tmp_path / "before")
    after = write_crafted_run(tmp_path / "after")
    lines = (after / "trials.jsonl").read_text().split("\n")
    stages = iter(["follower", "startup", "follower"])  # navtopo's timeout; metric_grid's two collisions
    for i, line in enumerate(lines):
        record = json.loads(line) if line.startswith("{") and line.endswith("}") else None
        if record is not None and not record["success"] and record["reason"] != "written twice: the first record counts":
            lines[i] = json.dumps({**record, "failure_stage": next(stages)})
    (after / "trials.jsonl").write_text("\n".join(lines))
    topo, metric = table_rows([Run.load(after)], with_paper=False)
    assert cells(topo)["failures"] == "timeout 1 (follower 1)"
    assert cells(metric)["failures"] == "collision 2 (follower 1, startup 1)"
    old_topo, old_metric = table_rows([Run.load(before)], with_paper=False)
    assert (cells(old_topo)["failures"], cells(old_metric)["failures"]) == ("timeout 1", "collision 2")
    table = list(csv.DictReader(io.StringIO(to_csv([topo, metric]))))
    assert [row["failure_stages"] for row in table] == ["follower:1", "follower:1;startup:1"]
