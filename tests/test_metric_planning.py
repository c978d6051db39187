"""The metric baseline's global planner on crafted grids with known answers: doors of the robot's
width, as a 0.1 m grid draws them (its jambs a cell into the opening)."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.metric_grid.config import PlanningConfig
from baselines.metric_grid.occupancy import GridMap
from baselines.metric_grid.planning import GridPlanner
from navkit.geometry import distance_to_polyline
from navkit.raster import FREE, OCCUPIED

RADIUS = 0.3  # the benchmark robot's
RES = 0.1


def two_rooms(door_cells: int) -> GridMap:
    """Two 4 x 4 m rooms side by side (x 0-4 and 4.1-8.1 m, y 0-4 m), a wall one cell thick between
    them at column 40 with a door of ``door_cells`` free cells centred on y = 2 m."""
    cells = np.full((42, 83), OCCUPIED, np.uint8)
    cells[1:41, 1:82] = FREE
    cells[:, 41] = OCCUPIED
    low = 21 - door_cells // 2
    cells[low : low + door_cells, 41] = FREE
    return GridMap(cells, np.array([-0.1, -0.1]), RES)


@pytest.mark.parametrize("door_cells", [5, 6])
def test_a_door_the_grid_drew_narrower_than_the_robot_radius_allows_is_passed_along_its_middle(door_cells):
    """A 0.8 m door mapped as 5-6 free cells (0.5-0.6 m): no cell of it is the radius plus half a
    cell from the jambs' cells, so only the medial level finds the way, through the door's middle
    cells, the robot's radius from the jambs' centres."""
    grid = two_rooms(door_cells)
    start, goal = np.array([2.0, 1.0]), np.array([6.0, 3.0])
    without = GridPlanner(grid, RADIUS, PlanningConfig(medial_passages=False, unknown_fallback=False))
    assert without.plan(start, goal, np.zeros((0, 2))) is None
    planner = GridPlanner(grid, RADIUS, PlanningConfig(unknown_fallback=False))
    planned = planner.plan(start, goal, np.zeros((0, 2)))
    assert planned is not None and planner.attempts[planned.level][2] == RADIUS
    occupied = grid.centres(grid.cells == OCCUPIED)
    jambs = occupied[np.abs(occupied[:, 0] - 4.05) < 0.06]
    samples = np.vstack([np.linspace(a, b, 50) for a, b in zip(planned.points[:-1], planned.points[1:], strict=True)])
    at_wall = samples[np.abs(samples[:, 0] - 4.05) < 0.05]
    opening = grid.centres((grid.cells == FREE) & (np.arange(grid.cells.shape[1]) == 41)[None, :])
    middle = float(opening[:, 1].mean())
    assert len(at_wall) and np.abs(at_wall[:, 1] - middle).max() <= RES / 2 + 1e-6  # its middle cell or two
    assert distance_to_polyline(jambs, samples).min() >= RADIUS - 1e-6


def test_a_gap_the_robot_cannot_pass_stays_shut():
    """4 free cells (0.4 m; 0.5 m between the jambs' centres): no level passes it."""
    grid = two_rooms(4)
    planner = GridPlanner(grid, RADIUS, PlanningConfig(unknown_fallback=False))
    assert planner.plan(np.array([2.0, 1.0]), np.array([6.0, 3.0]), np.zeros((0, 2))) is None


def test_a_wide_door_is_passed_with_the_margin_first():
    grid = two_rooms(10)
    planner = GridPlanner(grid, RADIUS, PlanningConfig(unknown_fallback=False))
    planned = planner.plan(np.array([2.0, 1.0]), np.array([6.0, 3.0]), np.zeros((0, 2)))
    assert planned is not None and planned.level == 0
