"""Paths eased off walls where there is room (navkit.grid_planning.ease_path), against crafted grids
whose clearances are known: a corridor with a wall stub, a door approached on a slant, a passage
narrower than the clearance asked for."""

from __future__ import annotations

import numpy as np

from navkit import grid_search
from navkit.grid_planning import densify, leg_clearances, plan_path
from navkit.raster import GridFrame

RES = 0.1
RADIUS = 0.3
WIDE = RADIUS + RES / 2 + 0.1  # the systems' first level: radius, half a cell, 0.1 m margin
PREFER = WIDE + 0.2


def raster_clearance(squared: np.ndarray, frame: GridFrame):
    """Points (N, 2) -> metres to the nearest non-free cell's centre, bilinear between cell centres."""
    from scipy import ndimage

    distance = np.sqrt(squared) * frame.resolution

    def at(xy):
        rc = (np.asarray(xy, float).reshape(-1, 2)[:, ::-1] - frame.origin[::-1]) / frame.resolution - 0.5
        return ndimage.map_coordinates(distance, rc.T, order=1, mode="nearest")

    return at


def cells_of(mask: np.ndarray, frame: GridFrame):
    """Points (N, 2) -> whether each lies in a set cell of ``mask``."""

    def at(xy):
        cells = frame.to_cell(xy)
        inside = (cells >= 0).all(1) & (cells[:, 0] < mask.shape[0]) & (cells[:, 1] < mask.shape[1])
        out = np.zeros(len(cells), bool)
        out[inside] = mask[cells[inside, 0], cells[inside, 1]]
        return out

    return at


def _plan(free: np.ndarray, start, goal, prefer: float = 0.0):
    frame = GridFrame(np.zeros(2), RES)
    squared = grid_search.clearance_squared(free)
    masks = [grid_search.passable(squared, r, RES) for r in (WIDE, RADIUS + RES / 2)]
    clearance = raster_clearance(squared, frame)
    planned = plan_path(masks, frame, start, goal, clearance=squared, prefer_m=prefer)
    assert planned is not None
    return planned, clearance, masks[planned.level], frame


def _least(points, clearance) -> float:
    return float(leg_clearances(points, clearance, RES / 4).min())


def _length(points) -> float:
    return float(np.hypot(*np.diff(points, axis=0).T).sum())


def _corridor_with_stub() -> np.ndarray:
    """A corridor 2.2 m wide (rows 10-31 free), 12 m long, a wall stub 0.4 m into it from the top
    at x 5.5-6.5 m."""
    free = np.zeros((42, 120), bool)
    free[10:32, 0:120] = True
    free[28:32, 55:65] = False
    return free


def test_a_path_past_a_wall_stub_keeps_the_preferred_clearance():
    free = _corridor_with_stub()
    start, goal = (1.0, 2.75), (11.0, 2.75)  # along the corridor, near the stub's side
    shortest, clearance, _, _ = _plan(free, start, goal)
    eased, _, passable, frame = _plan(free, start, goal, PREFER)
    # the shortest path grazes the stub at the first level's clearance
    assert _least(shortest.points, clearance) < WIDE + 0.05
    # the eased one keeps the preferred clearance away from its ends (both ends have room)
    inner = eased.points
    body = densify(inner, RES / 4)
    far = np.minimum(np.hypot(*(body - start).T), np.hypot(*(body - goal).T)) > 2 * PREFER
    assert clearance(body[far]).min() >= PREFER - 0.03
    # at a small cost in length, on passable cells throughout, ends exact
    assert _length(inner) < 1.03 * _length(shortest.points)
    assert cells_of(passable, frame)(body).all()
    np.testing.assert_allclose(inner[0], start)
    np.testing.assert_allclose(inner[-1], goal)


def test_a_door_on_a_slant_is_passed_near_its_middle():
    """A wall across a room with a 1.3 m door; start and goal offset so the shortest path crosses
    the door on a slant, grazing a jamb at the first level's clearance."""
    free = np.zeros((80, 80), bool)
    free[1:79, 1:79] = True
    free[38:42, :] = False  # the wall, y 3.8-4.2 m
    free[38:42, 34:47] = True  # the door, x 3.4-4.7 m: 0.7 m from the jambs' cells at its middle
    start, goal = (6.5, 1.5), (1.5, 6.5)
    shortest, clearance, _, _ = _plan(free, start, goal)
    eased, _, passable, frame = _plan(free, start, goal, PREFER)
    middle = float(clearance(np.array([[4.05, 4.0]]))[0])
    assert _least(shortest.points, clearance) < middle - 0.05
    assert _least(eased.points, clearance) >= min(middle, PREFER) - 0.03
    assert cells_of(passable, frame)(densify(eased.points, RES / 4)).all()
    assert _length(eased.points) < 1.05 * _length(shortest.points)


def test_a_passage_narrower_than_preferred_is_followed_along_its_middle():
    """A 1.2 m corridor (clearance 0.6 m at its middle, below the preferred 0.75 m) with a bend:
    the eased path runs along the middle, as clear as the corridor allows."""
    free = np.zeros((80, 80), bool)
    free[10:22, 5:70] = True  # along x, y 1.0-2.2 m
    free[10:75, 58:70] = True  # then up, x 5.8-7.0 m
    start, goal = (1.0, 1.6), (6.4, 7.0)
    start = (0.9, 1.6)
    eased, clearance, passable, frame = _plan(free, start, goal, PREFER)
    body = densify(eased.points, RES / 4)
    far = np.minimum(np.hypot(*(body - start).T), np.hypot(*(body - goal).T)) > 2 * PREFER
    # the corridor's middle is 0.55 m from the wall cells' centres; the bend's outer corner leaves more
    assert clearance(body[far]).min() >= 0.55 - 0.06
    assert cells_of(passable, frame)(body).all()


def test_no_preference_keeps_the_shortest_path():
    free = _corridor_with_stub()
    plain, _, _, _ = _plan(free, (1.0, 2.75), (11.0, 2.75))
    zero, _, _, _ = _plan(free, (1.0, 2.75), (11.0, 2.75), 0.0)
    np.testing.assert_array_equal(plain.points, zero.points)


def test_the_compiled_thinning_keeps_the_points_simplify_clear_keeps():
    """The easing's thinning runs compiled in cell units; on wobbly paths along a corridor with a
    pillar (chords that must keep the clearance, and some that cannot) it keeps the points the
    vectorized ``simplify_clear`` keeps, at a slack that keeps exact ties out of the comparison."""
    from navkit.grid_planning import _simplify_clear_kernel, clearance_at, simplify_clear

    free = np.zeros((40, 120), bool)
    free[5:35, 2:118] = True
    free[17:23, 50:56] = False  # a pillar
    frame = GridFrame(np.zeros(2), RES)
    squared = grid_search.clearance_squared(free)
    rng = np.random.default_rng(5)
    for _ in range(20):
        x = np.linspace(0.5, 11.5, 90)
        y = 2.0 + 1.2 * np.sin(x * rng.uniform(0.3, 1.5)) + rng.normal(0.0, 0.03, x.size)
        points = np.stack([x, y], 1)
        cells = points[:, ::-1] / RES  # continuous (row, col): the frame sits at the origin
        keep = np.zeros(len(points), bool)
        keep[45] = True  # pinned
        _simplify_clear_kernel(cells[:, 0].copy(), cells[:, 1].copy(), squared, 0.25, 6.0, 0.25, 0.01, keep)
        pinned = np.zeros(len(points), bool)
        pinned[45] = True
        clear_at = clearance_at(squared, frame)
        expected = simplify_clear(points, clear_at, RES / 4, cap=0.6, step=RES / 4, slack=0.001, pinned=pinned)
        assert np.array_equal(points[keep], expected)
