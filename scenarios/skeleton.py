"""The skeleton a generated route tours, and the depth-first walk over it.

The skeleton is the medial axis (``skimage.morphology.skeletonize``) of the largest connected
piece of the fit space (``scenarios.route_space``), made into something a route can tour:

1. skeleton pixels in roomy space are kept; the narrow stretches between them (where the
   skeleton passes a door or a gap) are kept only where they join parts of the roomy skeleton
   that are not joined otherwise, widest first: a route goes through a door to reach a room,
   never through a gap beside a chair it can go round, never into a dead end narrower than
   the roomy space (its tip would be too tight to turn at), nor through a gap to a pocket of
   less than ``MIN_ROOMY_M2`` of roomy space;
2. loops round small obstacles (chairs, pillars, lidar speckles: less than
   ``SMALL_OBSTACLE_M2``) are opened at their narrowest point; short corner spurs are pruned
   (not a short branch whose tip has a robot radius more clearance than its junction: it runs
   to the middle of a small room, as one does when the loop through a room with two doors has
   been opened next to it; a corner spur loses clearance towards its corner).

``skeleton_walk`` then walks it depth first from a dead end (chosen by the scenario's random
generator) down every branch and back, cell centre by cell centre. Rasters are (H, W) bool,
``[row, col]`` with row <-> y (``scenarios.world``); neighbourhoods are 8-connected.
"""

from __future__ import annotations

from typing import cast

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from skimage.morphology import skeletonize

from navkit.raster import largest_component
from scenarios.route_space import PASS_MARGIN_M, ROUTE_MARGIN_M, RouteSpace
from scenarios.world import World

SPUR_LENGTH_M = 1.5  # skeleton branches shorter than this that end nowhere are pruned (corner spurs)
MIN_ROOMY_M2 = 1.0  # a pocket of roomy space smaller than this is not worth a narrow passage
SMALL_OBSTACLE_M2 = 1.0  # a skeleton loop round less obstacle than this is opened (no tours round chairs)
EIGHT = np.ones((3, 3), bool)
FOUR = ndimage.generate_binary_structure(2, 1)


def _neighbours(mask: NDArray[np.bool_]) -> NDArray[np.int32]:
    kernel = np.ones((3, 3), np.int32)
    kernel[1, 1] = 0
    return ndimage.convolve(mask.astype(np.int32), kernel, mode="constant") * mask


OFFSETS = [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)]


def _prune_spurs(skeleton: NDArray[np.bool_], max_cells: int, clear: NDArray, climb: float, passes: int = 2) -> NDArray[np.bool_]:
    """Remove short branches that end at a junction (corner spurs: the medial axis running into a
    corner, losing clearance); a branch whose tip has ``climb`` more clearance than its junction
    runs to the middle of a small room and stays."""
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
            into_room = clear[branch[0]] >= clear[branch[-1]] + climb
            if ends_at_junction and not into_room:
                for cell in branch:
                    skeleton[cell] = False
        skeleton = skeletonize(skeleton)
    return skeleton


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
    obstacle = (~world.free).ravel().astype(np.float64)
    obstacle_m2 = cast(NDArray[np.float64], np.bincount(faces.ravel(), weights=obstacle, minlength=n_faces + 1))
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
    fit = largest_component(space.fit)
    skeleton = skeletonize(fit)
    if not skeleton.any():
        raise ValueError("free space too narrow for the robot: empty skeleton")
    roomy_from = space.radius + ROUTE_MARGIN_M
    kept = _keep_connecting_passages(skeleton, clear, roomy_from, world.resolution)
    if (kept & (clear >= roomy_from)).any():
        kept = _peel_tips(largest_component(kept), kept & (clear < roomy_from))
    else:  # nothing roomy: at least keep dead ends off their walls
        peeled = _peel_tips(kept, kept & (clear < space.radius + PASS_MARGIN_M + 0.05))
        kept = peeled if peeled.any() else kept
    kept = largest_component(kept)
    kept = _open_small_loops(kept, world, clear, SMALL_OBSTACLE_M2)
    kept = _prune_spurs(kept, int(SPUR_LENGTH_M / world.resolution), clear, climb=space.radius)
    return largest_component(kept)


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
