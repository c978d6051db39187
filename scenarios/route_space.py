"""Where a route may run, and its legs: planned through that space and checked against walls.

Where a route may run is graded by the clearance C of a point (its distance to the nearest
non-free cell, ``World.clearance``) and the robot radius r:

* passable, C >= r: the robot fits, touching walls (GT shortest paths use this space);
* fit, C >= r + ``PASS_MARGIN_M`` (0.07 m): the narrowest place a generated route passes (a door), and
  only on its centre line, straight through;
* roomy, C >= r + ``ROUTE_MARGIN_M`` (0.15 m): where a route turns, ends and runs wherever it can. The
  shared follower strays up to about 0.12 m from a path at its corners (measured on random
  zig-zags), and overshoots a dead end by about 0.07 m before it turns round.

A leg between two metric points is the any-angle shortest path of ``navkit.grid_planning.plan_path``
in the first of the grades (roomy, fit, passable) that holds both ends (without snapping them) and
joins them: the exact end points, cell centres between. Routes are (K, 2) float64 polylines, x and y
in metres in the scenario frame. The clearance along a leg is sampled every half cell, bilinear
in the clearance raster; a leg below the fit margin is re-planned (``repair_legs``) and
simplification keeps the clearance of the walk it replaces (``simplify_walk``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from navkit import grid_planning
from navkit.grid_planning import plan_path
from scenarios.world import World

ROUTE_MARGIN_M = 0.15  # legs keep this much more than the robot radius from walls where they can
PASS_MARGIN_M = 0.07  # generated routes pass no gap narrower than 2 * (radius + this) (0.74 m for r = 0.3)
CLEARANCE_SLACK_M = 0.01  # a simplified leg may lose this much clearance against the skeleton it replaces


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


def as_space(world: World, space: RouteSpace | NDArray[np.bool_]) -> RouteSpace:
    """A bare passable mask (the old signatures) is the space of a robot as wide as its least clearance."""
    if isinstance(space, RouteSpace):
        return space
    passable = np.asarray(space, bool)
    return route_space(world, float(world.clearance[passable].min()) if passable.any() else 0.0)


# ---------------------------------------------------------------------------------------------
# legs planned


def plan_leg(world: World, tiers: list[NDArray[np.bool_]], a: NDArray, b: NDArray) -> NDArray[np.float64] | None:
    """A shortest path from a to b in the first of ``tiers`` that holds both ends and joins them.

    The ends are not snapped: an end outside a tier's mask (or outside the raster) skips that tier.
    """
    planned = plan_path(tiers, world.frame, a, b)
    return None if planned is None else planned.points


def shortest_path(world: World, passable: NDArray[np.bool_], start_xy: NDArray, goal_xy: NDArray) -> NDArray[np.float64] | None:
    """Any-angle shortest path between two points (both inside ``passable``), as a polyline.

    The end points are the exact points, not the cell centres; the inner vertices are cell centres.
    """
    return plan_leg(world, [passable], start_xy, goal_xy)


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
    return grid_planning.leg_clearances(points, world.clearances_at, world.resolution / 2.0)


def simplify_walk(
    world: World, points: NDArray, radius: float, tolerance: float | None = None, pinned: NDArray[np.bool_] | None = None
) -> NDArray[np.float64]:
    """Douglas-Peucker on a walk over cell centres, with a clearance rule: a leg replaces a stretch
    of the walk only if it keeps as far from walls as that stretch does (less ``CLEARANCE_SLACK_M``),
    capped at ``radius + ROUTE_MARGIN_M`` (``navkit.grid_planning.simplify_clear``). ``pinned``
    points are kept."""
    return grid_planning.simplify_clear(
        points,
        world.clearances_at,
        tolerance=world.resolution if tolerance is None else tolerance,
        cap=radius + ROUTE_MARGIN_M,
        step=world.resolution / 2.0,
        slack=CLEARANCE_SLACK_M,
        pinned=pinned,
    )


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
