"""Mapping routes: explicit waypoints joined by ground-truth shortest paths, or generated.

A generated route (``auto: {min_length}``) is a closed tour of the free space's skeleton that
walks every branch to its dead end and back (a depth-first traversal of the skeleton graph),
repeated — alternately forwards and backwards, so places are seen from both directions —
until it is at least ``min_length`` long.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from shapely.geometry import LineString
from skimage.morphology import skeletonize

from navtopo import grid_search
from scenarios.world import World

SPUR_LENGTH_M = 1.5  # skeleton branches shorter than this that end nowhere are pruned (corner spurs)


def polyline_length(points: NDArray) -> float:
    points = np.asarray(points, dtype=np.float64)
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum()) if len(points) > 1 else 0.0


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


ROUTE_MARGIN_M = 0.15  # legs keep this much more than the robot radius from walls where they can


def waypoint_route(
    world: World, passable: NDArray[np.bool_], waypoints: NDArray, roomy: NDArray[np.bool_] | None = None
) -> tuple[NDArray[np.float64] | None, int]:
    """Join waypoints by shortest paths; returns (route, -1) or (None, index of the unreachable waypoint).

    Each leg is planned in ``roomy`` (free space with a margin) when both its ends lie there and it
    connects them, so that a follower's small deviations at corners do not touch walls; else in
    ``passable``.
    """
    pieces = [np.asarray(waypoints[0], float)[None, :]]
    for i in range(1, len(waypoints)):
        piece = shortest_path(world, roomy, waypoints[i - 1], waypoints[i]) if roomy is not None else None
        if piece is None:
            piece = shortest_path(world, passable, waypoints[i - 1], waypoints[i])
        if piece is None:
            return None, i
        pieces.append(piece[1:])
    return np.vstack(pieces), -1


def _neighbours(mask: NDArray[np.bool_]) -> NDArray[np.int32]:
    kernel = np.ones((3, 3), np.int32)
    kernel[1, 1] = 0
    return ndimage.convolve(mask.astype(np.int32), kernel, mode="constant") * mask


def _prune_spurs(skeleton: NDArray[np.bool_], max_cells: int, passes: int = 2) -> NDArray[np.bool_]:
    skeleton = skeleton.copy()
    offsets = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]
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
                    for dr, dc in offsets
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
                for rr, cc in ((branch[-1][0] + dr, branch[-1][1] + dc) for dr, dc in offsets)
                if 0 <= rr < h and 0 <= cc < w
            )
            if ends_at_junction:
                for cell in branch:
                    skeleton[cell] = False
        skeleton = skeletonize(skeleton)
    return skeleton


def skeleton_tour(world: World, passable: NDArray[np.bool_], rng: np.random.Generator) -> NDArray[np.float64]:
    """A closed walk over the skeleton of ``passable`` that visits every branch, as a polyline."""
    skeleton = skeletonize(passable)
    skeleton = _prune_spurs(skeleton, max_cells=int(SPUR_LENGTH_M / world.resolution))
    labels, count = ndimage.label(skeleton, structure=np.ones((3, 3), bool))
    if count == 0:
        raise ValueError("free space too narrow for the robot: empty skeleton")
    if count > 1:  # keep the largest piece (the others are unreachable anyway)
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        skeleton = labels == int(np.argmax(sizes))
    cells = np.argwhere(skeleton)
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
    points = world.to_world(cells[np.asarray(walk)])
    simplified = np.asarray(LineString(points).simplify(world.resolution, preserve_topology=False).coords)
    return simplified


def auto_route(world: World, passable: NDArray[np.bool_], min_length: float, rng: np.random.Generator) -> NDArray[np.float64]:
    tour = skeleton_tour(world, passable, rng)
    pieces = [tour]
    length = polyline_length(tour)
    if length <= 0:
        raise ValueError("the skeleton tour has zero length")
    while length < min_length:
        nxt = pieces[-1][::-1]
        pieces.append(nxt[1:])
        length += polyline_length(tour)
    return np.vstack(pieces)
