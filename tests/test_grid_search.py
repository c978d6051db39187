"""A* and Theta* on grids, checked against exact answers (closed-form paths, Dijkstra, EDT)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.ndimage import distance_transform_cdt, distance_transform_edt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from navkit import grid_search as gs
from navkit.raster import GridFrame

RES = 0.05
RADIUS = 0.3


def centres(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """World x, y of every cell centre of a grid with origin (0, 0) at RES."""
    rows, cols = np.mgrid[0:height, 0:width]
    return (cols + 0.5) * RES, (rows + 0.5) * RES


# A 8 m x 12 m room split by a 0.2 m thick wall from the bottom edge up to y = 5.5 m, as the
# scenario code rasterises shapes: a cell is free iff its centre lies outside the wall.
ROOM_H, ROOM_W = 160, 240
WALL_X0, WALL_X1, WALL_TOP = 5.9, 6.1, 5.5


@pytest.fixture(scope="module")
def room() -> np.ndarray:
    x, y = centres(ROOM_H, ROOM_W)
    return ~((x > WALL_X0) & (x < WALL_X1) & (y < WALL_TOP))


def around_wall_end(start_xy: np.ndarray, goal_xy: np.ndarray) -> float:
    """Exact shortest path from the left of the wall to its right, over its top, for a disc
    robot of RADIUS: tangent to the circle around the top-left corner, arc, the wall's
    thickness across the top, arc around the top-right corner, tangent to the goal."""
    left = np.array([WALL_X0, WALL_TOP])
    right = np.array([WALL_X1, WALL_TOP])
    d_start = np.linalg.norm(left - start_xy)
    d_goal = np.linalg.norm(goal_xy - right)
    # heading of the tangent leaving the start, and of the one arriving at the goal
    out_heading = math.atan2(*(left - start_xy)[::-1]) + math.asin(RADIUS / d_start)
    in_heading = math.atan2(*(goal_xy - right)[::-1]) - math.asin(RADIUS / d_goal)
    assert out_heading > 0 > in_heading, "the path must turn over the top of the wall"
    return (
        math.sqrt(d_start**2 - RADIUS**2)
        + RADIUS * out_heading
        + (WALL_X1 - WALL_X0)
        + RADIUS * -in_heading
        + math.sqrt(d_goal**2 - RADIUS**2)
    )


def segment_samples(cells: np.ndarray, step: float = 0.2) -> np.ndarray:
    """Points (in cell units, row/col) every `step` cells along a cell path, ends included."""
    samples = [cells[:1].astype(float)]
    for a, b in zip(cells[:-1], cells[1:], strict=True):
        n = max(int(np.ceil(np.hypot(*(b - a)) / step)), 1)
        t = np.linspace(0.0, 1.0, n + 1)[1:, None]
        samples.append(a + t * (b - a))
    return np.concatenate(samples)


# --- coordinates -----------------------------------------------------------------------------


def test_path_length_is_euclidean_between_centres():
    assert gs.path_length(np.array([[0, 0], [3, 4], [3, 10]]), 0.5) == pytest.approx(5.5)
    assert gs.path_length(np.array([[1, 1]]), 0.5) == 0.0
    assert gs.path_length(None, 0.5) == 0.0


# --- inflation -------------------------------------------------------------------------------


def test_inflate_equals_scipy_edt_with_blocked_outside():
    rng = np.random.default_rng(4)
    free = rng.random((70, 90)) > 0.03
    free[30:40, 10:60] = False
    reference_distance = distance_transform_edt(np.pad(free, 1))[1:-1, 1:-1] * RES
    for radius in (0.05, 0.1, 0.15, 0.3, 0.35, 0.5):
        assert np.array_equal(gs.inflate_free(free, radius, RES), reference_distance >= radius)
    # outside is blocked: with a 3-cell radius an open grid keeps cells 3 or more cells from
    # the outside row -1, so it loses its two outer rows and columns
    open_grid = gs.inflate_free(np.ones((20, 20), bool), 0.15, RES)
    assert open_grid[2:-2, 2:-2].all() and not open_grid[:2].any() and not open_grid[:, -2:].any()


def test_without_disks_removes_exactly_the_cells_within_the_radius_of_each_obstacle_cell():
    rng = np.random.default_rng(7)
    passable = rng.random((60, 80)) > 0.2
    # obstacles on the grid, one just off each side (its disk reaches onto the grid), and repeats
    cells = np.vstack([rng.integers(0, 60, (40, 1)), [[-2], [30], [61], [30]]])
    cells = np.hstack([cells, np.vstack([rng.integers(0, 80, (40, 1)), [[40], [-1], [40], [81]]])])
    cells = np.vstack([cells, cells[:5]])
    rows, cols = np.mgrid[0:60, 0:80]
    for radius in (0.07, 0.12, 0.26, 0.33):  # none a whole number of cells: there the float test decides
        # the truth: each cell's distance to the nearest obstacle cell's centre, from a k-d tree
        nearest = cKDTree(cells * RES).query(np.stack([rows.ravel(), cols.ravel()], axis=1) * RES)[0].reshape(60, 80)
        out = gs.without_disks(passable, cells, radius, RES)
        assert np.array_equal(out, passable & (nearest > radius + 1e-9))
    assert passable.sum() > out.sum()  # a copy: the mask given is untouched
    assert np.array_equal(gs.without_disks(passable, np.zeros((0, 2), int), 0.3, RES), passable)


def test_the_squared_distance_transform_is_scipys_exact_one_in_integers():
    rng = np.random.default_rng(7)
    for _ in range(200):
        height, width = rng.integers(1, 50, 2)
        free = rng.random((height, width)) < rng.uniform(0.5, 1.0)
        squared = gs.clearance_squared(free)
        exact = np.square(distance_transform_edt(np.pad(free, 1))[1:-1, 1:-1])  # the outside blocked
        assert squared.dtype == np.int32 and np.array_equal(squared, np.rint(exact))
        blocked = rng.random((height, width)) < rng.uniform(0.0, 0.2)
        to_blocked = gs.squared_distance_to(blocked)  # the outside not counted
        if blocked.any():
            assert np.array_equal(to_blocked, np.rint(np.square(distance_transform_edt(~blocked))))
        else:
            assert (to_blocked == (height + width) ** 2).all()


# --- line of sight ---------------------------------------------------------------------------


def test_line_of_sight_refuses_a_segment_grazing_a_wall_corner():
    free = np.ones((10, 10), bool)
    assert gs.line_of_sight(free, (3, 4), (5, 6))  # diagonal through the corner at (5, 6)
    for blocked in [(4, 6), (5, 5)]:  # either cell beside that corner
        grid = free.copy()
        grid[blocked] = False
        assert not gs.line_of_sight(grid, (3, 4), (5, 6))
        assert not gs.line_of_sight(grid, (5, 6), (3, 4))
    # slope 1/3 from (0, 0) to (2, 6) passes exactly through the grid corner (1, 2)
    grid = free.copy()
    grid[1, 1] = False
    assert not gs.line_of_sight(grid, (0, 0), (2, 6))
    grid = free.copy()
    grid[0, 3] = False  # beside the segment, not touched by it
    grid[2, 3] = False
    assert gs.line_of_sight(grid, (0, 0), (2, 6))
    assert not gs.line_of_sight(free, (0, 0), (10, 3))  # end outside the grid


def test_line_of_sight_with_clearance_leaps_agrees_with_the_cell_walk():
    rng = np.random.default_rng(7)
    for _ in range(40):
        height, width = rng.integers(5, 60, 2)
        free = np.ones((height, width), bool)
        for _ in range(rng.integers(0, 6)):
            r, c = rng.integers(0, height), rng.integers(0, width)
            free[r : r + rng.integers(1, 8), c : c + rng.integers(1, 8)] = False
        clear = gs._chebyshev_clearance(free)
        chessboard = distance_transform_cdt(np.pad(free, 1), metric="chessboard")[1:-1, 1:-1]
        assert np.array_equal(clear, np.minimum(chessboard, 255))
        for _ in range(100):
            a = rng.integers(0, (height, width))
            b = rng.integers(0, (height, width))
            walk = gs._line_of_sight(free, a[0], a[1], b[0], b[1])
            assert walk == gs._clear_line_of_sight(clear, a[0], a[1], b[0], b[1])
    # open ground wider than the saturated clearance (255)
    free = np.ones((800, 800), bool)
    free[100:110, 100:700] = False
    clear = gs._chebyshev_clearance(free)
    assert clear.max() == 255
    for _ in range(300):
        a, b = rng.integers(0, 800, 2), rng.integers(0, 800, 2)
        walk = gs._line_of_sight(free, a[0], a[1], b[0], b[1])
        assert walk == gs._clear_line_of_sight(clear, a[0], a[1], b[0], b[1])


# --- planners --------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "start, goal",
    [
        ((20, 30), (30, 210)),  # far from the wall on both sides: a shallow bend
        ((40, 60), (40, 180)),
        ((60, 100), (15, 140)),  # close to the wall: the path wraps ~180 degrees around its top
        ((10, 105), (10, 135)),
    ],
)
def test_theta_star_matches_the_exact_shortest_path_around_a_wall(room, start, goal):
    free = gs.inflate_free(room, RADIUS, RES)
    path = gs.theta_star(free, start, goal)
    assert path is not None and path.dtype == np.int64 and path.shape[1] == 2
    assert tuple(path[0]) == start and tuple(path[-1]) == goal
    start_xy, goal_xy = GridFrame(np.zeros(2), RES).to_world(np.array([start, goal]))
    exact = around_wall_end(start_xy, goal_xy)
    assert gs.path_length(path, RES) == pytest.approx(exact, rel=0.01)
    assert all(gs.line_of_sight(free, a, b) for a, b in zip(path[:-1], path[1:], strict=True))


def test_theta_star_in_the_open_is_one_straight_segment():
    free = np.ones((40, 50), bool)
    path = gs.theta_star(free, (3, 2), (37, 45))
    assert path.tolist() == [[3, 2], [37, 45]]


def eight_connected_graph(free: np.ndarray) -> coo_matrix:
    """The 8-connected moves between free cells (no diagonal past a blocked side cell), weighted by
    their lengths in cells, as a sparse matrix over the flat cell indices."""
    height, width = free.shape
    index = np.arange(free.size).reshape(free.shape)
    rows, cols, weights = [], [], []
    for dr, dc in [(0, 1), (1, 0), (1, 1), (1, -1)]:
        r0, r1 = max(0, -dr), height - max(0, dr)
        c0, c1 = max(0, -dc), width - max(0, dc)
        a = (slice(r0, r1), slice(c0, c1))
        b = (slice(r0 + dr, r1 + dr), slice(c0 + dc, c1 + dc))
        ok = free[a] & free[b]
        if dr and dc:
            ok &= free[r0 + dr : r1 + dr, c0:c1] & free[r0:r1, c0 + dc : c1 + dc]
        rows.append(index[a][ok])
        cols.append(index[b][ok])
        weights.append(np.full(ok.sum(), math.hypot(dr, dc)))
    return coo_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))), shape=(free.size, free.size))


@pytest.mark.parametrize("seed", range(4))
def test_jump_point_search_finds_a_shortest_8_connected_path_that_never_cuts_a_corner(seed):
    """On random grids (sparse to cluttered), from random starts: the same length as Dijkstra's
    over the 8-connected moves, every step one of those moves, None exactly where none leads."""
    rng = np.random.default_rng(seed)
    for _ in range(150):
        height, width = rng.integers(2, 40, 2)
        free = rng.random((height, width)) < rng.uniform(0.55, 1.0)
        cells = np.argwhere(free)
        if len(cells) < 2:
            continue
        start, goal = (tuple(int(v) for v in cell) for cell in cells[rng.choice(len(cells), 2, replace=False)])
        index = np.arange(free.size).reshape(free.shape)
        exact = dijkstra(eight_connected_graph(free), directed=False, indices=index[start])[index[goal]]
        path = gs._jps_kernel(free, *start, *goal)
        if not np.isfinite(exact):
            assert len(path) == 0
            continue
        assert tuple(path[0]) == start and tuple(path[-1]) == goal
        assert gs.path_length(path, 1.0) == pytest.approx(exact, abs=1e-9)
        steps = np.diff(path, axis=0)
        assert (np.abs(steps).max(axis=1) == 1).all()
        for (r, c), (dr, dc) in zip(path[:-1], steps, strict=True):
            assert free[r + dr, c + dc] and (dr == 0 or dc == 0 or (free[r + dr, c] and free[r, c + dc]))
    smoothed = gs.jps_smoothed(free, start, goal)  # the last grid: pulled to any angle, still clear
    if smoothed is not None:
        assert all(gs.line_of_sight(free, a, b) for a, b in zip(smoothed[:-1], smoothed[1:], strict=True))


def test_astar_is_8_connected_optimal_and_not_shorter_than_theta_star(room):
    free = gs.inflate_free(room, RADIUS, RES)[::2, ::2]  # 80 x 120: small enough for Dijkstra
    start, goal = (10, 20), (12, 100)
    path = gs.astar(free, start, goal)
    assert path is not None and tuple(path[0]) == start and tuple(path[-1]) == goal
    steps = np.diff(path, axis=0)
    assert (np.abs(steps).max(axis=1) == 1).all()  # every step to an 8-neighbour
    assert free[path[:, 0], path[:, 1]].all()
    diagonal = (steps != 0).all(axis=1)
    corners_a = free[path[:-1][diagonal, 0] + steps[diagonal, 0], path[:-1][diagonal, 1]]
    corners_b = free[path[:-1][diagonal, 0], path[:-1][diagonal, 1] + steps[diagonal, 1]]
    assert corners_a.all() and corners_b.all()  # no diagonal step cuts a corner

    # exact 8-connected shortest path length by Dijkstra over the same moves
    index = np.arange(free.size).reshape(free.shape)
    graph = eight_connected_graph(free)
    best = dijkstra(graph, directed=False, indices=index[start])[index[goal]]
    assert gs.path_length(path, 1.0) == pytest.approx(best, abs=1e-9)
    any_angle = gs.path_length(gs.theta_star(free, start, goal), 1.0)
    assert any_angle <= gs.path_length(path, 1.0) <= any_angle * 1.0824  # octile bound


def test_theta_star_keeps_the_radius_from_every_wall():
    rng = np.random.default_rng(11)
    x, y = centres(120, 120)
    room = np.ones((120, 120), bool)
    for _ in range(25):  # random discs and boxes
        cx, cy, size = rng.uniform(0.0, 6.0), rng.uniform(0.0, 6.0), rng.uniform(0.1, 0.5)
        if rng.random() < 0.5:
            room &= np.hypot(x - cx, y - cy) > size
        else:
            room &= (np.abs(x - cx) > size) | (np.abs(y - cy) > size / 2)
    free = gs.inflate_free(room, RADIUS, RES)
    clearance = distance_transform_edt(np.pad(room, 1))[1:-1, 1:-1] * RES
    walls = cKDTree(np.argwhere(np.pad(~room, 1, constant_values=True)) - 1)  # incl. outside
    planned = 0
    for _ in range(6):
        start = gs.nearest_free(free, rng.integers(0, 120, 2), 120)
        goal = gs.nearest_free(free, rng.integers(0, 120, 2), 120)
        path = gs.theta_star(free, start, goal)
        if path is None:
            continue
        planned += 1
        samples = segment_samples(path)
        cells = np.floor(samples + 0.5).astype(int)  # the cell each sample lies in
        assert (clearance[cells[:, 0], cells[:, 1]] >= RADIUS - 1e-9).all()
        # continuous check: a sample is within half a cell diagonal of a cell centre that
        # is at least RADIUS from every wall cell centre
        gaps, _ = walls.query(samples)
        assert gaps.min() * RES >= RADIUS - RES / math.sqrt(2.0) - 1e-9
    assert planned >= 3


def test_planners_return_none_when_the_goal_cannot_be_reached():
    free = np.ones((30, 30), bool)
    free[:, 15] = False  # a wall across the whole grid
    for plan in (gs.astar, gs.theta_star):
        assert plan(free, (5, 5), (5, 25)) is None
        assert plan(free, (5, 15), (5, 5)) is None  # start in the wall
        assert plan(free, (5, 5), (-1, 5)) is None  # goal outside the grid
        assert plan(free, (5, 5), (5, 40)) is None
        assert plan(free, (5, 5), (5, 5)).tolist() == [[5, 5]]
    # a diagonal gap between two blocked cells is not a way through
    free = np.ones((10, 10), bool)
    free[:5, 5] = False
    free[5:, 4] = False
    free[4, 4] = True
    assert gs.astar(free, (0, 0), (0, 9)) is None
    assert gs.theta_star(free, (9, 0), (0, 9)) is None


def test_nearest_free_moves_a_cell_out_of_the_inflated_zone():
    free = np.zeros((20, 20), bool)
    free[10:, 12:] = True
    assert gs.nearest_free(free, (15, 15), 3) == (15, 15)
    assert gs.nearest_free(free, (5, 15), 10) == (10, 15)
    assert gs.nearest_free(free, (8, 9), 10) == (10, 12)  # the corner, sqrt(13) away
    assert gs.nearest_free(free, (5, 15), 4) is None
    assert gs.nearest_free(free, (25, 25), 10) == (19, 19)  # outside the grid


def test_nearest_free_through_snaps_over_no_wall():
    """A robot in a room no location saw, a wall between it and the corridor's free cells a metre
    off: snapped over the wall it drove into it. With ``through`` (no wall cell on the way) the cell
    beyond the wall does not count; the one in the room, farther, does."""
    free = np.zeros((30, 30), bool)
    free[10:20, 16:] = True  # the corridor, east of the wall
    free[10:20, :3] = True  # free cells in the room, far to the west
    wall = np.zeros_like(free)
    wall[:, 13] = True
    robot = (15, 11)
    assert gs.nearest_free(free, robot, 10) == (15, 16)  # through the wall, 5 cells
    assert gs.nearest_free(free, robot, 10, through=~wall) == (15, 2)  # in the room, 9 cells
    assert gs.nearest_free(free, robot, 6, through=~wall) is None
    assert gs.nearest_free(free, (15, 17), 10, through=~wall) == (15, 17)  # a free cell is itself


def test_passable_joins_every_diagonal_touch_through_a_clear_free_side_cell():
    """On random rubble (0.05 m cells, the robot's 0.3 m): what a level's cells joined only by
    diagonal steps (8-connected), the search's 4-connected moves now join; each cell added for it
    is free and ``bridge_clearance`` clear. On a level of bare free cells (a radius of one cell)
    the diagonal touches are wall corners: nothing is added."""
    from scipy import ndimage

    bridged = corners = 0
    for seed in range(751, 755):
        rng = np.random.default_rng(seed)
        free = ndimage.binary_opening(rng.random((120, 120)) > 0.04, iterations=1)
        squared = gs.clearance_squared(free)
        for radius, medial in ((RADIUS + RES / 2, None), (RADIUS + RES / 2, RADIUS), (RES, RES)):
            bare = gs.clear_of(squared, radius, RES)
            if medial is not None:
                bare |= gs.medial_axis(squared) & gs.clear_of(squared, medial, RES)
            mask = gs.passable(squared, radius, RES, medial)
            added = mask & ~bare
            assert (bare <= mask).all() and free[added].all()
            if radius == RES:
                corners += int((bare[:-1, :-1] & bare[1:, 1:] & ~bare[:-1, 1:] & ~bare[1:, :-1]).sum())
                assert not added.any()
                continue
            bridged += int(added.sum())
            least = min(radius, medial or radius) / RES
            assert (np.sqrt(squared[added]) >= gs.bridge_clearance(least) - 1e-9).all()
            eight, _ = ndimage.label(bare, np.ones((3, 3), bool))
            four, _ = ndimage.label(mask)
            cells = np.flatnonzero(bare)
            # one 4-connected part of the result for each 8-connected part of the bare level
            pairs = np.unique(np.stack([eight.ravel()[cells], four.ravel()[cells]]), axis=1)
            assert len(np.unique(pairs[0])) == pairs.shape[1]
    assert bridged and corners  # both cases met


@pytest.mark.parametrize("start, goal", [((20, 30), (30, 210)), ((60, 100), (15, 140)), ((10, 105), (10, 135))])
def test_astar_string_pulled_matches_the_exact_shortest_path_around_a_wall(room, start, goal):
    free = gs.inflate_free(room, RADIUS, RES)
    path = gs.astar_smoothed(free, start, goal)
    assert path is not None and tuple(path[0]) == start and tuple(path[-1]) == goal
    start_xy, goal_xy = GridFrame(np.zeros(2), RES).to_world(np.array([start, goal]))
    assert gs.path_length(path, RES) == pytest.approx(around_wall_end(start_xy, goal_xy), rel=0.01)
    assert all(gs.line_of_sight(free, a, b) for a, b in zip(path[:-1], path[1:], strict=True))


def test_a_goal_field_is_dijkstra_from_the_goal_and_gives_paths_from_any_start(room):
    free = gs.inflate_free(room, RADIUS, RES)[::2, ::2]
    free[40:44, 70:90] = False  # a second obstacle, and cells no way reaches
    free[5:8, 5:8] = True
    free[4, 4:9] = free[8, 4:9] = free[4:9, 4] = free[4:9, 8] = False
    goal = (12, 100)
    field = gs.goal_field(free, goal)
    index = np.arange(free.size).reshape(free.shape)
    exact = dijkstra(eight_connected_graph(free), directed=False, indices=index[goal]).reshape(free.shape)
    reached = np.isfinite(exact) & free
    lengths = field.cells()
    assert field.steps.dtype == np.uint16 and field.per_cell == gs.FIELD_PER_CELL
    assert np.array_equal(np.isfinite(lengths), reached)
    assert np.abs(lengths[reached] - exact[reached]).max() <= 0.5 / field.per_cell  # rounded to its steps
    sight = gs.sight_raster(free)
    for start in [(10, 20), (70, 10), (45, 80), (12, 101)]:
        path = gs.field_path(free, field, start, sight)
        assert path is not None and tuple(path[0]) == start and tuple(path[-1]) == goal
        assert all(gs.line_of_sight(free, a, b) for a, b in zip(path[:-1], path[1:], strict=True))
        any_angle = gs.path_length(gs.theta_star(free, start, goal), 1.0)
        assert gs.path_length(path, 1.0) == pytest.approx(any_angle, rel=0.01)  # either may be the shorter
    assert gs.field_path(free, field, (6, 6), sight) is None  # the sealed pocket


def test_a_goal_field_longer_than_its_16_bits_takes_coarser_steps_and_still_leads_to_the_goal():
    free = np.zeros((41, 1200), bool)  # a serpentine: 20 lanes of 1200 cells, about 24,000 cells long
    free[::2, :] = True
    for lane in range(20):
        free[2 * lane + 1, -1 if lane % 2 == 0 else 0] = True
    goal = (40, 600)
    field = gs.goal_field(free, goal)
    index = np.arange(free.size).reshape(free.shape)
    exact = dijkstra(eight_connected_graph(free), directed=False, indices=index[goal]).reshape(free.shape)
    assert field.per_cell < 65534 / 20000  # coarser than 1/8 cell: 16 bits hold the longest path
    reached = np.isfinite(exact)
    assert np.abs(field.cells()[reached] - exact[reached]).max() <= 0.5 / field.per_cell
    path = gs.field_path(free, field, (0, 0))
    assert path is not None and tuple(path[0]) == (0, 0) and tuple(path[-1]) == goal
    assert gs.path_length(path, 1.0) == pytest.approx(exact[0, 0], rel=0.01)
