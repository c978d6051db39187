"""The metric baseline's global planner on crafted grids with known answers: doors of the robot's
width, as a 0.1 m grid draws them (its jambs a cell into the opening)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from baselines.metric_grid.config import PlanningConfig
from baselines.metric_grid.occupancy import GridMap
from baselines.metric_grid.planning import GridPlanner
from navkit import grid_search
from navkit.geometry import distance_to_polyline
from navkit.grid_planning import plan_path
from navkit.raster import FREE, OCCUPIED, UNKNOWN

RADIUS = 0.3  # the benchmark robot's
SQRT1_2 = 0.5**0.5
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
    rows = np.flatnonzero(grid.cells[:, 41] == FREE)  # the opening's cells, bottom to top
    middle = rows[(len(rows) - 1) // 2 : len(rows) // 2 + 1]  # its middle cell or two
    assert len(at_wall) and np.isin(grid.frame.to_cell(at_wall)[:, 0], middle).all()
    # to a millimetre: the path eased off the walls beyond the door leaves its middle cell on a chord
    # that its thinning judged by clearances interpolated between cell centres
    assert distance_to_polyline(jambs, samples).min() >= RADIUS - 1e-3


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


# ---------------------------------------------------------------------------------------------
# a passage on a slant: its narrow levels joined only diagonally (grid_search.passable's bridges)


def slanted_passage(angle_deg: float, width: float = 0.66) -> GridMap:
    """Two 1.8 m square rooms (x, y 0.2-2.0 m and 4.0-5.8 m) joined by a straight passage ``width``
    wide through (3, 3) m at ``angle_deg`` to the x axis, drawn as a map draws shapes (a cell is free
    iff its centre is in free space). 0.66 m is between the medial level (0.6 m between the wall
    cells' centres) and the tight one (0.8 m): on a slant the passage's medial axis, and the few
    cells of it that are clear enough, step diagonally from cell to cell."""
    rows, cols = np.mgrid[:60, :60]
    x, y = (cols + 0.5) * RES, (rows + 0.5) * RES
    free = np.zeros((60, 60), bool)
    free[2:20, 2:20] = free[40:58, 40:58] = True
    heading = np.radians(angle_deg)
    px, py = x - 3.0, y - 3.0
    across = np.abs(-np.sin(heading) * px + np.cos(heading) * py)
    along = np.cos(heading) * px + np.sin(heading) * py
    free |= (across <= width / 2) & (np.abs(along) < 2.2)
    return GridMap(np.where(free, FREE, OCCUPIED).astype(np.uint8), np.zeros(2), RES)


def legal_steps(free: np.ndarray, cells: np.ndarray) -> bool:
    """Every segment of a cell path crosses only free cells of ``free``, and none passes through a
    grid corner beside a non-free cell (``grid_search.line_of_sight``: no corner cut)."""
    return all(grid_search.line_of_sight(free, a, b) for a, b in zip(cells[:-1], cells[1:], strict=True))


@pytest.mark.parametrize("angle", [30.0, 36.0, 45.0, 54.0, 60.0])
def test_a_slanted_passage_whose_narrow_levels_touch_only_diagonally_is_passed(angle):
    """The noisy ring's no_path (BENCHMARKS.md, "Design choices: planning levels joined where they touch
    only diagonally"): the medial level's cells along a
    slanted passage are 8-connected but not 4-connected, and the search, which never cuts a corner,
    could not walk along them. ``grid_search.passable`` bridges each diagonal-only touch with its
    clearer side cell; the path stays legal on the raw free space and keeps, at every cell and
    between cells, the level's clearance less the documented tolerance (``passable``)."""
    grid = slanted_passage(angle)
    free = grid.cells == FREE
    squared = grid_search.clearance_squared(free)
    tight = RADIUS + RES / 2
    steps = ((tight + 0.1, None), (tight, None), (tight, RADIUS))  # as GridPlanner builds its known levels
    levels = [grid_search.passable(squared, r, RES, m) for r, m in steps]
    least = [min(r, m or r) / RES for r, m in steps]  # cells: the clearance each level asks of its cells
    start, goal = np.array([1.0, 1.0]), np.array([5.0, 5.0])
    start_cell, goal_cell = (tuple(grid.cell_of(p)[0]) for p in (start, goal))
    # the way exists only along the passage's middle: no cell of it is the radius plus half a cell
    # clear all the way (on a slant those clear enough, if any, touch diagonally too)
    bare_tight = grid_search.clear_of(squared, tight, RES)
    assert grid_search.theta_star(bare_tight, start_cell, goal_cell) is None
    for level in (1, 2):
        _, parts = cv2.connectedComponents(levels[level].view(np.uint8), connectivity=4)
        joined = parts[start_cell] == parts[goal_cell]  # as NavTopo's local planner labels a level before a search
        cells = grid_search.theta_star(levels[level], start_cell, goal_cell)
        assert joined == (cells is not None)
        if cells is not None:
            assert legal_steps(free, cells)
            assert np.sqrt(squared[cells[:, 0], cells[:, 1]]).min() >= grid_search.bridge_clearance(least[level]) - 1e-9
    assert cells is not None  # the medial level joins them
    occupied = grid.centres(grid.cells == OCCUPIED)
    for planned in (
        plan_path(levels, grid.frame, start, goal),
        GridPlanner(grid, RADIUS, PlanningConfig(unknown_fallback=False)).plan(start, goal, np.zeros((0, 2))),
    ):
        assert planned is not None and planned.level in (1, 2)
        floor = grid_search.bridge_clearance(least[planned.level])
        # the centre keeps the bridge's clearance from every wall cell's centre, less between path cells
        # at most the half diagonal of a cell (each point of a segment lies in a passable cell it crosses)
        assert distance_to_polyline(occupied, planned.points).min() >= (floor - SQRT1_2) * RES - 1e-9


def test_free_space_that_meets_only_at_a_wall_corner_is_not_joined():
    """Two rooms of the raw map that meet only at the corner of an occupied cell (a diagonal touch
    whose two side cells are walls): no bridge, at any level, even one that keeps the robot's
    centre a single cell from the walls (where the rooms' corner cells are passable)."""
    cells = np.full((20, 20), OCCUPIED, np.uint8)
    cells[1:10, 1:10] = FREE
    cells[10:19, 10:19] = FREE  # (9, 9) and (10, 10) touch at a corner; (9, 10) and (10, 9) are walls
    grid = GridMap(cells, np.zeros(2), RES)
    free = cells == FREE
    squared = grid_search.clearance_squared(free)
    for radius in (RES / 2, RES):
        mask = grid_search.passable(squared, radius, RES, radius)
        assert mask[9, 9] and mask[10, 10] and not mask[9, 10] and not mask[10, 9]
        assert grid_search.theta_star(mask, (5, 5), (14, 14)) is None
    planner = GridPlanner(grid, RADIUS, PlanningConfig(unknown_fallback=False))
    assert planner.plan(np.array([0.5, 0.5]), np.array([1.5, 1.5]), np.zeros((0, 2))) is None


@pytest.mark.parametrize("seed", range(6))
def test_new_obstacles_remake_the_masks_round_them_as_a_whole_map_transform_would(seed):
    """Blocked cells (a shut door, a box) change every level's mask only near them: the masks the
    planner remakes in their window equal a transform of the whole map with them as walls, also
    when tiles made at an earlier plan are kept; the line-of-sight raster patched round them is
    that mask where nonzero, and never above its Chebyshev clearance (what line of sight leaps on)."""
    rng = np.random.default_rng(seed)
    cells = np.full((120, 160), FREE, np.uint8)
    cells[rng.random(cells.shape) < 0.02] = OCCUPIED  # speckle, and walls with doors of 6-11 cells
    for col in range(20, 160, 35):
        cells[:, col] = OCCUPIED
        door = int(rng.integers(10, 100))
        cells[door : door + int(rng.integers(6, 12)), col] = FREE
    cells[rng.random(cells.shape) < 0.01] = UNKNOWN  # a few unknown cells
    planner = GridPlanner(GridMap(cells, np.zeros(2), RES), RADIUS, PlanningConfig(unknown_fallback=True))
    blocked = np.zeros(cells.shape, bool)
    centre = rng.integers([10, 10], [110, 150])
    blocked[tuple((centre + rng.integers(-6, 7, size=(12, 2))).T)] = True
    if seed % 2:
        blocked[tuple(rng.integers([0, 0], cells.shape, size=(3, 2)).T)] = True  # and far apart
    more = blocked.copy()
    more[tuple((centre + rng.integers(-3, 4, size=(4, 2))).T)] = True  # seen next: tiles far from them are kept
    for key in planner.attempts:
        kind, radius, medial = key
        free = (cells == FREE) if kind == "known" else (cells != OCCUPIED)
        for cut in (blocked, more, blocked):
            whole = grid_search.passable(grid_search.clearance_squared(free & ~cut), radius, RES, medial)
            assert np.array_equal(planner.with_blocked(key, np.argwhere(cut)), whole), key
            if key not in planner._sight:
                planner._sight[key] = grid_search.sight_raster(planner.mask(key))
            patched = planner.sight_with_blocked(key, whole, np.argwhere(cut))
            assert np.array_equal(patched > 0, whole) and (patched <= grid_search.sight_raster(whole)).all()


def test_the_masks_kept_bit_packed_and_as_sight_rasters_are_the_eroded_free_space():
    """The planner keeps the first level's line-of-sight raster, the fallbacks' masks as bits and a
    searched fallback's line-of-sight raster: each gives back the level's eroded free space
    exactly, and its bytes count what is kept."""
    grid = two_rooms(5)
    grid.cells[5:9, 60:70] = UNKNOWN
    planner = GridPlanner(grid, RADIUS, PlanningConfig())
    for kind, radius, medial in planner.attempts:
        free = grid.cells == FREE if kind == "known" else grid.cells != OCCUPIED
        assert np.array_equal(
            planner.mask((kind, radius, medial)), grid_search.passable(grid_search.clearance_squared(free), radius, RES, medial)
        )
    before = planner.nbytes
    # the fallbacks' bits, the first level's line-of-sight bytes, the clearance bytes
    assert before == sum((grid.cells.size + 7) // 8 for _ in planner.attempts[1:]) + 2 * grid.cells.size
    expected = {key: planner.mask(key) for key in planner.attempts}
    assert planner.plan(np.array([2.0, 1.0]), np.array([6.0, 3.0]), np.zeros((0, 2))) is not None  # the medial level
    searched = len(planner._sight) - 1
    assert searched >= 1 and planner.nbytes == before + searched * grid.cells.size
    assert all(np.array_equal(planner.mask(key), expected[key]) for key in planner.attempts)
    planner.forget()
    assert planner.nbytes == before


def test_a_goal_field_serves_the_plans_after_the_first_to_the_same_goal():
    """With ``goal_field``: the first plan to a goal searches, the second makes the field rooted at
    the goal and every later one descends it: paths the search's length within 1 %, the field
    counted in the planner's bytes while the goal lasts, dropped by ``forget``."""
    grid = two_rooms(8)
    planner = GridPlanner(grid, RADIUS, PlanningConfig(goal_field=True))
    searching = GridPlanner(grid, RADIUS, PlanningConfig(goal_field=False))
    goal, none = np.array([6.5, 3.0]), np.zeros((0, 2))
    starts = [np.array([1.0, 1.0]), np.array([2.0, 3.5]), np.array([3.5, 0.8]), np.array([1.2, 2.0])]
    for k, start in enumerate(starts):
        planned, expected = planner.plan(start, goal, none), searching.plan(start, goal, none)
        assert planned is not None and expected is not None and planned.level == expected.level
        length = float(np.hypot(*np.diff(planned.points, axis=0).T).sum())
        assert length == pytest.approx(float(np.hypot(*np.diff(expected.points, axis=0).T).sum()), rel=0.01)
        assert bool(planner._fields) == (k >= 1)
    kept = sum(field.nbytes for _, field in planner._fields.values())
    assert planner.nbytes == searching.nbytes + kept
    # 16 bits a cell of the tiles a way leads into, the unreached rest one shared tile
    for _, field in planner._fields.values():
        assert field.nbytes == field.steps.tile_of.nbytes + 2 * 16 * 16 * len(field.steps.tiles)
        assert len(field.steps.tiles) - 1 == int((field.steps.tile_of > 0).sum())
    planner.forget()
    assert not planner._fields
