"""NavTopo's local planner at doors of the robot's width, against ground truth: a corridor, a wall
with one door and a room, scanned by the benchmark's lidar (``test_local_grid``'s ray caster) from a
location on each side, the robot (0.6 m wide) seen at any heading to the walls.

A scan draws a jamb into the cell its returns fall in, a cell the door may mostly lie in: a 0.8 m
door keeps 6-7 free cells between its jambs' cells, and at a slant to the grid a staircase of them.
The margin rule (the robot's centre at least its radius plus half a cell from every wall cell's
centre) then finds no way through most such doors (at 0.8 m, with the cells of a staircase that
touch only diagonally joined, through some); the union grid turned along the walls and the
passage's medial axis do, and the scan's returns, exact where the cells are not, put the way
through the door's middle or shut a gap the robot does not fit."""

from __future__ import annotations

import numpy as np
import pytest
from shapely.geometry import LineString, box
from shapely.ops import unary_union

from navkit import geometry as se2
from navkit.grid_search import medial_axis
from navkit.passages import Passage, fit_passage, moved_passage, narrow_part, shifted_path
from navkit.raster import FREE, OCCUPIED, GridFrame
from navkit.scan import obstacle_points
from navkit.scan_grid import GridConfig, grid_from_points
from navtopo.graph import TopologicalGraph
from navtopo.local_grid import CroppedGrid
from navtopo.planning import LocalPlanner, PlanningConfig, UnionGrid, UnionGrids, build_union_grid

try:
    from test_local_grid import WALL_HEIGHT, RasterWorld, lidar_scan
except ImportError:  # run from the repository root as a package
    from tests.test_local_grid import WALL_HEIGHT, RasterWorld, lidar_scan

GRID = GridConfig()
RADIUS = 0.3  # the benchmark robot's
MARGIN = 0.04  # navigation.passage_margin's default: what the scan must leave beyond the radius
MARGIN_RULE = PlanningConfig(align_walls=False, medial_passages=False)  # the planner before doors were passed


def door_world(width: float, centre: float = 0.0):
    """A corridor (y < 0) and a room (y > 0.2) 6 m wide, a wall 0.2 m thick between them with a
    door ``width`` wide centred at x = ``centre``: the ray caster's world and the walls' shapes."""
    world = RasterWorld(-4.0, -3.0, 8.0, 8.0)
    world.add_room_walls(-3.0, 3.0, -2.0, 4.2)
    world.add_box(-3.0, centre - width / 2, 0.0, 0.2)
    world.add_box(centre + width / 2, 3.0, 0.0, 0.2)
    walls = unary_union(
        [
            box(-3.0, 0.0, centre - width / 2, 0.2),
            box(centre + width / 2, 0.0, 3.0, 0.2),
            box(-4.0, -3.0, 4.0, 5.0).difference(box(-3.0, -2.0, 3.0, 4.2)),
        ]
    )
    return world, walls


def door_locations(world, heading_deg: float) -> tuple[TopologicalGraph, list[np.ndarray]]:
    """Two locations, in the corridor and in the room, their grids from the scans taken there and
    the exact edge between them; the corridor's at ``heading_deg`` to the walls."""
    heading = np.radians(heading_deg)
    poses = [np.array([0.4, -1.0, heading]), np.array([-0.3, 1.8, heading + 0.5])]
    graph = TopologicalGraph(4)
    for i, pose in enumerate(poses):
        grid = grid_from_points(lidar_scan(world, pose, ceiling=WALL_HEIGHT), GRID)
        graph.add_vertex(CroppedGrid.from_grid(grid), np.ones(4), pose, float(i))
    graph.add_edge(0, 1, se2.between(poses[0], poses[1]))
    return graph, poses


def plan_across(graph: TopologicalGraph, config: PlanningConfig):
    """The local plan from the corridor's location to the room's, in the corridor's union grid."""
    planner = LocalPlanner(UnionGrids(graph, GRID, config), RADIUS, config)
    union = planner.grids.get(0)
    return planner, union, planner.plan(union, np.zeros(3), graph.edge(0, 1)[:2])


def true_clearance(path: np.ndarray, pose: np.ndarray, walls) -> float:
    """The least distance (m) from a path (K, 2, in the frame at ``pose``) to the true walls."""
    line = LineString(se2.transform_points(pose, path))
    return min(walls.distance(line.interpolate(d)) for d in np.arange(0.0, line.length, 0.01))


def scan_returns(world, pose: np.ndarray, passage: Passage) -> np.ndarray:
    """The scan's obstacle returns near the passage, in the frame at ``pose`` (as the navigator takes them)."""
    points = obstacle_points(lidar_scan(world, pose, ceiling=WALL_HEIGHT))[:, :2].astype(np.float64)
    near = se2.distance_to_polyline(points, np.vstack([passage.entry, passage.exit])) <= 0.5 + 0.3 + RADIUS
    return np.unique(np.round(points[near] / 0.01), axis=0) * 0.01


def test_the_walls_direction_is_found_at_any_heading_and_a_union_grid_turns_to_it():
    world, _ = door_world(0.8)
    for heading in (0.0, 17.0, 30.0, 44.0, 71.0):
        graph, _ = door_locations(world, heading)
        union = build_union_grid(graph, 0, GRID, 25.0)
        # the walls run along x and y of the world: in the corridor's frame at -heading (mod 90°)
        off = (np.degrees(union.yaw) + heading + 45.0) % 90.0 - 45.0
        assert abs(off) < 1.5, (heading, np.degrees(union.yaw))
        # turned, the wall's face toward the corridor (5 m) lies along a row or two of cells, not a
        # staircase across many (15 at 17°)
        cells = np.argwhere(union.cells == OCCUPIED)
        in_world = se2.transform_points(np.array([0.4, -1.0, np.radians(heading)]), union.to_point(cells))
        face = cells[(np.abs(in_world[:, 1]) < 0.1) & (np.abs(in_world[:, 0]) < 2.5)]
        across = face[:, 0] if np.ptp(face[:, 1]) > np.ptp(face[:, 0]) else face[:, 1]  # the index the face does not run along
        assert len(face) > 30 and np.ptp(across) <= 2, (heading, np.unique(across, return_counts=True))


def test_the_medial_axis_is_the_middle_of_a_passage():
    """A passage six cells wide between walls along x: its axis is its middle two rows, along it no
    other cell; a passage seven wide: its middle row."""
    for width, middle in ((6, {3, 4}), (7, {4})):
        cells = np.full((width + 2, 20), FREE, np.uint8)
        cells[0], cells[-1] = OCCUPIED, OCCUPIED
        union = UnionGrid(0, cells, GridFrame(np.zeros(2), 0.1))
        axis = medial_axis(union._squared("known"))
        rows = set(np.flatnonzero(axis[:, 5:15].all(axis=1)).tolist())
        assert rows == middle, (width, rows)
        assert not axis[[1, 2, -2, -3], 5:15].any()


@pytest.mark.parametrize("width", [0.75, 0.8, 0.85])
def test_a_door_at_the_robots_width_is_passed_through_its_middle(width):
    headings = (0.0, 20.0, 37.0, 60.0)
    missed_by_the_margin_rule = 0
    for heading in headings:
        world, walls = door_world(width, centre=0.02 * heading / 20.0)
        graph, poses = door_locations(world, heading)
        missed_by_the_margin_rule += plan_across(graph, MARGIN_RULE)[2] is None
        planner, union, planned = plan_across(graph, PlanningConfig())
        assert planned is not None, (width, heading)
        kind, radius, medial = planner.levels[planned.level]
        passage = narrow_part(planned.points, union.passable_at(kind, radius)) if medial is not None else None
        if passage is None:  # found by the margin rule, in the turned grid
            assert true_clearance(planned.points, poses[0], walls) >= RADIUS + 0.03, (width, heading)
            continue
        # the scan from the corridor's location, a metre before the door: the passage to its middle
        moves, clearance = fit_passage(planned.points, passage, scan_returns(world, poses[0], passage), from_arc=RADIUS)
        assert clearance >= RADIUS + MARGIN, (width, heading, clearance)
        moved = shifted_path(planned.points, passage, moves)
        assert true_clearance(moved, poses[0], walls) >= RADIUS + 0.03, (width, heading)
    # why the medial axis is there: the margin rule misses most doors of 0.75 m; at 0.8 m, since the
    # cells of a level that touch only diagonally are joined, it misses the door at 20 degrees alone
    if width < 0.8:
        assert missed_by_the_margin_rule >= len(headings) // 2
    elif width < 0.85:
        assert missed_by_the_margin_rule >= 1


def test_a_tight_path_to_a_door_is_eased_off_the_wall_it_would_hug_with_ease_tight():
    """A 0.9 m door, approached from along the corridor's wall: only the tight level (no margin beyond
    the radius) finds a way, and its shortest path hugs the wall on the way to the door at the
    radius, its stretch off the first level's cells too long for the passage check to take
    (narrow_part: a corridor, not a door); with planning.ease_tight the way is eased up to
    the first level's clearance where the corridor allows: 0.1 m more room by the true walls, and
    the door alone left for the scan check."""
    world, walls = door_world(0.9)
    for heading in (0.0, 20.0, 37.0):
        graph, poses = door_locations(world, heading)
        start = se2.between(poses[0], np.array([-2.2, -0.75, 0.0]))  # 0.75 m from the wall, 2.2 m beside the door
        found = {}
        for ease_tight in (False, True):
            config = PlanningConfig(ease_tight=ease_tight)
            planner = LocalPlanner(UnionGrids(graph, GRID, config), RADIUS, config)
            union = planner.grids.get(0)
            planned = planner.plan(union, start, graph.edge(0, 1)[:2])
            assert planned is not None and planner.levels[planned.level] == ("known", planner.tight, None), heading
            passage = narrow_part(planned.points, union.passable_at("known", planner.wide))
            found[ease_tight] = (true_clearance(planned.points, poses[0], walls), passage, planned.length)
        (hugged, no_passage, shortest), (eased, passage, length) = found[False], found[True]
        assert hugged < RADIUS + 0.06 and no_passage is None, heading
        assert eased >= RADIUS + 0.1 and passage is not None and passage.exit_arc - passage.entry_arc <= 1.0, heading
        assert length <= 1.03 * shortest, heading


@pytest.mark.parametrize("width", [0.5, 0.6, 0.65])
def test_a_gap_the_robot_does_not_fit_is_never_driven_through(width):
    """Either no way on the map, or the scan leaves less than the margin there (the navigator shuts
    the passage: its returns become obstacles, and the plan with them finds no way through)."""
    for heading in (0.0, 20.0, 37.0, 60.0):
        world, walls = door_world(width, centre=0.02 * heading / 20.0)
        graph, poses = door_locations(world, heading)
        planner, union, planned = plan_across(graph, PlanningConfig())
        if planned is None:
            continue
        kind, radius, medial = planner.levels[planned.level]
        assert medial is not None  # never by the margin rule
        passage = narrow_part(planned.points, union.passable_at(kind, radius))
        assert passage is not None
        returns = scan_returns(world, poses[0], passage)
        moves, clearance = fit_passage(planned.points, passage, returns, from_arc=RADIUS)
        assert clearance < RADIUS + MARGIN, (width, heading, clearance)
        moved = shifted_path(planned.points, passage, moves)
        shut = returns[se2.distance_to_polyline(returns, moved) < RADIUS + MARGIN]
        assert planner.plan(union, np.zeros(3), graph.edge(0, 1)[:2], shut) is None, (width, heading)


def test_a_moved_passage_is_followed_from_the_robot():
    path = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 3.0]])
    passage = Passage(np.array([2.0, 0.5]), np.array([2.0, 1.5]), 2.5, 3.5)
    moves = np.array([[0.1, 0.0], [-0.05, 0.0]])
    # before the passage: the robot, the corner, the moved ends, the rest
    moved, on_it = moved_passage(path, passage, moves, 1.0, np.array([1.0, 0.02]))
    assert np.allclose(moved, [[1.0, 0.02], [2.0, 0.0], [2.1, 0.5], [1.95, 1.5], [2.0, 3.0]])
    assert np.allclose(on_it.entry, [2.1, 0.5]) and np.allclose(on_it.exit, [1.95, 1.5])
    arcs = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(moved, axis=0).T))])
    assert on_it.entry_arc == pytest.approx(arcs[2]) and on_it.exit_arc == pytest.approx(arcs[3])
    # in it: from the robot straight to the moved exit
    moved, on_it = moved_passage(path, passage, moves, 3.0, np.array([2.0, 1.0]))
    assert np.allclose(moved, [[2.0, 1.0], [1.95, 1.5], [2.0, 3.0]])
    assert on_it.entry_arc == 0.0 and np.allclose(on_it.entry, [2.0, 1.0])
    assert np.allclose(shifted_path(path, passage, moves), [[0.0, 0.0], [2.0, 0.0], [2.1, 0.5], [1.95, 1.5], [2.0, 3.0]])
