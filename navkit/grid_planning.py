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
path is kept as it was. The eased path is then thinned (Douglas-Peucker) by a rule that never trades
clearance for length: a straight leg replaces a stretch only if it keeps as clear as that stretch
(up to ``prefer_m``). The same rule thins the scenario generator's routes (``simplify_clear``).

Raster convention (``navkit.grid_search``): ``mask[row, col]``, row ↔ y, col ↔ x, the centre of
cell (r, c) at ``origin + ((c + 0.5) * resolution, (r + 0.5) * resolution)``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from navkit import grid_search
from navkit.raster import GridFrame

ClearanceAt = Callable[[NDArray[np.float64]], NDArray[np.float64]]  # (N, 2) points -> (N,) clearance, m


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
    clearance_at: ClearanceAt | None = None,
    prefer_m: float = 0.0,
) -> PlannedPath | None:
    """The first path found on ``masks`` in order (see the module docstring), or None.

    masks: passable (H, W) bool rasters, or a callable giving the i-th one on demand (a caller that
    builds its fallbacks only when needed), then with ``levels`` their number.
    exact_goal: end at ``goal_xy`` itself (default); False ends at the free cell the goal snapped
    to, for a goal the robot does not fit at (a goal estimated off into a wall is approached, never
    driven into).
    clearance_at, prefer_m: the free space's clearance (points -> metres, in the convention the
    levels' radii use) and the clearance the path keeps where the free space allows: the path found
    is eased (``ease_path``, on the level's passable cells). None (default): as found.
    """
    start_xy = np.asarray(start_xy, dtype=np.float64)[:2]
    goal_xy = np.asarray(goal_xy, dtype=np.float64)[:2]
    start_cell = frame.to_cell(start_xy)
    goal_cell = frame.to_cell(goal_xy)
    count = levels if callable(masks) else len(masks)
    for level in range(count or 0):
        passable = masks(level) if callable(masks) else masks[level]
        start = grid_search.nearest_free(passable, start_cell, snap_cells)
        goal = grid_search.nearest_free(passable, goal_cell, snap_cells)
        if start is None or goal is None:
            continue
        cells = grid_search.theta_star(passable, start, goal)
        if cells is None:
            continue
        end_xy = goal_xy if exact_goal else frame.to_world(cells[-1:])[0]
        points = waypoints(frame, cells, start_xy, end_xy)
        if clearance_at is not None and prefer_m > 0.0:
            points = ease_path(points, clearance_at, cells_of(passable, frame), prefer_m, frame.resolution)
        return PlannedPath(points, level)
    return None


def cells_of(mask: NDArray[np.bool_], frame: GridFrame) -> Callable[[NDArray[np.float64]], NDArray[np.bool_]]:
    """Points (N, 2) -> (N,) whether each lies in a set cell of ``mask`` (False off the raster)."""

    def at(xy: NDArray[np.float64]) -> NDArray[np.bool_]:
        cells = frame.to_cell(xy)
        rows, cols = cells[:, 0], cells[:, 1]
        inside = (rows >= 0) & (rows < mask.shape[0]) & (cols >= 0) & (cols < mask.shape[1])
        out = np.zeros(len(cells), bool)
        out[inside] = mask[rows[inside], cols[inside]]
        return out

    return at


def raster_clearance(squared: NDArray, frame: GridFrame) -> ClearanceAt:
    """Points (N, 2) -> clearance in metres, bilinear between cell centres, from a raster of squared
    clearances in cells (``grid_search.clearance_squared``, or a capped uint8 copy of it): the
    distance to the nearest non-free cell's centre, as the planning levels' radii count it."""
    res = frame.resolution

    def at(xy: NDArray[np.float64]) -> NDArray[np.float64]:
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        col = (xy[:, 0] - frame.origin[0]) / res + frame.origin_cell[1] - 0.5
        row = (xy[:, 1] - frame.origin[1]) / res + frame.origin_cell[0] - 0.5
        r0 = np.clip(np.floor(row).astype(np.int64), 0, max(squared.shape[0] - 2, 0))
        c0 = np.clip(np.floor(col).astype(np.int64), 0, max(squared.shape[1] - 2, 0))
        fr = np.clip(row - r0, 0.0, 1.0)
        fc = np.clip(col - c0, 0.0, 1.0)
        r1 = np.minimum(r0 + 1, squared.shape[0] - 1)
        c1 = np.minimum(c0 + 1, squared.shape[1] - 1)

        def d(r: NDArray, c: NDArray) -> NDArray[np.float64]:
            return np.sqrt(squared[r, c].astype(np.float64))

        top = d(r0, c0) * (1 - fc) + d(r0, c1) * fc
        bottom = d(r1, c0) * (1 - fc) + d(r1, c1) * fc
        return (top * (1 - fr) + bottom * fr) * res

    return at


EASE_ITERATIONS = 40  # push-and-pull rounds of ``ease_path``
EASE_PULL = 0.25  # the smoothing pull's share of the way to the neighbours' midpoint, per round
EASE_RAMP = 3.0  # points move fully from this many ``prefer_m`` along the path from its ends, less nearer


def ease_path(
    points: NDArray[np.float64],
    clearance_at: ClearanceAt,
    passable_at: Callable[[NDArray[np.float64]], NDArray[np.bool_]],
    prefer_m: float,
    step: float,
) -> NDArray[np.float64]:
    """The path (K, 2) eased off the walls where there is room (see the module docstring): points
    every ``step`` metres pushed up the clearance (``clearance_at``) toward ``prefer_m`` and pulled
    taut, never off ``passable_at``; the ends keep their place, and the points near them move the
    less the nearer they are (fully from ``EASE_RAMP * prefer_m`` along the path: no sharp bend
    between an end near a wall and the eased path). Then thinned by
    ``simplify_clear``. The path as given if any stretch of the eased one leaves ``passable_at``."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2 or prefer_m <= 0.0:
        return points
    dense = densify(points, step)
    if len(dense) < 3:
        return points
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(dense, axis=0).T))])
    weight = np.clip(np.minimum(arc, arc[-1] - arc) / (EASE_RAMP * prefer_m), 0.0, 1.0)[1:-1, None]
    h = step / 2.0
    shifts = np.array([[h, 0.0], [-h, 0.0], [0.0, h], [0.0, -h]])
    eased = dense.copy()
    for _ in range(EASE_ITERATIONS):
        inner = eased[1:-1]
        probes = clearance_at((inner[:, None, :] + shifts[None]).reshape(-1, 2)).reshape(-1, 4)
        slope = np.stack([probes[:, 0] - probes[:, 1], probes[:, 2] - probes[:, 3]], axis=1) / (2 * h)
        short = np.clip(prefer_m - clearance_at(inner), 0.0, h)[:, None]
        pull = EASE_PULL * (0.5 * (eased[:-2] + eased[2:]) - inner)
        moved = inner + weight * (short * slope + pull)
        stay = ~passable_at(moved)
        moved[stay] = inner[stay]
        eased[1:-1] = moved
    if not passable_at(densify(eased, step / 2.0)).all():
        return points
    return simplify_clear(eased, clearance_at, tolerance=step / 4.0, cap=prefer_m, step=step / 2.0)


def densify(points: NDArray[np.float64], step: float) -> NDArray[np.float64]:
    """The polyline (K, 2) with points added so that consecutive ones are at most ``step`` apart
    (every leg cut into equal parts; the given points kept)."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return points.copy()
    lengths = np.hypot(*np.diff(points, axis=0).T)
    parts = np.maximum(np.ceil(lengths / step).astype(np.int64), 1)
    leg = np.repeat(np.arange(len(lengths)), parts)
    t = (np.arange(parts.sum()) - np.repeat(np.cumsum(parts) - parts, parts)) / np.repeat(parts, parts)
    return np.vstack([points[leg] + t[:, None] * (points[leg + 1] - points[leg]), points[-1:]])


def leg_clearances(points: NDArray, clearance_at: ClearanceAt, step: float) -> NDArray[np.float64]:
    """(K-1,) the least clearance along each leg of a polyline (K, 2), sampled every ``step`` or
    nearer, both ends included."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return np.zeros(0)
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    counts = np.maximum(np.ceil(lengths / step).astype(np.int64), 1) + 1
    leg = np.repeat(np.arange(len(lengths)), counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    t = (np.arange(counts.sum()) - np.repeat(starts, counts)) / np.repeat(counts - 1, counts)
    samples = points[leg] + t[:, None] * (points[leg + 1] - points[leg])
    return np.minimum.reduceat(clearance_at(samples), starts)


def simplify_clear(
    points: NDArray,
    clearance_at: ClearanceAt,
    tolerance: float,
    cap: float,
    step: float,
    slack: float = 0.01,
    pinned: NDArray[np.bool_] | None = None,
) -> NDArray[np.float64]:
    """Douglas-Peucker on a polyline (K, 2) with a clearance rule: a straight leg replaces a stretch
    only if it keeps as clear as the stretch's points do (less ``slack``), capped at ``cap``; legs are
    sampled every ``step``. ``pinned`` points are kept, and the ends."""
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    if n <= 2:
        return points.copy()
    clear = clearance_at(points)
    keep = np.zeros(n, bool) if pinned is None else np.asarray(pinned, bool).copy()
    keep[[0, -1]] = True
    anchors = np.nonzero(keep)[0]
    stack = list(zip(anchors[:-1].tolist(), anchors[1:].tolist(), strict=True))
    while stack:
        i, j = stack.pop()
        if j <= i + 1:
            continue
        a, b = points[i], points[j]
        inner = points[i + 1 : j]
        ab = b - a
        norm2 = float(ab @ ab)
        if norm2 < 1e-18:
            distance = np.linalg.norm(inner - a, axis=1)
        else:
            t = np.clip((inner - a) @ ab / norm2, 0.0, 1.0)
            distance = np.linalg.norm(inner - (a + t[:, None] * ab), axis=1)
        k = int(np.argmax(distance))
        if distance[k] <= tolerance:
            need = min(float(clear[i : j + 1].min()), cap) - slack
            if leg_clearances(np.stack([a, b]), clearance_at, step)[0] >= need:
                continue
        mid = i + 1 + k
        keep[mid] = True
        stack.append((i, mid))
        stack.append((mid, j))
    return points[keep]


def waypoints(frame: GridFrame, cells: NDArray, start_xy: NDArray, goal_xy: NDArray) -> NDArray[np.float64]:
    """A cell path as metric points with the exact start and goal at its ends; an end cell more than
    a cell and a half from its exact point stays, as the way into the planned free space."""
    points = frame.to_world(cells)
    near = 1.5 * frame.resolution
    head = points[1:] if np.hypot(*(points[0] - start_xy)) <= near else points
    if len(head) and np.hypot(*(head[-1] - goal_xy)) <= near:
        head = head[:-1]
    return np.vstack([start_xy[None], head, goal_xy[None]])
