"""navkit.grid_planning: the one grid-planning function of the oracle, the baseline, NavTopo's
local planner and the scenario routes; pinned against the planners' paths before it existed."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from baselines.metric_grid.config import PlanningConfig
from baselines.metric_grid.occupancy import GridMap
from baselines.metric_grid.system import MetricGrid, MetricGridConfig
from navkit import grid_search
from navkit.grid_planning import densify, plan_path, split_at
from navkit.raster import FREE, GridFrame
from runners.systems import GroundTruth, SystemContext, get_system
from scenarios import load_scenario

REFERENCE = Path(__file__).resolve().parent / "data" / "planning_reference.npz"


@pytest.fixture(scope="module")
def reference():
    return dict(np.load(REFERENCE))


@pytest.fixture(scope="module")
def tiny():
    return load_scenario("tiny")


def _without_snapped_ends(path: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """``path`` minus a second or second-to-last point that the reference lacks."""
    keep = np.ones(len(path), bool)
    for index in (1, len(path) - 2):
        if 0 < index < len(path) - 1 and not any(np.array_equal(path[index], q) for q in reference):
            keep[index] = False
    return path[keep]


def test_the_baseline_and_the_oracle_plan_the_same_paths_as_before_the_extraction(reference, tiny):
    """The reference holds the paths the baseline's and the oracle's own planning code gave on
    tiny (a 0.1 m trinary map made from the GT raster; the 3 trials and 12 random pairs anywhere in
    free space) before both called ``plan_path``. The baseline's are identical. The oracle's are
    identical for the trials; where a random end lay deep in the inflated zone near a wall, the
    oracle used to drop the cell it snapped to and head straight for the next vertex, across the
    inflated zone; it now keeps that cell as the way into free space, the baseline's rule. The
    baseline's shortest paths, that is: without easing them off the walls (``keep_clear`` 0;
    the eased ones are pinned against these below), with the search it had then (Lazy Theta*);
    its default search now, A* string-pulled, gives paths within 1 % of their lengths."""
    context = SystemContext(robot=tiny.spec.robot, sensor=tiny.spec.sensor)
    baseline = MetricGrid(MetricGridConfig(planning=PlanningConfig(keep_clear=0.0, search="theta_star")), context)
    baseline._prepare_navigation(GridMap(reference["map_cells"], reference["map_origin"], 0.1))
    default = MetricGrid(MetricGridConfig(planning=PlanningConfig(keep_clear=0.0)), context)
    default._prepare_navigation(GridMap(reference["map_cells"], reference["map_origin"], 0.1))
    truth = GroundTruth(world=tiny.world, world_from_map=np.zeros(3))
    entry = get_system("oracle")
    oracle = entry.create(
        entry.default_config(), SystemContext(robot=tiny.spec.robot, sensor=tiny.spec.sensor, ground_truth=truth)
    )
    for i, (start, goal) in enumerate(zip(reference["starts"], reference["goals"], strict=True)):
        assert np.array_equal(baseline.plan(start, goal), reference[f"baseline_{i}"]), i
        assert _length(default.plan(start, goal)) == pytest.approx(_length(reference[f"baseline_{i}"]), rel=0.01), i
        oracle.goal_world = goal
        path, old = oracle._plan(start), reference[f"oracle_{i}"]
        if i < len(tiny.trials):
            assert np.array_equal(path, old), i
        else:
            assert np.array_equal(_without_snapped_ends(path, old), old), i


def test_the_baseline_eases_its_paths_off_the_walls(reference, tiny):
    """With its default ``keep_clear`` the baseline's paths between the same ends keep at least the
    shortest paths' clearance from the map's walls, more where the shortest one hugs a wall with
    room beside it (over the first ``keep_clear_horizon`` metres, the part eased), for a few per cent
    of length; the ends are the same."""
    context = SystemContext(robot=tiny.spec.robot, sensor=tiny.spec.sensor)
    baseline = MetricGrid(MetricGridConfig(), context)
    grid = GridMap(reference["map_cells"], reference["map_origin"], 0.1)
    baseline._prepare_navigation(grid)
    squared = grid_search.clearance_squared(grid.cells == FREE)

    horizon = baseline.config.planning.keep_clear_horizon

    def least(path: np.ndarray) -> float:  # over the eased first stretch
        cells = grid.frame.to_cell(densify(split_at(path, horizon)[0], 0.025)[1:-1])
        return float(np.sqrt(squared[cells[:, 0], cells[:, 1]]).min()) * 0.1

    gained = 0
    for i, (start, goal) in enumerate(zip(reference["starts"], reference["goals"], strict=True)):
        shortest, eased = reference[f"baseline_{i}"], baseline.plan(start, goal)
        assert np.array_equal(eased[0], shortest[0]) and np.array_equal(eased[-1], shortest[-1]), i
        assert least(eased) >= least(shortest) - 0.03, i
        assert _length(eased) <= 1.05 * _length(shortest) + 0.2, i
        gained += least(eased) > least(shortest) + 0.05
    assert gained >= 3


def _length(path: np.ndarray) -> float:
    return float(np.hypot(*np.diff(path, axis=0).T).sum())


def test_fallback_levels_snapping_and_exact_ends():
    frame = GridFrame(np.array([-1.0, -1.0]), 0.1)
    open_room = np.ones((40, 40), bool)
    walled = open_room.copy()
    walled[:, 20] = False  # a wall across the room, no door: the first level has no path
    start, goal = np.array([0.03, 0.52]), np.array([2.4, 0.57])
    planned = plan_path([walled, open_room], frame, start, goal)
    assert planned is not None and planned.level == 1
    assert np.array_equal(planned.points[0], start) and np.array_equal(planned.points[-1], goal)
    assert planned.length == pytest.approx(np.hypot(*(goal - start)), rel=1e-6)  # one straight segment
    # a start inside a blocked cell: without a snap no path, with one the snapped cell leads in
    blocked_start = open_room.copy()
    blocked_start[15, 10] = False  # the cell of (0.03, 0.52)
    assert plan_path([blocked_start], frame, start, goal) is None
    snapped = plan_path([blocked_start], frame, start, goal, snap_cells=2)
    assert snapped is not None and np.array_equal(snapped.points[0], start)
    # masks made on demand: only as many as needed are built
    built = []

    def mask(level):
        built.append(level)
        return [walled, open_room, open_room][level]

    assert plan_path(mask, frame, start, goal, levels=3).level == 1 and built == [0, 1]
    assert plan_path([walled], frame, start, goal) is None


def test_the_oracle_passes_a_door_of_little_more_than_its_width_through_the_middle():
    """A door 0.8 m wide (0.1 m beyond the 0.3 m radius on each side: no path at the oracle's
    0.15 m margin) met on a diagonal: the tight level's path, eased toward the margin, keeps at
    least 0.07 m beyond the radius from the jambs, where the shortest one cut the corner at 0.035 m
    and the follower's deviation touched it (loop_office_door, trial 1)."""
    from navkit.grid_planning import densify as dense
    from scenarios.world import World

    res = 0.05
    free = np.ones((120, 120), bool)  # 6 m x 6 m
    free[[0, -1], :] = free[:, [0, -1]] = False
    free[:, 59:61] = False  # a wall at x = 3 m
    free[52:68, 59:61] = True  # its door: y in [2.6, 3.4]
    world = World(res, np.zeros(2), free, free.copy(), np.zeros((0, 2, 2)), 2.6, True)
    tiny = load_scenario("tiny")
    robot = tiny.spec.robot.model_copy(update={"radius": 0.3})
    truth = GroundTruth(world=world, world_from_map=np.zeros(3))
    entry = get_system("oracle")
    oracle = entry.create(entry.default_config(), SystemContext(robot=robot, sensor=tiny.spec.sensor, ground_truth=truth))
    oracle.goal_world = np.array([5.0, 5.2])
    path = oracle._plan(np.array([1.0, 0.8]))
    assert path is not None
    points = dense(path, res / 2)
    clearance = world.clearance[tuple(np.floor(points[:, ::-1] / res).astype(int).T)]
    assert clearance.min() >= 0.3 + 0.07, clearance.min()


def test_a_search_bounded_to_a_ways_length_finds_what_the_whole_grid_does_within_it():
    """``within_length``: every cell a way of the length can pass is in, none a way a twelfth
    longer could not reach; and on a cluttered grid, searching only the cells it keeps finds a
    shortest 8-connected path as long as the whole grid's whenever that is within the bound, and
    otherwise none or one no shorter."""
    from navkit.grid_planning import GRID_STRETCH, within_length

    frame = GridFrame(np.zeros(2), 0.1)
    a, b = np.array([1.0, 1.0]), np.array([5.0, 2.0])
    kept = within_length(frame, (60, 80), a, b, 6.0)
    centres = frame.to_world(np.argwhere(np.ones((60, 80), bool))).reshape(60, 80, 2)
    span = np.hypot(*(centres - a).transpose(2, 0, 1)) + np.hypot(*(centres - b).transpose(2, 0, 1))
    assert kept[span <= 6.0].all() and not kept[span > GRID_STRETCH * 6.0 + 0.2].any()

    rng = np.random.default_rng(7)
    free = np.ones((90, 90), bool)
    for r, c in rng.integers(0, 90, (70, 2)):
        free[r : r + rng.integers(2, 12), c : c + rng.integers(2, 4)] = False  # wall stubs
    cells = np.argwhere(free)
    compared = 0
    for _ in range(40):
        start, goal = (tuple(int(v) for v in cells[k]) for k in rng.integers(0, len(cells), 2))
        ends = frame.to_world(np.array([start, goal]))
        bound = 1.3 * float(np.hypot(*(ends[1] - ends[0]))) + 0.5
        found = grid_search.astar(free, start, goal)
        if found is None:
            continue
        whole = grid_search.path_length(found, frame.resolution)
        bounded = grid_search.astar(free & within_length(frame, free.shape, ends[0], ends[1], bound), start, goal)
        if whole <= bound:
            assert bounded is not None and grid_search.path_length(bounded, frame.resolution) == pytest.approx(whole, abs=1e-9)
            compared += 1
        elif bounded is not None:
            assert grid_search.path_length(bounded, frame.resolution) >= whole - 1e-9
    assert compared >= 10


def test_a_scan_plan_passes_a_narrow_door_into_unseen_space_before_giving_up_on_the_way_round():
    """``ScanGrid.plan_seen_first``: the goal lies in unseen space beyond a door the scan shows 0.6 m
    between its jambs' cells (a robot of radius 0.3 m passes it along its middle only). The way round
    the wall's end is far longer than the detour allowed; the door's way must be found, not the plan
    given up at the first level that has a way at all (office02, noisy: the edge was removed)."""
    from navkit.raster import OCCUPIED, UNKNOWN
    from navkit.scan_grid import ScanGrid

    frame = GridFrame(np.array([-5.0, -5.0]), 0.1)
    grid = np.full((100, 100), UNKNOWN, np.uint8)
    centres = frame.to_world(np.argwhere(np.ones(grid.shape, bool))).reshape(100, 100, 2)
    x, y = centres[..., 0], centres[..., 1]
    grid[x < 1.0] = FREE  # the room the robot stands in, seen
    wall = (x > 1.0) & (x < 1.1) & (np.abs(y) < 3.0)
    door = np.abs(y) < 0.3  # six cells: 0.3 m from the middle to the jambs' centres
    grid[wall & ~door] = OCCUPIED
    grid[wall & door] = FREE
    end = np.array([3.5, 0.0])  # unseen, straight through the door
    scan = ScanGrid(grid, frame, wide=0.45, tight=0.35)
    assert grid_search.clear_of(scan.open_squared, 0.35, 0.1)[wall & door].sum() == 0  # the door at the middle only

    found = scan.plan_seen_first(end, detour=1.5, medial=0.3)
    assert found is not None and found.level == 5  # unseen space, along the door's middle
    way = densify(found.points, 0.02)
    crossing = way[np.argmin(np.abs(way[:, 0] - 1.05))]
    assert abs(crossing[1]) < 0.1 and found.length < 4.0  # through the door, not round the wall

    grid[wall] = OCCUPIED  # the door shut: only the way round, 8 m against 3.5 m straight
    assert ScanGrid(grid, frame, wide=0.45, tight=0.35).plan_seen_first(end, detour=1.5, medial=0.3) is None
