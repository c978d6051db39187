"""Mapping routes: explicit waypoints joined by ground-truth shortest paths, or generated.

This module composes the parts and owns no algorithm itself:

* ``scenarios.route_space``: the graded space a route may run in (passable, fit, roomy), legs
  planned through it (``waypoint_route``: the waypoints of a scenario file joined by shortest
  paths, roomy first, then fit, then passable) and checked against walls;
* ``scenarios.skeleton``: the skeleton of the fit space a generated route tours, and the walk;
* ``scenarios.passages``: narrow stretches of the walk crossed on straight lines.

A generated route (``auto: {min_length}``) is a closed tour of the skeleton (medial axis) of
the fit space: a depth-first walk that goes down every branch to its end and back, then the
same walk backwards, alternately, until the route is at least ``min_length`` long (places are
seen from both directions). The skeleton and the walk are made drivable:

1. the skeleton keeps roomy space, narrow stretches only where they join what is not joined
   otherwise (doors to rooms), and loops round small obstacles opened (``scenarios.skeleton``);
2. the walk goes down every branch of it and back;
3. every narrow stretch of the walk is crossed on one straight line from an approach point in
   roomy space up to ``APPROACH_M`` before it, laid out for the direction of travel (the
   backward tour gets its own), so the follower has settled when it reaches the door;
   a stretch no straight line crosses is entered straight and then followed densely;
4. the walk is simplified (Douglas-Peucker, one cell) with a clearance rule: a leg may not
   pass closer to walls than the walk it replaces (nor below roomy where that was roomy);
5. every leg of the result is checked against the clearance raster and any leg below the fit
   margin is re-planned (Theta*, roomy first, then fit, then passable).

Routes are (K, 2) float64 polylines, metres in the scenario frame. The names of the parts that
importers use are importable from here too.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from scenarios.passages import APPROACH_M, straighten_passages
from scenarios.route_space import (
    CLEARANCE_SLACK_M,
    PASS_MARGIN_M,
    ROUTE_MARGIN_M,
    RouteSpace,
    as_space,
    leg_clearances,
    plan_leg,
    polyline_length,
    repair_legs,
    route_space,
    shortest_path,
    simplify_walk,
    waypoint_route,
)
from scenarios.skeleton import MIN_ROOMY_M2, SMALL_OBSTACLE_M2, SPUR_LENGTH_M, route_skeleton, skeleton_walk
from scenarios.world import World

__all__ = [
    "APPROACH_M",
    "CLEARANCE_SLACK_M",
    "MIN_ROOMY_M2",
    "PASS_MARGIN_M",
    "ROUTE_MARGIN_M",
    "SMALL_OBSTACLE_M2",
    "SPUR_LENGTH_M",
    "RouteSpace",
    "auto_route",
    "drivable",
    "leg_clearances",
    "plan_leg",
    "polyline_length",
    "repair_legs",
    "route_skeleton",
    "route_space",
    "shortest_path",
    "simplify_walk",
    "skeleton_tour",
    "skeleton_walk",
    "straighten_passages",
    "waypoint_route",
]


def drivable(world: World, walk: NDArray, space: RouteSpace) -> NDArray[np.float64]:
    """A walk made into a route for the follower: narrow passages crossed straight (their approach
    laid out for this direction of travel), simplified with the clearance rule, legs checked."""
    points, pinned = straighten_passages(world, walk, space)
    tour = simplify_walk(world, points, space.radius, pinned=pinned)
    tour, _ = repair_legs(world, tour, space)
    return tour


def skeleton_tour(world: World, space: RouteSpace | NDArray[np.bool_], rng: np.random.Generator) -> NDArray[np.float64]:
    """A closed walk over the route skeleton that visits every branch, as a drivable polyline."""
    space = as_space(world, space)
    return drivable(world, skeleton_walk(world, space, rng), space)


def auto_route(
    world: World, space: RouteSpace | NDArray[np.bool_], min_length: float, rng: np.random.Generator
) -> NDArray[np.float64]:
    """The skeleton tour, then the same walk backwards, alternately, until ``min_length``.

    The backward tour is made drivable on its own (not the forward polyline reversed): a narrow
    passage is entered straight from the side the robot comes from.
    """
    space = as_space(world, space)
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
