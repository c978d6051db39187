"""Narrow passages of a walk crossed on straight lines (step 3 of a generated route, ``scenarios.routes``).

A walk over the route skeleton (``scenarios.skeleton``) runs along cell centres; where its
clearance falls below roomy (``scenarios.route_space``: a door, a gap between furniture) the
follower would enter the passage still turning. So every narrow stretch of the walk is crossed
on one straight line, from an approach point in roomy space up to ``APPROACH_M`` before it
(the follower's offset after turning there has died out at the door) to an exit point just
beyond it, laid out for the direction of travel (the backward tour gets its own). The line is
sought along the stretch's axis through its narrowest point (tilted up to 40°), and if that
gives no long approach, between any roomy points near where the walk enters and leaves the
stretch; the walk just before and after is joined to its ends by straight roomy legs. A
stretch no straight line crosses (a narrow bent corridor) is entered straight if it can be and
keeps its own walk, pinned against simplification (``PIN_M`` either side): the follower tracks
a dense path closely.

Walks and lines are (K, 2) float64 points, metres in the scenario frame; clearances are
bilinear in ``World.clearance``; ``arc`` is the walk's cumulative length (K,).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import NDArray

from navkit.geometry import point_at_arc
from scenarios.route_space import CLEARANCE_SLACK_M, PASS_MARGIN_M, ROUTE_MARGIN_M, RouteSpace
from scenarios.world import World

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
    values = world.clearances_at(centre + t[:, None] * direction)
    above = np.nonzero(values >= level)[0]
    return float(t[above[0]]) if len(above) else None


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
    values = world.clearances_at(samples.reshape(-1, 2)).reshape(len(a), n)
    below = values < comfortable
    any_below = cast(NDArray[np.bool_], below.any(axis=1))
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
    return grid[world.clearances_at(grid) >= comfortable]


def _narrow_runs(narrow: NDArray[np.bool_], arc: NDArray[np.float64]) -> list[tuple[int, int]]:
    """The narrow stretches of a walk as index ranges [s, e], in walk order; stretches with a
    little roomy pocket between them (less than ``MERGE_GAP_M`` along the walk) are one stretch."""
    edges = np.diff(np.concatenate([[0], narrow.astype(np.int8), [0]]))
    runs = list(zip(np.nonzero(edges == 1)[0].tolist(), (np.nonzero(edges == -1)[0] - 1).tolist(), strict=True))
    merged = [runs[0]]
    for s, e in runs[1:]:
        if arc[s] - arc[merged[-1][1]] < MERGE_GAP_M:
            merged[-1] = (merged[-1][0], e)
        else:
            merged.append((s, e))
    return merged


@dataclass(frozen=True)
class _Walk:
    """A walk being straightened and what is measured along it once. ``cursor`` arguments: the
    walk index up to which earlier lines have replaced the walk (a line never reaches back past it)."""

    world: World
    points: NDArray[np.float64]  # (K, 2)
    radius: float  # the robot's
    clear: NDArray[np.float64]  # (K,) clearance at each point
    comfortable: float  # roomy from this clearance on
    narrow: NDArray[np.bool_]  # (K,) clear < comfortable
    arc: NDArray[np.float64]  # (K,) cumulative length
    join: float  # least clearance of a leg joining the walk to a line's end

    def seen_from(self, candidates: NDArray, stretch: NDArray) -> NDArray[np.bool_]:
        """Which candidates have a roomy straight leg to some roomy point of ``stretch`` (every 2nd)."""
        sparse = stretch[::2]
        sparse = sparse[self.world.clearances_at(sparse) >= self.comfortable] if len(sparse) else sparse
        if len(candidates) == 0 or len(sparse) == 0:
            return np.zeros(len(candidates), bool)
        a = np.repeat(candidates, len(sparse), axis=0)
        b = np.tile(sparse, (len(candidates), 1))
        least = _segment_profiles(self.world, a, b, self.comfortable)[0].reshape(len(candidates), len(sparse))
        return cast(NDArray[np.bool_], (least >= self.join).any(axis=1))

    def rank(self, a: NDArray, x: NDArray, need: float) -> list[tuple[NDArray, NDArray, float, float]]:
        """Lines a[k] -> x[k] that cross a narrow stretch from a long enough approach to a long
        enough exit keeping ``need``, best first: (approach point, exit point, approach, least)."""
        if len(a) == 0:
            return []
        least, approach, exit_, ends, crosses = _segment_profiles(self.world, a, x, self.comfortable)
        ok = ends & crosses & (least >= need) & (approach >= min(APPROACH_M)) & (exit_ >= EXIT_M * 0.75)
        # the margin left at the passage once the follower's offset after its turn at the
        # approach point (about 0.15 m, dying out over the lookahead) is spent
        spare = least - self.radius - FOLLOWER_OFFSET_M * np.exp(-approach / FOLLOWER_SETTLE_M)
        order = sorted(np.nonzero(ok)[0], key=lambda k: -spare[k])
        return [(a[k], x[k], float(approach[k]), float(least[k])) for k in order]

    def axis_candidates(self, s: int, e: int) -> tuple[NDArray, NDArray]:
        """Approach and exit points on the stretch's axis through its narrowest point, tilted by
        each of ``TILT_DEG``, each approach ``APPROACH_M`` before where the clearance gets roomy."""
        points, arc = self.points, self.arc
        m = s + int(np.argmin(self.clear[s : e + 1]))
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
            back = _leave_distance(self.world, points[m], -u, self.comfortable, limit)
            ahead = _leave_distance(self.world, points[m], u, self.comfortable, limit)
            if back is None or ahead is None:
                continue
            for d in APPROACH_M:
                approach_points.append(points[m] - u * (back + d))
                exit_points.append(points[m] + u * (ahead + EXIT_M))
        return np.array(approach_points).reshape(-1, 2), np.array(exit_points).reshape(-1, 2)

    def best_line(self, s: int, e: int, need: float, cursor: int) -> tuple[NDArray, NDArray] | None:
        """The straight line (approach point, exit point) across the stretch [s, e], or None."""
        points, arc = self.points, self.arc
        before = points[max(cursor, int(np.searchsorted(arc, arc[s] - JOIN_WINDOW_M))) : s]
        after = points[e + 1 : int(np.searchsorted(arc, arc[e] + JOIN_WINDOW_M, side="right"))]
        if len(before) == 0 or len(after) == 0:
            return None
        axis_a, axis_x = self.axis_candidates(s, e)
        found = self.rank(axis_a, axis_x, need)
        for a, x, _, _ in [f for f in found if f[2] >= GOOD_APPROACH_M][:20]:
            if self.seen_from(a[None], before)[0] and self.seen_from(x[None], after)[0]:
                return a, x
        entries = _disc_points(self.world, points[s], ENTRY_RADIUS_M, self.comfortable)
        exits = _disc_points(self.world, points[e], EXIT_RADIUS_M, self.comfortable)
        entries, exits = entries[self.seen_from(entries, before)], exits[self.seen_from(exits, after)]
        if len(axis_a):
            keep = self.seen_from(axis_a, before) & self.seen_from(axis_x, after)
            entries = np.vstack([entries, axis_a[keep]])
            exits = np.vstack([exits, axis_x[keep]])
        if len(entries) == 0 or len(exits) == 0:
            return None
        found = self.rank(np.repeat(entries, len(exits), axis=0), np.tile(exits, (len(entries), 1)), need)
        return (found[0][0], found[0][1]) if found else None

    def joined(self, a: NDArray, x: NDArray, s: int, e: int, cursor: int) -> tuple[int, int]:
        """The earliest walk index before ``s`` seen from a, the latest after ``e`` seen from x."""
        points, arc, comfortable = self.points, self.arc, self.comfortable
        first = max(cursor, int(np.searchsorted(arc, arc[s] - JOIN_WINDOW_M)))
        last = int(np.searchsorted(arc, arc[e] + JOIN_WINDOW_M, side="right"))
        before, after = points[first:s], points[e + 1 : last]
        ok_a = _segment_profiles(self.world, before, np.broadcast_to(a, before.shape), comfortable)[0] >= self.join
        ok_x = _segment_profiles(self.world, np.broadcast_to(x, after.shape), after, comfortable)[0] >= self.join
        ok_a &= ~self.narrow[first:s]  # joined at roomy points of the walk only
        ok_x &= ~self.narrow[e + 1 : last]
        return first + int(np.argmax(ok_a)), e + 1 + int(len(after) - 1 - np.argmax(ok_x[::-1]))

    def entry_approach(self, s: int, need: float, cursor: int) -> tuple[NDArray, int] | None:
        """An approach point straight behind where the walk enters the stretch, and the walk
        index it is joined from."""
        points, arc, comfortable = self.points, self.arc, self.comfortable
        inward = point_at_arc(points, arc, arc[s] + AXIS_WINDOW_M) - points[s]
        if np.linalg.norm(inward) < 1e-9:
            return None
        inward /= np.linalg.norm(inward)
        first = max(cursor, int(np.searchsorted(arc, arc[s] - JOIN_WINDOW_M)))
        before = points[first:s]
        if len(before) == 0:
            return None
        for d in APPROACH_M:
            a = points[s] - inward * d
            if self.world.clearances_at(a[None])[0] < comfortable:
                continue
            if _segment_profiles(self.world, a, points[s], comfortable)[0][0] < min(float(self.clear[s]), need):
                continue
            ok = _segment_profiles(self.world, before, np.broadcast_to(a, before.shape), comfortable)[0] >= self.join
            ok &= ~self.narrow[first:s]
            if ok.any():
                return a, first + int(np.argmax(ok))
        return None

    def kept_through(self, s: int, e: int, need: float, cursor: int) -> tuple[list[NDArray], list[NDArray], int]:
        """The walk kept through a stretch no line crosses, densely, entered straight if it can
        be: (pieces, their pins, the walk index the rest of the walk goes on from)."""
        points, arc = self.points, self.arc
        hi = int(np.searchsorted(arc, arc[e] + PIN_M, side="right"))
        approach = self.entry_approach(s, need, cursor)
        if approach is not None:
            a, t = approach
            pieces = [points[cursor : t + 1], a[None], points[s:hi]]
            return pieces, [np.zeros(t + 1 - cursor, bool), np.ones(1 + hi - s, bool)], hi
        lo = max(cursor, int(np.searchsorted(arc, arc[s] - PIN_M)))
        return [points[cursor:lo], points[lo:hi]], [np.zeros(lo - cursor, bool), np.ones(hi - lo, bool)], hi


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
    clear = world.clearances_at(points)
    comfortable = space.radius + ROUTE_MARGIN_M
    narrow = clear < comfortable
    if n < 3 or narrow.all() or not narrow.any():
        return points, np.zeros(n, bool)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    walk = _Walk(world, points, space.radius, clear, comfortable, narrow, arc, comfortable - CLEARANCE_SLACK_M)
    out: list[NDArray] = []
    pins: list[NDArray] = []
    cursor = 0
    for s, e in _narrow_runs(narrow, arc):
        if s < cursor or e >= n - 1:
            continue  # the walk starts or ends in it, or an earlier line already replaced it
        least = float(clear[s : e + 1].min())
        need = max(least - TILT_LOSS_M, min(least, space.radius + PASS_MARGIN_M)) - CLEARANCE_SLACK_M
        line = walk.best_line(s, e, need, cursor)
        if line is None:  # keep the walk itself through it, densely, entered straight if possible
            pieces, pinned, cursor = walk.kept_through(s, e, need, cursor)
            out.extend(pieces)
            pins.extend(pinned)
            continue
        a, x = line
        t, v = walk.joined(a, x, s, e, cursor)
        out.extend([points[cursor : t + 1], a[None], x[None]])
        pins.extend([np.zeros(t + 1 - cursor, bool), np.ones(2, bool)])
        cursor = v
    out.append(points[cursor:])
    pins.append(np.zeros(n - cursor, bool))
    return np.vstack(out), np.concatenate(pins)
