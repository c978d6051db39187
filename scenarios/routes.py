"""Mapping routes: explicit waypoints joined by ground-truth shortest paths, or generated.

Where a route may run is graded by the clearance C of a point (its distance to the nearest
non-free cell) and the robot radius r:

* passable, C >= r: the robot fits, touching walls (GT shortest paths use this space);
* fit, C >= r + ``PASS_MARGIN_M`` (0.07 m): the narrowest place a generated route passes (a door), and
  only on its centre line, straight through;
* roomy, C >= r + ``ROUTE_MARGIN_M`` (0.15 m): where a route turns, ends and runs wherever it can. The
  shared follower strays up to about 0.12 m from a path at its corners (measured on random
  zig-zags), and overshoots a dead end by about 0.07 m before it turns round.

A generated route (``auto: {min_length}``) is a closed tour of the skeleton (medial axis) of
the fit space: a depth-first walk that goes down every branch to its end and back, then the
same walk backwards, alternately, until the route is at least ``min_length`` long (places are
seen from both directions). The skeleton and the walk are made drivable:

1. skeleton pixels in roomy space are kept; the narrow stretches between them (where the
   skeleton passes a door or a gap) are kept only where they join parts of the roomy skeleton
   that are not joined otherwise, widest first: a route goes through a door to reach a room,
   never through a gap beside a chair it can go round, never into a dead end narrower than
   the roomy space (its tip would be too tight to turn at), nor through a gap to a pocket of
   less than ``MIN_ROOMY_M2`` of roomy space;
2. loops round small obstacles (chairs, pillars, lidar speckles: less than
   ``SMALL_OBSTACLE_M2``) are opened at their narrowest point; short corner spurs are pruned;
3. every narrow stretch of the walk is crossed on one straight line from an approach point in
   roomy space up to ``APPROACH_M`` before it, laid out for the direction of travel (the
   backward tour gets its own), so the follower has settled when it reaches the door;
   a stretch no straight line crosses is entered straight and then followed densely;
4. the walk is simplified (Douglas-Peucker, one cell) with a clearance rule: a leg may not
   pass closer to walls than the walk it replaces (nor below roomy where that was roomy);
5. every leg of the result is checked against the clearance raster and any leg below the fit
   margin is re-planned (Theta*, roomy first, then fit, then passable).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from skimage.morphology import skeletonize

from navkit import grid_search
from scenarios.world import World

SPUR_LENGTH_M = 1.5  # skeleton branches shorter than this that end nowhere are pruned (corner spurs)
ROUTE_MARGIN_M = 0.15  # legs keep this much more than the robot radius from walls where they can
PASS_MARGIN_M = 0.07  # generated routes pass no gap narrower than 2 * (radius + this) (0.74 m for r = 0.3)
MIN_ROOMY_M2 = 1.0  # a pocket of roomy space smaller than this is not worth a narrow passage
SMALL_OBSTACLE_M2 = 1.0  # a skeleton loop round less obstacle than this is opened (no tours round chairs)
CLEARANCE_SLACK_M = 0.01  # a simplified leg may lose this much clearance against the skeleton it replaces
EIGHT = np.ones((3, 3), bool)
FOUR = ndimage.generate_binary_structure(2, 1)


def polyline_length(points: NDArray) -> float:
    points = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) if len(points) > 1 else 0.0


@dataclass(frozen=True)
class RouteSpace:
    """The graded space of a robot of ``radius`` in a world (see the module docstring)."""

    radius: float
    passable: NDArray[np.bool_]  # C >= r
    fit: NDArray[np.bool_]  # C >= r + PASS_MARGIN_M
    roomy: NDArray[np.bool_]  # C >= r + ROUTE_MARGIN_M

    @property
    def tiers(self) -> list[NDArray[np.bool_]]:
        """Where legs are planned, by preference."""
        return [self.roomy, self.fit, self.passable]


def route_space(world: World, radius: float) -> RouteSpace:
    clearance = world.clearance
    return RouteSpace(
        radius=float(radius),
        passable=clearance >= radius,
        fit=clearance >= radius + PASS_MARGIN_M,
        roomy=clearance >= radius + ROUTE_MARGIN_M,
    )


def shortest_path(world: World, passable: NDArray[np.bool_], start_xy: NDArray, goal_xy: NDArray) -> NDArray[np.float64] | None:
    """Any-angle shortest path between two points (both inside ``passable``), as a polyline.

    The end points are the exact points, not the cell centres; the inner vertices are cell centres.
    """
    start_cell = world.to_cell(start_xy)
    goal_cell = world.to_cell(goal_xy)
    if not (world.inside(start_cell) and world.inside(goal_cell)):
        return None
    if not (passable[tuple(start_cell)] and passable[tuple(goal_cell)]):
        return None
    cells = grid_search.theta_star(passable, start_cell, goal_cell)
    if cells is None:
        return None
    inner = world.to_world(cells[1:-1]) if len(cells) > 2 else np.zeros((0, 2))
    return np.vstack([np.asarray(start_xy, float)[None, :2], inner, np.asarray(goal_xy, float)[None, :2]])


def plan_leg(world: World, tiers: list[NDArray[np.bool_]], a: NDArray, b: NDArray) -> NDArray[np.float64] | None:
    """A shortest path from a to b in the first of ``tiers`` that holds both ends and joins them."""
    for space in tiers:
        path = shortest_path(world, space, a, b)
        if path is not None:
            return path
    return None


def waypoint_route(
    world: World,
    passable: NDArray[np.bool_],
    waypoints: NDArray,
    roomy: NDArray[np.bool_] | None = None,
    fit: NDArray[np.bool_] | None = None,
) -> tuple[NDArray[np.float64] | None, int]:
    """Join waypoints by shortest paths; returns (route, -1) or (None, index of the unreachable waypoint).

    Each leg is planned in ``roomy`` (free space with a margin) when both its ends lie there and it
    connects them, so that a follower's small deviations at corners do not touch walls; else in
    ``fit`` (a smaller margin), else in ``passable``.
    """
    tiers = [space for space in (roomy, fit, passable) if space is not None]
    pieces = [np.asarray(waypoints[0], float)[None, :]]
    for i in range(1, len(waypoints)):
        piece = plan_leg(world, tiers, waypoints[i - 1], waypoints[i])
        if piece is None:
            return None, i
        pieces.append(piece[1:])
    return np.vstack(pieces), -1


# ---------------------------------------------------------------------------------------------
# clearance along legs


def leg_clearances(world: World, points: NDArray) -> NDArray[np.float64]:
    """(K-1,) the least clearance along each leg of a polyline (K, 2), sampled every half cell."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return np.zeros(0)
    step = world.resolution / 2.0
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    counts = np.maximum(np.ceil(lengths / step).astype(np.int64), 1) + 1
    leg = np.repeat(np.arange(len(lengths)), counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    t = (np.arange(counts.sum()) - np.repeat(starts, counts)) / np.repeat(counts - 1, counts)
    samples = points[leg] + t[:, None] * (points[leg + 1] - points[leg])
    values = _clearance_at(world, samples)
    return np.minimum.reduceat(values, starts)


def _clearance_at(world: World, xy: NDArray) -> NDArray[np.float64]:
    return world.clearances_at(xy)


def simplify_walk(
    world: World, points: NDArray, radius: float, tolerance: float | None = None, pinned: NDArray[np.bool_] | None = None
) -> NDArray[np.float64]:
    """Douglas-Peucker on a walk over cell centres, with a clearance rule: a leg replaces a stretch
    of the walk only if it keeps as far from walls as that stretch does (less ``CLEARANCE_SLACK_M``),
    capped at ``radius + ROUTE_MARGIN_M``. ``pinned`` points are kept."""
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    if n <= 2:
        return points.copy()
    tolerance = world.resolution if tolerance is None else tolerance
    clear = _clearance_at(world, points)
    comfortable = radius + ROUTE_MARGIN_M
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
            need = min(float(clear[i : j + 1].min()), comfortable) - CLEARANCE_SLACK_M
            if leg_clearances(world, np.stack([a, b]))[0] >= need:
                continue
        mid = i + 1 + k
        keep[mid] = True
        stack.append((i, mid))
        stack.append((mid, j))
    return points[keep]


APPROACH_M = (1.2, 1.0, 0.8, 0.6, 0.4, 0.25)  # a narrow passage is entered straight from this far, where room allows
GOOD_APPROACH_M = 0.8  # an approach this long along the axis is good enough: no wider search
FOLLOWER_OFFSET_M, FOLLOWER_SETTLE_M = 0.15, 0.6  # the follower's offset after a corner, and its decay length
TILT_DEG = (0, 8, -8, 16, -16, 24, -24, 32, -32, 40, -40)  # the line may cross a passage this far off its axis
TILT_LOSS_M = 0.03  # ... losing at most this much clearance against the passage's centre line
AXIS_WINDOW_M = 0.4  # the passage axis is fitted to the walk this far either side of its narrowest point
EXIT_M = 0.2  # the line goes on this far into roomy space after the passage before it may turn
SEARCH_STEP_M = 0.15  # spacing of the candidate approach and exit points of the wider search
ENTRY_RADIUS_M, EXIT_RADIUS_M = 1.5, 1.0  # ... within this of where the walk enters and leaves the passage
JOIN_WINDOW_M = 2.5  # how much of the walk before and after a passage the straight line may replace
MERGE_GAP_M = 1.0  # narrow stretches less than this apart along the walk are crossed as one
PIN_M = 0.5  # a passage no straight line crosses keeps its walk (unsimplified) this far either side


def _leave_distance(world: World, centre: NDArray, direction: NDArray, level: float, limit: float) -> float | None:
    """How far from ``centre`` along ``direction`` the clearance first reaches ``level`` (None within ``limit``)."""
    step = world.resolution / 2.0
    t = np.arange(0.0, limit + step, step)
    values = _clearance_at(world, centre + t[:, None] * direction)
    above = np.nonzero(values >= level)[0]
    return float(t[above[0]]) if len(above) else None


def _point_at(points: NDArray, arc: NDArray, value: float) -> NDArray[np.float64]:
    """The point of a polyline at arc length ``value`` (clamped)."""
    i = int(np.clip(np.searchsorted(arc, value), 1, len(arc) - 1))
    span = arc[i] - arc[i - 1]
    t = 0.0 if span <= 0 else float(np.clip((value - arc[i - 1]) / span, 0.0, 1.0))
    return points[i - 1] + t * (points[i] - points[i - 1])


def _segment_profiles(
    world: World, a: NDArray, b: NDArray, comfortable: float
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_]]:
    """For segments a[k] -> b[k]: least clearance, length of the roomy stretch at the start (the
    approach) and at the end (the exit), whether both ends are roomy and whether it passes
    anywhere less than roomy (crosses a narrow stretch)."""
    a, b = np.atleast_2d(a).astype(np.float64), np.atleast_2d(b).astype(np.float64)
    lengths = np.linalg.norm(b - a, axis=1)
    n = int(np.ceil(lengths.max(initial=0.0) / (world.resolution / 2.0))) + 2
    t = np.linspace(0.0, 1.0, n)
    samples = a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]
    values = _clearance_at(world, samples.reshape(-1, 2)).reshape(len(a), n)
    below = values < comfortable
    any_below = below.any(axis=1)
    first = np.where(any_below, np.argmax(below, axis=1), n - 1)
    last = np.where(any_below, n - 1 - np.argmax(below[:, ::-1], axis=1), 0)
    approach = t[first] * lengths
    exit_ = (1.0 - t[last]) * lengths
    ends_roomy = (values[:, 0] >= comfortable) & (values[:, -1] >= comfortable)
    return values.min(axis=1), approach, exit_, ends_roomy, any_below


def _disc_points(world: World, centre: NDArray, radius: float, comfortable: float) -> NDArray[np.float64]:
    """Roomy points on a grid of ``SEARCH_STEP_M`` within ``radius`` of ``centre``."""
    offsets = np.arange(-radius, radius + 1e-9, SEARCH_STEP_M)
    grid = np.stack(np.meshgrid(offsets, offsets), axis=-1).reshape(-1, 2)
    grid = centre + grid[np.linalg.norm(grid, axis=1) <= radius]
    return grid[_clearance_at(world, grid) >= comfortable]


def straighten_passages(world: World, points: NDArray, space: RouteSpace) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Cross every narrow stretch of a walk (clearance below roomy) on one straight line.

    Returns the new walk and which of its points must survive simplification.

    The line runs from an approach point in roomy space, up to ``APPROACH_M`` before the stretch
    (so the follower's offset after turning there has died out at the door), to an exit point
    just beyond it, and keeps as much clearance as the walk did there (less ``TILT_LOSS_M``). It
    is sought along the stretch's axis through its narrowest point (tilted up to 40°), and if that
    gives no long approach, between any roomy points near where the walk enters and leaves the
    stretch. The walk just before and after is joined to the line's ends by straight roomy legs,
    so a line is laid out for the direction the walk crosses in. A stretch that no straight line
    crosses (a narrow bent corridor) keeps its own walk, unsimplified (``PIN_M`` either side):
    the follower tracks a dense path closely.
    """
    points = np.asarray(points, dtype=np.float64)
    n = len(points)
    clear = _clearance_at(world, points)
    comfortable = space.radius + ROUTE_MARGIN_M
    narrow = clear < comfortable
    if n < 3 or narrow.all() or not narrow.any():
        return points, np.zeros(n, bool)
    edges = np.diff(np.concatenate([[0], narrow.astype(np.int8), [0]]))
    runs = list(zip(np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0] - 1, strict=True))
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    merged = [runs[0]]  # stretches with a little roomy pocket between them are one stretch
    for s, e in runs[1:]:
        if arc[s] - arc[merged[-1][1]] < MERGE_GAP_M:
            merged[-1] = (merged[-1][0], e)
        else:
            merged.append((s, e))
    runs = merged
    join = comfortable - CLEARANCE_SLACK_M

    def seen_from(candidates: NDArray, walk: NDArray) -> NDArray[np.bool_]:
        """Which candidates have a roomy straight leg to some roomy point of ``walk`` (every 2nd)."""
        sparse = walk[::2]
        sparse = sparse[_clearance_at(world, sparse) >= comfortable] if len(sparse) else sparse
        if len(candidates) == 0 or len(sparse) == 0:
            return np.zeros(len(candidates), bool)
        a = np.repeat(candidates, len(sparse), axis=0)
        b = np.tile(sparse, (len(candidates), 1))
        least = _segment_profiles(world, a, b, comfortable)[0].reshape(len(candidates), len(sparse))
        return (least >= join).any(axis=1)

    def rank(a: NDArray, x: NDArray, need: float) -> list[tuple[NDArray, NDArray, float, float]]:
        if len(a) == 0:
            return []
        least, approach, exit_, ends, crosses = _segment_profiles(world, a, x, comfortable)
        ok = ends & crosses & (least >= need) & (approach >= min(APPROACH_M)) & (exit_ >= EXIT_M * 0.75)
        # the margin left at the passage once the follower's offset after its turn at the
        # approach point (about 0.15 m, dying out over the lookahead) is spent
        spare = least - space.radius - FOLLOWER_OFFSET_M * np.exp(-approach / FOLLOWER_SETTLE_M)
        order = sorted(np.nonzero(ok)[0], key=lambda k: -spare[k])
        return [(a[k], x[k], float(approach[k]), float(least[k])) for k in order]

    def axis_candidates(s: int, e: int) -> tuple[NDArray, NDArray]:
        m = s + int(np.argmin(clear[s : e + 1]))
        window = points[(arc >= arc[m] - AXIS_WINDOW_M) & (arc <= arc[m] + AXIS_WINDOW_M)]
        if len(window) < 3:
            return np.zeros((0, 2)), np.zeros((0, 2))
        axis = np.linalg.svd(window - window.mean(axis=0), full_matrices=False)[2][0]
        if axis @ (points[e + 1] - points[s - 1]) < 0:
            axis = -axis
        limit = arc[e] - arc[s] + 2.0 * AXIS_WINDOW_M
        approach_points, exit_points = [], []
        for tilt in np.radians(TILT_DEG):
            c, si = np.cos(tilt), np.sin(tilt)
            u = np.array([c * axis[0] - si * axis[1], si * axis[0] + c * axis[1]])
            back = _leave_distance(world, points[m], -u, comfortable, limit)
            ahead = _leave_distance(world, points[m], u, comfortable, limit)
            if back is None or ahead is None:
                continue
            for d in APPROACH_M:
                approach_points.append(points[m] - u * (back + d))
                exit_points.append(points[m] + u * (ahead + EXIT_M))
        return np.array(approach_points).reshape(-1, 2), np.array(exit_points).reshape(-1, 2)

    def best_line(s: int, e: int, need: float) -> tuple[NDArray, NDArray] | None:
        before = points[max(cursor, int(np.searchsorted(arc, arc[s] - JOIN_WINDOW_M))) : s]
        after = points[e + 1 : int(np.searchsorted(arc, arc[e] + JOIN_WINDOW_M, side="right"))]
        if len(before) == 0 or len(after) == 0:
            return None
        axis_a, axis_x = axis_candidates(s, e)
        found = rank(axis_a, axis_x, need)
        for a, x, _, _ in [f for f in found if f[2] >= GOOD_APPROACH_M][:20]:
            if seen_from(a[None], before)[0] and seen_from(x[None], after)[0]:
                return a, x
        entries = _disc_points(world, points[s], ENTRY_RADIUS_M, comfortable)
        exits = _disc_points(world, points[e], EXIT_RADIUS_M, comfortable)
        entries, exits = entries[seen_from(entries, before)], exits[seen_from(exits, after)]
        if len(axis_a):
            keep = seen_from(axis_a, before) & seen_from(axis_x, after)
            entries = np.vstack([entries, axis_a[keep]])
            exits = np.vstack([exits, axis_x[keep]])
        if len(entries) == 0 or len(exits) == 0:
            return None
        found = rank(np.repeat(entries, len(exits), axis=0), np.tile(exits, (len(entries), 1)), need)
        return (found[0][0], found[0][1]) if found else None

    def joined(a: NDArray, x: NDArray, s: int, e: int) -> tuple[int, int]:
        """The earliest walk index before ``s`` seen from a, the latest after ``e`` seen from x."""
        first = max(cursor, int(np.searchsorted(arc, arc[s] - JOIN_WINDOW_M)))
        last = int(np.searchsorted(arc, arc[e] + JOIN_WINDOW_M, side="right"))
        before, after = points[first:s], points[e + 1 : last]
        ok_a = _segment_profiles(world, before, np.broadcast_to(a, before.shape), comfortable)[0] >= join
        ok_x = _segment_profiles(world, np.broadcast_to(x, after.shape), after, comfortable)[0] >= join
        ok_a &= ~narrow[first:s]  # joined at roomy points of the walk only
        ok_x &= ~narrow[e + 1 : last]
        return first + int(np.argmax(ok_a)), e + 1 + int(len(after) - 1 - np.argmax(ok_x[::-1]))

    def entry_approach(s: int, need: float) -> tuple[NDArray, int] | None:
        """An approach point straight behind where the walk enters the stretch, and the walk
        index it is joined from."""
        inward = _point_at(points, arc, arc[s] + AXIS_WINDOW_M) - points[s]
        if np.linalg.norm(inward) < 1e-9:
            return None
        inward /= np.linalg.norm(inward)
        first = max(cursor, int(np.searchsorted(arc, arc[s] - JOIN_WINDOW_M)))
        before = points[first:s]
        if len(before) == 0:
            return None
        for d in APPROACH_M:
            a = points[s] - inward * d
            if _clearance_at(world, a[None])[0] < comfortable:
                continue
            if _segment_profiles(world, a, points[s], comfortable)[0][0] < min(float(clear[s]), need):
                continue
            ok = _segment_profiles(world, before, np.broadcast_to(a, before.shape), comfortable)[0] >= join
            ok &= ~narrow[first:s]
            if ok.any():
                return a, first + int(np.argmax(ok))
        return None

    out: list[NDArray] = []
    pins: list[NDArray] = []
    cursor = 0
    for s, e in runs:
        if s < cursor or e >= n - 1:
            continue  # the walk starts or ends in it, or an earlier line already replaced it
        least = float(clear[s : e + 1].min())
        need = max(least - TILT_LOSS_M, min(least, space.radius + PASS_MARGIN_M)) - CLEARANCE_SLACK_M
        line = best_line(s, e, need)
        if line is None:  # keep the walk itself through it, densely, entered straight if possible
            hi = int(np.searchsorted(arc, arc[e] + PIN_M, side="right"))
            approach = entry_approach(s, need)
            if approach is not None:
                a, t = approach
                out.extend([points[cursor : t + 1], a[None], points[s:hi]])
                pins.extend([np.zeros(t + 1 - cursor, bool), np.ones(1 + hi - s, bool)])
            else:
                lo = max(cursor, int(np.searchsorted(arc, arc[s] - PIN_M)))
                out.extend([points[cursor:lo], points[lo:hi]])
                pins.extend([np.zeros(lo - cursor, bool), np.ones(hi - lo, bool)])
            cursor = hi
            continue
        a, x = line
        t, v = joined(a, x, s, e)
        out.extend([points[cursor : t + 1], a[None], x[None]])
        pins.extend([np.zeros(t + 1 - cursor, bool), np.ones(2, bool)])
        cursor = v
    out.append(points[cursor:])
    pins.append(np.zeros(n - cursor, bool))
    return np.vstack(out), np.concatenate(pins)


def repair_legs(world: World, points: NDArray, space: RouteSpace) -> tuple[NDArray[np.float64], int]:
    """Re-plan every leg that passes closer to walls than the fit margin; returns (route, legs re-planned)."""
    points = np.asarray(points, dtype=np.float64)
    low = leg_clearances(world, points) < space.radius + PASS_MARGIN_M - CLEARANCE_SLACK_M
    if not low.any():
        return points, 0
    pieces = [points[:1]]
    for i in range(len(points) - 1):
        if low[i]:
            leg = plan_leg(world, space.tiers, points[i], points[i + 1])
            if leg is not None:
                pieces.append(leg[1:])
                continue
        pieces.append(points[i + 1 : i + 2])
    return np.vstack(pieces), int(low.sum())


# ---------------------------------------------------------------------------------------------
# the skeleton


def _neighbours(mask: NDArray[np.bool_]) -> NDArray[np.int32]:
    kernel = np.ones((3, 3), np.int32)
    kernel[1, 1] = 0
    return ndimage.convolve(mask.astype(np.int32), kernel, mode="constant") * mask


OFFSETS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def _prune_spurs(skeleton: NDArray[np.bool_], max_cells: int, passes: int = 2) -> NDArray[np.bool_]:
    skeleton = skeleton.copy()
    h, w = skeleton.shape
    for _ in range(passes):
        degree = _neighbours(skeleton)
        if (degree >= 3).sum() == 0:
            break  # a single path (or ring): nothing is a spur
        for r, c in np.argwhere(degree == 1):
            branch = [(r, c)]
            previous, current = None, (r, c)
            while len(branch) <= max_cells:
                nxt = [
                    (current[0] + dr, current[1] + dc)
                    for dr, dc in OFFSETS
                    if 0 <= current[0] + dr < h
                    and 0 <= current[1] + dc < w
                    and skeleton[current[0] + dr, current[1] + dc]
                    and (current[0] + dr, current[1] + dc) != previous
                    and (current[0] + dr, current[1] + dc) not in branch
                ]
                if len(nxt) != 1 or degree[nxt[0]] >= 3:
                    break
                previous, current = current, nxt[0]
                branch.append(current)
            else:
                continue  # long branch: a real dead end, keep it
            ends_at_junction = any(
                degree[rr, cc] >= 3
                for rr, cc in ((branch[-1][0] + dr, branch[-1][1] + dc) for dr, dc in OFFSETS)
                if 0 <= rr < h and 0 <= cc < w
            )
            if ends_at_junction:
                for cell in branch:
                    skeleton[cell] = False
        skeleton = skeletonize(skeleton)
    return skeleton


def _largest(mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    labels, count = ndimage.label(mask, structure=EIGHT)
    if count <= 1:
        return mask
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels == int(np.argmax(sizes))


class _Sets:
    """Union-find over integer labels."""

    def __init__(self, n: int) -> None:
        self.parent = list(range(n))

    def find(self, a: int) -> int:
        while self.parent[a] != a:
            self.parent[a] = self.parent[self.parent[a]]
            a = self.parent[a]
        return a

    def union(self, a: int, b: int) -> None:
        self.parent[self.find(a)] = self.find(b)


def _touching(a_labels: NDArray[np.int32], b_labels: NDArray[np.int32]) -> NDArray[np.int64]:
    """Unique pairs (a, b) of labels > 0 on 8-neighbouring cells."""
    h, w = a_labels.shape
    pairs = []
    for dr, dc in OFFSETS:
        a = a_labels[max(0, -dr) : h - max(0, dr), max(0, -dc) : w - max(0, dc)]
        b = b_labels[max(0, dr) : h - max(0, -dr), max(0, dc) : w - max(0, -dc)]
        both = (a > 0) & (b > 0)
        if both.any():
            pairs.append(np.stack([a[both], b[both]], axis=1))
    return np.unique(np.concatenate(pairs), axis=0) if pairs else np.zeros((0, 2), np.int64)


def _keep_connecting_passages(
    skeleton: NDArray[np.bool_], clear: NDArray, roomy_from: float, resolution: float
) -> NDArray[np.bool_]:
    """The roomy skeleton plus the narrow stretches that join otherwise separate parts of it,
    widest first; the whole skeleton if no part of it is roomy (a maze of narrow passages).

    A part of the roomy skeleton in less than ``MIN_ROOMY_M2`` of roomy space that hangs on one
    narrow stretch (a pocket between chairs) is dropped with its stretch, repeatedly: a route
    does not squeeze through a gap to reach a place hardly wider than the gap."""
    narrow = skeleton & (clear < roomy_from)
    roomy_part = skeleton & ~narrow
    pieces, n_pieces = ndimage.label(roomy_part, structure=EIGHT)
    if n_pieces == 0:
        return skeleton
    stretches, n_stretches = ndimage.label(narrow, structure=EIGHT)
    kept = roomy_part.copy()
    if n_stretches == 0:
        return kept
    touching: dict[int, set[int]] = {}
    for s, p in _touching(stretches, pieces):
        touching.setdefault(int(s), set()).add(int(p))
    index = np.arange(1, n_stretches + 1)
    least = np.asarray(ndimage.minimum(clear, stretches, index), dtype=np.float64)
    size = np.bincount(stretches.ravel(), minlength=n_stretches + 1)[1:]
    sets = _Sets(n_pieces + 1)
    chosen: dict[int, set[int]] = {}
    for i in np.lexsort((size, -least)):  # widest first, then shortest
        s = int(index[i])
        roots = {sets.find(p) for p in touching.get(s, set())}
        if len(roots) >= 2:
            chosen[s] = set(touching[s])
            first, *rest = roots
            for other in rest:
                sets.union(other, first)
    # the roomy area each piece lies in
    regions, _ = ndimage.label(clear >= roomy_from, structure=EIGHT)
    region_of = np.asarray(ndimage.maximum(regions, pieces, np.arange(1, n_pieces + 1)), dtype=np.int64)
    region_m2 = np.bincount(regions.ravel()) * resolution**2
    area = np.concatenate([[0.0], region_m2[region_of]])
    alive = np.ones(n_pieces + 1, bool)
    alive[0] = False
    biggest = int(np.argmax(area))
    changed = True
    while changed:
        changed = False
        links = np.zeros(n_pieces + 1, np.int64)
        for members in chosen.values():
            for p in members:
                links[p] += 1
        for s in list(chosen):
            for p in list(chosen[s]):
                if alive[p] and links[p] == 1 and area[p] < MIN_ROOMY_M2 and p != biggest:
                    alive[p] = False
                    chosen[s].discard(p)
                    changed = True
            if len(chosen[s]) < 2:
                del chosen[s]
                changed = True
    keep_stretch = np.zeros(n_stretches + 1, bool)
    keep_stretch[list(chosen)] = True
    return (kept & alive[pieces]) | keep_stretch[stretches]


def _open_small_loops(skeleton: NDArray[np.bool_], world: World, clear: NDArray, max_obstacle_m2: float) -> NDArray[np.bool_]:
    """Cut every skeleton loop that encloses less than ``max_obstacle_m2`` of obstacle at its
    narrowest pixel, unless the cut would split the skeleton."""
    skeleton = skeleton.copy()
    faces, n_faces = ndimage.label(~skeleton, structure=FOUR)
    if n_faces <= 1:
        return skeleton
    outer = np.unique(np.concatenate([faces[0], faces[-1], faces[:, 0], faces[:, -1]]))
    obstacle_m2 = np.bincount(faces.ravel(), weights=(~world.free).ravel().astype(np.float64), minlength=n_faces + 1)
    obstacle_m2 *= world.resolution**2
    small = np.nonzero(obstacle_m2 < max_obstacle_m2)[0]
    small = small[(small > 0) & ~np.isin(small, outer)]
    if len(small) == 0:
        return skeleton
    h, w = skeleton.shape
    boxes = ndimage.find_objects(faces)
    # cut inside an arc of the loop, away from where it meets other branches
    near_junction = ndimage.binary_dilation(_neighbours(skeleton) >= 3, structure=EIGHT, iterations=3)
    cuttable = skeleton & ~near_junction
    cuts: list[tuple[int, int]] = []
    for f in small:
        rows, cols = boxes[f - 1]
        r0, r1 = max(rows.start - 2, 0), min(rows.stop + 2, h)
        c0, c1 = max(cols.start - 2, 0), min(cols.stop + 2, w)
        face = faces[r0:r1, c0:c1] == f
        ring = cuttable[r0:r1, c0:c1] & ndimage.binary_dilation(face, structure=EIGHT)
        if not ring.any():
            continue
        cells = np.argwhere(ring)
        k = int(np.argmin(clear[r0:r1, c0:c1][ring]))
        r, c = int(cells[k, 0] + r0), int(cells[k, 1] + c0)
        cuts.append((r, c))
    removed = []
    for r, c in cuts:
        block = (slice(max(r - 1, 0), r + 2), slice(max(c - 1, 0), c + 2))
        removed.append((block, skeleton[block].copy()))
        skeleton[block] = False
    # a cut that split the skeleton is put back (two faces' cuts can together separate a part)
    labels, count = ndimage.label(skeleton, structure=EIGHT)
    sets = _Sets(count + 1)
    for block, before in removed:
        r, c = block[0].start + 1, block[1].start + 1
        window = labels[max(r - 3, 0) : r + 4, max(c - 3, 0) : c + 4]
        roots = {sets.find(int(v)) for v in np.unique(window) if v > 0}
        if len(roots) >= 2:
            skeleton[block] |= before
            first, *rest = roots
            for other in rest:
                sets.union(other, first)
    # the cut arc goes altogether, back to the junctions at its ends
    degree = _neighbours(skeleton)
    stubs = [
        (r, c)
        for block, _ in removed
        for r in range(max(block[0].start - 1, 0), min(block[0].stop + 1, h))
        for c in range(max(block[1].start - 1, 0), min(block[1].stop + 1, w))
        if skeleton[r, c] and degree[r, c] <= 1
    ]
    return _peel_tips(skeleton, np.ones_like(skeleton), np.array(stubs)) if stubs else skeleton


def _peel_tips(skeleton: NDArray[np.bool_], tight: NDArray[np.bool_], seeds: NDArray | None = None) -> NDArray[np.bool_]:
    """Remove dead-end branches back to where they leave ``tight`` space (or to their junction);
    only the branches that end at ``seeds`` (cells) if given."""
    skeleton = skeleton.copy()
    degree = _neighbours(skeleton)
    h, w = skeleton.shape
    starts = np.argwhere((degree <= 1) & skeleton & tight) if seeds is None else np.asarray(seeds).reshape(-1, 2)
    queue = [(int(r), int(c)) for r, c in starts]
    while queue:
        r, c = queue.pop()
        if not skeleton[r, c] or degree[r, c] > 1 or not tight[r, c]:
            continue
        skeleton[r, c] = False
        for dr, dc in OFFSETS:
            rr, cc = r + dr, c + dc
            if 0 <= rr < h and 0 <= cc < w and skeleton[rr, cc]:
                degree[rr, cc] -= 1
                if degree[rr, cc] <= 1 and tight[rr, cc]:
                    queue.append((rr, cc))
    return skeleton


def route_skeleton(world: World, space: RouteSpace) -> NDArray[np.bool_]:
    """The skeleton a generated route tours (steps 1 and 2 of the module docstring)."""
    clear = world.clearance
    fit = _largest(space.fit)
    skeleton = skeletonize(fit)
    if not skeleton.any():
        raise ValueError("free space too narrow for the robot: empty skeleton")
    roomy_from = space.radius + ROUTE_MARGIN_M
    kept = _keep_connecting_passages(skeleton, clear, roomy_from, world.resolution)
    if (kept & (clear >= roomy_from)).any():
        kept = _peel_tips(_largest(kept), kept & (clear < roomy_from))
    else:  # nothing roomy: at least keep dead ends off their walls
        peeled = _peel_tips(kept, kept & (clear < space.radius + PASS_MARGIN_M + 0.05))
        kept = peeled if peeled.any() else kept
    kept = _largest(kept)
    kept = _open_small_loops(kept, world, clear, SMALL_OBSTACLE_M2)
    kept = _prune_spurs(kept, max_cells=int(SPUR_LENGTH_M / world.resolution))
    return _largest(kept)


def _as_space(world: World, space: RouteSpace | NDArray[np.bool_]) -> RouteSpace:
    """A bare passable mask (the old signatures) is the space of a robot as wide as its least clearance."""
    if isinstance(space, RouteSpace):
        return space
    passable = np.asarray(space, bool)
    return route_space(world, float(world.clearance[passable].min()) if passable.any() else 0.0)


def skeleton_walk(world: World, space: RouteSpace, rng: np.random.Generator) -> NDArray[np.float64]:
    """A closed depth-first walk over the route skeleton, cell centre by cell centre, from a
    dead end chosen by ``rng`` down every branch and back to it."""
    skeleton = route_skeleton(world, space)
    cells = np.argwhere(skeleton)
    if len(cells) == 0:
        raise ValueError("free space too narrow for the robot: empty skeleton")
    index = -np.ones(skeleton.shape, np.int64)
    index[cells[:, 0], cells[:, 1]] = np.arange(len(cells))
    degree = _neighbours(skeleton)[cells[:, 0], cells[:, 1]]
    ends = np.nonzero(degree == 1)[0]
    start = int(rng.choice(ends)) if len(ends) else 0
    offsets = np.array([(-1, 0), (0, -1), (0, 1), (1, 0), (-1, -1), (-1, 1), (1, -1), (1, 1)])  # 4-nbrs first
    h, w = skeleton.shape
    visited = np.zeros(len(cells), bool)
    visited[start] = True
    walk = [start]
    stack = [(start, 0)]
    while stack:
        node, k = stack[-1]
        advanced = False
        while k < len(offsets):
            r, c = cells[node] + offsets[k]
            k += 1
            if 0 <= r < h and 0 <= c < w and index[r, c] >= 0 and not visited[index[r, c]]:
                child = int(index[r, c])
                visited[child] = True
                stack[-1] = (node, k)
                stack.append((child, 0))
                walk.append(child)
                advanced = True
                break
        if not advanced:
            stack.pop()
            if stack:
                walk.append(stack[-1][0])  # walk back to the parent
    return world.to_world(cells[np.asarray(walk)])


def drivable(world: World, walk: NDArray, space: RouteSpace) -> NDArray[np.float64]:
    """A walk made into a route for the follower: narrow passages crossed straight (their approach
    laid out for this direction of travel), simplified with the clearance rule, legs checked."""
    points, pinned = straighten_passages(world, walk, space)
    tour = simplify_walk(world, points, space.radius, pinned=pinned)
    tour, _ = repair_legs(world, tour, space)
    return tour


def skeleton_tour(world: World, space: RouteSpace | NDArray[np.bool_], rng: np.random.Generator) -> NDArray[np.float64]:
    """A closed walk over the route skeleton that visits every branch, as a drivable polyline."""
    space = _as_space(world, space)
    return drivable(world, skeleton_walk(world, space, rng), space)


def auto_route(
    world: World, space: RouteSpace | NDArray[np.bool_], min_length: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    """The skeleton tour, then the same walk backwards, alternately, until ``min_length``.

    The backward tour is made drivable on its own (not the forward polyline reversed): a narrow
    passage is entered straight from the side the robot comes from.
    """
    space = _as_space(world, space)
    walk = skeleton_walk(world, space, rng)
    tours = [drivable(world, walk, space)]
    lengths = [polyline_length(tours[0])]
    if lengths[0] <= 0:
        raise ValueError("the skeleton tour has zero length")
    pieces = [tours[0]]
    length = lengths[0]
    while length < min_length:
        if len(tours) == 1:
            tours.append(drivable(world, walk[::-1], space))
            lengths.append(polyline_length(tours[1]))
        k = len(pieces) % 2
        pieces.append(tours[k][1:])
        length += lengths[k]
    return np.vstack(pieces)
