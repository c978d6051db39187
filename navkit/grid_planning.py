"""Planning a path between two metric points on an occupancy raster: the one function every grid
planner of the benchmark calls (the oracle on the ground-truth raster, the metric baseline on its
global grid, NavTopo's local planner on its union grid, and the scenario's route and trial legs).

``plan_path`` tries a list of passable masks in order (e.g. free space eroded by the robot radius
plus a margin, then by the radius alone, then with unknown cells counted as free); on each it snaps
the start and the goal to the nearest passable cell within ``snap_cells`` (a robot a few
centimetres inside an inflated zone still gets a path), searches with Lazy Theta*
(``navkit.grid_search``), and returns the first path found as metric points with the exact start
and goal at its ends. A snapped end cell more than a cell and a half from its exact point stays on
the path, as the way into the planned free space.

**Keeping clear where there is room** (``ease_path``, used by ``plan_path`` when it is given the
free space's clearance): a shortest path found on a level hugs that level's boundary wherever it
bends or passes a wall stub, at exactly the level's clearance: the margin the robot keeps against its
own pose error is the level's margin alone, and on the tighter levels (a door the first level does
not pass) that is a few centimetres along the whole path. As a Nav2 user's inflation cost keeps
paths off walls where the corridor is wide, the found path is eased, like an elastic band: each point
is pushed up the clearance's slope until it is ``prefer_m`` clear or at the middle of its passage,
while a smoothing pull keeps the band taut; the ends stay put. A point the push would take off the
level's passable cells stays where it was; if any stretch of the eased path leaves them, the found
path is kept as it was. The eased path is then thinned (Douglas-Peucker at a quarter cell, which loses
at most that much clearance, by ``simplify_clear``'s clearance rule, the one that thins the scenario
generator's routes, compiled here on the raster).

Raster convention (``navkit.grid_search``): ``mask[row, col]``, row ↔ y, col ↔ x, the centre of
cell (r, c) at ``origin + ((c + 0.5) * resolution, (r + 0.5) * resolution)``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from navkit import grid_search
from navkit.raster import GridFrame

ClearanceAt = Callable[[NDArray[np.float64]], NDArray[np.float64]]  # (N, 2) points -> (N,) clearance
# a cell search: (level, passable, start cell, goal cell, the mask's sight raster or None) -> (K, 2) cells or None
Search = Callable[[int, NDArray[np.bool_], tuple[int, int], tuple[int, int], NDArray[np.uint8] | None], NDArray[np.int64] | None]


def theta_star_search(
    level: int, passable: NDArray[np.bool_], start: tuple[int, int], goal: tuple[int, int], sight: NDArray[np.uint8] | None
) -> NDArray[np.int64] | None:
    """``plan_path``'s default search: Lazy Theta* on every level."""
    return grid_search.theta_star(passable, start, goal, sight)


@dataclass(frozen=True)
class PlannedPath:
    points: NDArray[np.float64]  # (K, 2) metric, exact start first and exact goal last
    level: int  # index of the mask the path was found on (0: the first, most cautious one)

    @property
    def length(self) -> float:
        return float(np.hypot(*np.diff(self.points, axis=0).T).sum()) if len(self.points) > 1 else 0.0


def plan_path(
    masks: Sequence[NDArray[np.bool_]] | Callable[[int], NDArray[np.bool_]],
    frame: GridFrame,
    start_xy: ArrayLike,
    goal_xy: ArrayLike,
    snap_cells: int = 0,
    levels: int | None = None,
    exact_goal: bool = True,
    clearance: NDArray | None = None,
    prefer_m: float = 0.0,
    hold_m: float = 0.0,
    horizon_m: float | None = None,
    sight: Callable[[int], NDArray[np.uint8] | None] | None = None,
    search: Search = theta_star_search,
    snap_through: NDArray[np.bool_] | None = None,
) -> PlannedPath | None:
    """The first path found on ``masks`` in order (see the module docstring), or None.

    masks: passable (H, W) bool rasters, or a callable giving the i-th one on demand (a caller that
    builds its fallbacks only when needed), then with ``levels`` their number.
    exact_goal: end at ``goal_xy`` itself (default); False ends at the free cell the goal snapped
    to, for a goal the robot does not fit at (a goal estimated off into a wall is approached, never
    driven into).
    clearance, prefer_m: the free space's squared clearance in cells (``grid_search.clearance_squared``
    or a capped uint8 copy; to non-free cells' centres, as the levels' radii count it) and the
    clearance the path keeps where the free space allows: the path found is eased (``ease_path``,
    on the level's passable cells; its points less clear than ``hold_m`` stay, e.g. on a narrow
    passage's medial line; only its first ``horizon_m`` metres, if set). None (default): as found.
    sight: the i-th mask's ``grid_search.sight_raster``, for a caller that keeps it (None, or a
    callable that gives None: made for each search).
    search: the cell search, ``(level, passable, start, goal, sight) -> cells or None`` (Lazy
    Theta*; the metric baseline's A* and goal field).
    snap_through: (H, W) bool, optional: an end snaps only to a cell the straight line reaches over
    these cells (``grid_search.nearest_free``'s ``through``: no wall cell between the robot and the
    cell its path starts from).
    """
    start_xy = np.asarray(start_xy, dtype=np.float64)[:2]
    goal_xy = np.asarray(goal_xy, dtype=np.float64)[:2]
    start_cell = frame.to_cell(start_xy)
    goal_cell = frame.to_cell(goal_xy)
    count = levels if callable(masks) else len(masks)
    for level in range(count or 0):
        passable = masks(level) if callable(masks) else masks[level]
        start = grid_search.nearest_free(passable, start_cell, snap_cells, snap_through)
        goal = grid_search.nearest_free(passable, goal_cell, snap_cells, snap_through)
        if start is None or goal is None:
            continue
        cells = search(level, passable, start, goal, None if sight is None else sight(level))
        if cells is None:
            continue
        end_xy = goal_xy if exact_goal else frame.to_world(cells[-1:])[0]
        points = waypoints(frame, cells, start_xy, end_xy)
        if clearance is not None and prefer_m > 0.0:
            points = ease_path(points, frame, clearance, passable, prefer_m, hold_m, horizon_m)
        return PlannedPath(points, level)
    return None


# the most an 8-connected path is longer than the straight line it follows: 1 / cos(22.5 deg)
GRID_STRETCH = math.sqrt(4.0 - 2.0 * math.sqrt(2.0))


def within_length(frame: GridFrame, shape: tuple[int, int], a: ArrayLike, b: ArrayLike, length: float) -> NDArray[np.bool_]:
    """The cells (``shape``, of ``frame``) a cell path from ``a`` to ``b`` (metric points) can pass
    when the way it stands for is no longer than ``length`` m: those whose centre p has |p - a| +
    |p - b| <= ``GRID_STRETCH`` length plus two cells (an ellipse with foci a and b; every point of
    a way that long lies in the ellipse of ``length``, and the 8-connected shortest path near it
    is at most ``GRID_STRETCH`` times longer). ``passable & within_length(...)`` bounds a search
    whose result is refused past ``length`` (a way round through unknown space far longer than the
    straight line): where there is none so short the search gives up at the ellipse, not after
    every cell it can reach; where there is one, a shortest path as long as the whole grid's lies inside."""
    a, b = np.asarray(a, dtype=np.float64)[:2], np.asarray(b, dtype=np.float64)[:2]
    reach = GRID_STRETCH * length + 2.0 * frame.resolution
    inside = np.zeros(shape, np.bool_)
    lo = frame.to_cell(np.minimum(a, b) - reach / 2.0)
    hi = frame.to_cell(np.maximum(a, b) + reach / 2.0)
    r0, c0 = max(int(lo[0]), 0), max(int(lo[1]), 0)
    r1, c1 = min(int(hi[0]) + 1, shape[0]), min(int(hi[1]) + 1, shape[1])
    if r0 >= r1 or c0 >= c1:
        return inside
    xs = frame.to_world(np.stack([np.full(c1 - c0, r0), np.arange(c0, c1)], axis=1))[:, 0]
    ys = frame.to_world(np.stack([np.arange(r0, r1), np.full(r1 - r0, c0)], axis=1))[:, 1]
    to_a = np.sqrt(np.square(ys - a[1])[:, None] + np.square(xs - a[0])[None, :])
    to_b = np.sqrt(np.square(ys - b[1])[:, None] + np.square(xs - b[0])[None, :])
    inside[r0:r1, c0:c1] = to_a + to_b <= reach
    return inside


def waypoints(frame: GridFrame, cells: NDArray, start_xy: NDArray, goal_xy: NDArray) -> NDArray[np.float64]:
    """A cell path as metric points with the exact start and goal at its ends; an end cell more than
    a cell and a half from its exact point stays, as the way into the planned free space."""
    points = frame.to_world(cells)
    near = 1.5 * frame.resolution
    head = points[1:] if np.hypot(*(points[0] - start_xy)) <= near else points
    if len(head) and np.hypot(*(head[-1] - goal_xy)) <= near:
        head = head[:-1]
    return np.vstack([start_xy[None], head, goal_xy[None]])


EASE_ITERATIONS = 40  # push-and-pull rounds of ``ease_path``
EASE_PULL = 0.25  # the smoothing pull's share of the way to the neighbours' midpoint, per round
EASE_RAMP = 3.0  # points move fully from this many ``prefer_m`` along the path from its ends, less nearer


def ease_path(
    points: NDArray[np.float64],
    frame: GridFrame,
    squared: NDArray,
    passable: NDArray[np.bool_],
    prefer_m: float,
    hold_m: float = 0.0,
    horizon_m: float | None = None,
) -> NDArray[np.float64]:
    """The path (K, 2) eased off the walls where there is room (see the module docstring): points
    every cell along it pushed up the clearance (``squared``: ``grid_search.clearance_squared`` of
    the free space, or a capped uint8 copy, in ``frame``) toward ``prefer_m`` and pulled taut, never
    off the ``passable`` cells nor below the clearance a point had or ``prefer_m``; points less clear
    than ``hold_m`` (a narrow passage's medial line) and the ends keep their place, and the points near them move the less
    the nearer they are (fully from ``EASE_RAMP * prefer_m`` along the path: no sharp bend between
    an end near a wall and the eased path). Then thinned by ``simplify_clear`` at a quarter cell,
    a chord kept only if it is as clear as the points it replaces (up to ``prefer_m``). The path as
    given if any stretch of the thinned one leaves the passable cells. The rounds are compiled.
    ``horizon_m``: only the first so many metres are eased (the point there stays put), the rest is
    kept as found: a robot that plans again every few seconds drives only the near part of a path,
    and the easing's cost grows with the length eased."""
    points = np.asarray(points, dtype=np.float64)
    res = frame.resolution
    if len(points) < 2 or prefer_m <= 0.0:
        return points
    if horizon_m is not None:
        head, tail = split_at(points, horizon_m)
        if len(tail) > 1:
            eased = ease_path(head, frame, squared, passable, prefer_m, hold_m)
            return np.vstack([eased, tail[1:]])
    dense = densify(points, res)
    if len(dense) < 3:
        return points
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(dense, axis=0).T))])
    weight = np.clip(np.minimum(arc, arc[-1] - arc) / (EASE_RAMP * prefer_m), 0.0, 1.0)
    # continuous cell coordinates: cell (r, c) spans [r, r + 1) x [c, c + 1)
    col = (dense[:, 0] - frame.origin[0]) / res + frame.origin_cell[1]
    row = (dense[:, 1] - frame.origin[1]) / res + frame.origin_cell[0]
    squared = np.ascontiguousarray(squared)
    passable = np.ascontiguousarray(passable, dtype=np.bool_)
    _ease_kernel(row, col, squared, passable, prefer_m / res, hold_m / res, weight, EASE_ITERATIONS, EASE_PULL)
    eased = np.stack(
        [(col - frame.origin_cell[1]) * res + frame.origin[0], (row - frame.origin_cell[0]) * res + frame.origin[1]], 1
    )
    eased[0], eased[-1] = points[0], points[-1]  # exactly (densify may round the last point)
    # thinned in cell units: a quarter cell's tolerance, chords sampled every quarter cell
    keep = np.zeros(len(row), np.bool_)
    _simplify_clear_kernel(row, col, squared, 0.25, prefer_m / res, 0.25, 0.0, keep)
    return eased[keep] if _stays_on(passable, np.stack([row[keep], col[keep]], 1)) else points


def clearance_at(squared: NDArray, frame: GridFrame) -> ClearanceAt:
    """Points (N, 2) -> metres to the nearest non-free cell's centre, bilinear between cell centres,
    from a raster of squared clearances in cells in ``frame`` (``ease_path``'s measure)."""
    res = frame.resolution

    def at(xy: NDArray[np.float64]) -> NDArray[np.float64]:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        row = (xy[:, 1] - frame.origin[1]) / res + frame.origin_cell[0]
        col = (xy[:, 0] - frame.origin[0]) / res + frame.origin_cell[1]
        return _clearances_cells(squared, row, col) * res

    return at


@njit(cache=True)
def _clearances_cells(squared, row, col):
    out = np.empty(row.shape[0])
    for i in range(row.shape[0]):
        out[i] = _clearance_cells(squared, row[i], col[i])
    return out


@njit(cache=True)
def _clearance_cells(squared, row, col):
    """Bilinear clearance (cells) between cell centres at a continuous (row, col); clamped to the raster."""
    height, width = squared.shape
    r = min(max(row - 0.5, 0.0), height - 1.0)
    c = min(max(col - 0.5, 0.0), width - 1.0)
    r0 = min(int(r), max(height - 2, 0))
    c0 = min(int(c), max(width - 2, 0))
    r1 = min(r0 + 1, height - 1)
    c1 = min(c0 + 1, width - 1)
    fr = min(r - r0, 1.0)
    fc = min(c - c0, 1.0)
    top = math.sqrt(float(squared[r0, c0])) * (1.0 - fc) + math.sqrt(float(squared[r0, c1])) * fc
    bottom = math.sqrt(float(squared[r1, c0])) * (1.0 - fc) + math.sqrt(float(squared[r1, c1])) * fc
    return top * (1.0 - fr) + bottom * fr


@njit(cache=True)
def _on(passable, row, col):
    r = int(math.floor(row))
    c = int(math.floor(col))
    return 0 <= r < passable.shape[0] and 0 <= c < passable.shape[1] and passable[r, c]


@njit(cache=True)
def _stays_on(passable, cells):
    """Whether the polyline through ``cells`` (K, 2: continuous row, col) stays on the passable
    cells, checked every quarter cell."""
    for i in range(cells.shape[0] - 1):
        d_row = cells[i + 1, 0] - cells[i, 0]
        d_col = cells[i + 1, 1] - cells[i, 1]
        parts = max(int(math.ceil(math.hypot(d_row, d_col) * 4.0)), 1)
        for k in range(parts + 1):
            if not _on(passable, cells[i, 0] + k / parts * d_row, cells[i, 1] + k / parts * d_col):
                return False
    return True


@njit(cache=True)
def _ease_kernel(row, col, squared, passable, prefer, hold, weight, iterations, pull):
    """``ease_path``'s rounds on points in continuous cell coordinates (moved in place)."""
    n = row.shape[0]
    h = 0.5
    for _ in range(iterations):
        moved = False
        for i in range(1, n - 1):
            w = weight[i]
            if w <= 0.0:
                continue
            clear = _clearance_cells(squared, row[i], col[i])
            if clear < hold:
                continue
            short = min(max(prefer - clear, 0.0), h)
            slope_r = (_clearance_cells(squared, row[i] + h, col[i]) - _clearance_cells(squared, row[i] - h, col[i])) / (2 * h)
            slope_c = (_clearance_cells(squared, row[i], col[i] + h) - _clearance_cells(squared, row[i], col[i] - h)) / (2 * h)
            new_r = row[i] + w * (short * slope_r + pull * (0.5 * (row[i - 1] + row[i + 1]) - row[i]))
            new_c = col[i] + w * (short * slope_c + pull * (0.5 * (col[i - 1] + col[i + 1]) - col[i]))
            if new_r == row[i] and new_c == col[i] or not _on(passable, new_r, new_c):
                continue
            # no point loses clearance below the preferred (the pull alone would take a path
            # through a door of the robot's width off its middle line)
            if _clearance_cells(squared, new_r, new_c) >= min(clear, prefer) - 1e-9:
                row[i] = new_r
                col[i] = new_c
                moved = True
        if not moved:
            break


@njit(cache=True)
def _simplify_clear_kernel(row, col, squared, tolerance, cap, step, slack, keep):
    """``simplify_clear`` compiled, on points in continuous cell coordinates with the clearance of
    ``squared`` (every length in cells): ``keep`` (K,) marks the points kept (``True`` on entry:
    pinned; the ends are kept). The same stretches split at the same points, one at a time (a chord
    exactly as clear as its stretch may go either way by rounding: 2 of 180 paths on three maps kept
    a point more or less); ~100x faster than the vectorized one with a callback."""
    n = row.shape[0]
    keep[0] = True
    keep[n - 1] = True
    clear = np.empty(n)
    for i in range(n):
        clear[i] = _clearance_cells(squared, row[i], col[i])
    pending = np.empty((n, 2), np.int64)  # disjoint stretches: never more than the points
    count = 0
    anchor = 0
    for i in range(1, n):
        if keep[i]:
            if i > anchor + 1:
                pending[count, 0], pending[count, 1] = anchor, i
                count += 1
            anchor = i
    while count > 0:
        count -= 1
        first, last = pending[count, 0], pending[count, 1]
        largest, farthest = _farthest_from_chord(row, col, first, last)
        fine = largest <= tolerance and _chord_keeps_clear(row, col, squared, clear, first, last, cap, step, slack)
        if not fine:
            keep[farthest] = True
            if farthest > first + 1:
                pending[count, 0], pending[count, 1] = first, farthest
                count += 1
            if last > farthest + 1:
                pending[count, 0], pending[count, 1] = farthest, last
                count += 1


@njit(cache=True)
def _farthest_from_chord(row, col, first, last):
    """(distance, index) of the inner point of a stretch farthest from its chord (the first of equals)."""
    a_row, a_col = row[first], col[first]
    d_row, d_col = row[last] - a_row, col[last] - a_col
    norm2 = d_row * d_row + d_col * d_col
    largest, farthest = -1.0, first + 1
    for k in range(first + 1, last):
        t = 0.0
        if norm2 >= 1e-18:
            t = min(max(((row[k] - a_row) * d_row + (col[k] - a_col) * d_col) / norm2, 0.0), 1.0)
        distance = math.hypot(row[k] - (a_row + t * d_row), col[k] - (a_col + t * d_col))
        if distance > largest:
            largest, farthest = distance, k
    return largest, farthest


@njit(cache=True)
def _chord_keeps_clear(row, col, squared, clear, first, last, cap, step, slack):
    """Whether a stretch's chord, sampled every ``step``, keeps the least clearance of its points
    (up to ``cap``) less ``slack``."""
    need = clear[first]
    for k in range(first + 1, last + 1):
        need = min(need, clear[k])
    need = min(need, cap) - slack
    d_row, d_col = row[last] - row[first], col[last] - col[first]
    samples = max(int(math.ceil(math.hypot(d_row, d_col) / step)), 1) + 1
    for k in range(samples):
        t = k / (samples - 1)
        if _clearance_cells(squared, row[first] + t * d_row, col[first] + t * d_col) < need:
            return False
    return True


def split_at(points: NDArray[np.float64], arc: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The polyline (K, 2) cut ``arc`` metres along it: (the part before, ending at the cut point; the
    part after, starting there). Past its end: (all of it, its last point alone)."""
    points = np.asarray(points, dtype=np.float64)
    lengths = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    if arc >= lengths[-1]:
        return points, points[-1:]
    i = int(np.searchsorted(lengths, arc, side="right")) - 1
    cut = points[i] + (arc - lengths[i]) / (lengths[i + 1] - lengths[i]) * (points[i + 1] - points[i])
    return np.vstack([points[: i + 1], cut[None]]), np.vstack([cut[None], points[i + 1 :]])


def densify(points: ArrayLike, step: float) -> NDArray[np.float64]:
    """(M, 2) points along a polyline (K, 2), at most ``step`` apart, its vertices included (every
    leg cut into equal parts)."""
    return densify_legs(points, step)[0]


def densify_legs(points: ArrayLike, step: float) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """``densify``'s points (M, 2) and the leg each lies on (M,): leg k runs from vertex k to k + 1;
    the first point (vertex 0) is on leg 0, each leg's end vertex on that leg."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(points) < 2:
        return points.copy(), np.zeros(len(points), dtype=np.int64)
    legs = np.diff(points, axis=0)
    counts = np.maximum(np.ceil(np.hypot(legs[:, 0], legs[:, 1]) / step).astype(np.int64), 1)
    leg = np.repeat(np.arange(len(legs)), counts)
    # the k-th of each leg's ``count`` points, k = 1..count: its start plus k / count of the leg
    k = np.arange(1, int(counts.sum()) + 1) - np.repeat(np.cumsum(counts) - counts, counts)
    dense = np.vstack([points[:1], points[leg] + (k / counts[leg])[:, None] * legs[leg]])
    return dense, np.concatenate([[0], leg]).astype(np.int64)


def leg_clearances(points: NDArray, clearance_at: ClearanceAt, step: float) -> NDArray[np.float64]:
    """(K-1,) the least clearance along each leg of a polyline (K, 2), sampled every ``step`` or
    nearer, both ends included."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return np.zeros(0)
    return segment_clearances(points[:-1], points[1:], clearance_at, step)


def segment_clearances(a: NDArray, b: NDArray, clearance_at: ClearanceAt, step: float) -> NDArray[np.float64]:
    """(M,) the least clearance along each segment from ``a`` (M, 2) to ``b`` (M, 2), sampled every
    ``step`` or nearer, both ends included (one ``clearance_at`` call for all)."""
    lengths = np.linalg.norm(b - a, axis=1)
    counts = np.maximum(np.ceil(lengths / step).astype(np.int64), 1) + 1
    leg = np.repeat(np.arange(len(lengths)), counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    t = (np.arange(counts.sum()) - np.repeat(starts, counts)) / np.repeat(counts - 1, counts)
    samples = a[leg] + t[:, None] * (b[leg] - a[leg])
    return np.minimum.reduceat(clearance_at(samples), starts)


def simplify_clear(
    points: NDArray,
    clearance_at: ClearanceAt | None,
    tolerance: float,
    cap: float = 0.0,
    step: float = 0.0,
    slack: float = 0.01,
    pinned: NDArray[np.bool_] | None = None,
) -> NDArray[np.float64]:
    """Douglas-Peucker on a polyline (K, 2) with a clearance rule: a straight leg replaces a stretch
    only if it keeps as clear as the stretch's points do (less ``slack``), capped at ``cap``; legs are
    sampled every ``step``. ``pinned`` points are kept, and the ends. The stretches are split a
    level at a time, the legs of a level checked in one ``clearance_at`` call. ``clearance_at``
    None: no clearance rule (plain Douglas-Peucker)."""
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    if n <= 2:
        return points.copy()
    clear = clearance_at(points) if clearance_at is not None else None
    keep = np.zeros(n, bool) if pinned is None else np.asarray(pinned, bool).copy()
    keep[[0, -1]] = True
    anchors = np.nonzero(keep)[0]
    pending = np.array([(i, j) for i, j in zip(anchors[:-1].tolist(), anchors[1:].tolist(), strict=True) if j > i + 1])
    while len(pending):
        first, last = pending[:, 0], pending[:, 1]
        # every stretch's inner points at once: the farthest from its chord (the first of equals)
        counts = last - first - 1
        offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
        owner = np.repeat(np.arange(len(pending)), counts)
        inner = points[np.arange(counts.sum()) - np.repeat(offsets, counts) + first[owner] + 1]
        a, ab = points[first][owner], (points[last] - points[first])[owner]
        norm2 = np.einsum("ij,ij->i", ab, ab)
        t = np.clip(np.einsum("ij,ij->i", inner - a, ab) / np.where(norm2 < 1e-18, 1.0, norm2), 0.0, 1.0)
        t[norm2 < 1e-18] = 0.0
        distance = np.linalg.norm(inner - (a + t[:, None] * ab), axis=1)
        largest = np.maximum.reduceat(distance, offsets)
        at_max = np.flatnonzero(distance == largest[owner])
        _, where = np.unique(owner[at_max], return_index=True)
        farthest = at_max[where] - offsets + first + 1
        # a stretch within the tolerance of its chord: the chord must keep the stretch's clearance
        fine = largest <= tolerance
        near = np.flatnonzero(fine)
        if clear is not None and clearance_at is not None and len(near):
            least = segment_clearances(points[first[near]], points[last[near]], clearance_at, step)
            spans = np.concatenate([np.arange(i, j + 1) for i, j in pending[near]])
            bounds = np.concatenate([[0], np.cumsum(last[near] - first[near] + 1)[:-1]])
            need = np.minimum(np.minimum.reduceat(clear[spans], bounds), cap) - slack
            fine[near] = least >= need
        split = ~fine
        keep[farthest[split]] = True
        halves = np.concatenate([np.stack([first[split], farthest[split]], 1), np.stack([farthest[split], last[split]], 1)])
        pending = halves[halves[:, 1] > halves[:, 0] + 1]
    return points[keep]
