"""The narrowest gap a trial passes: how much room its ground-truth shortest path leaves the robot.

A trial's GT shortest path (``scenarios.trials``) hugs every corner at exactly the robot radius r,
so the clearance of the path itself says nothing of the passages it goes through. The narrowest
gap is instead the room the robot would have if it kept as far from walls as it can while going
the same way: the bottleneck (maximin) clearance of the paths from start to goal that stay within
``GAP_CAP_M`` of the GT shortest path, less r:

    gap = max over such paths P of min over P of (C(p) - r),  capped at GAP_CAP_M,

with C the clearance (distance to the nearest non-free cell). It is the space left on *each side*
of a robot centred in the narrowest passage: a door of free width w gives w / 2 - r, a straight
corridor of width w the same. Two things are left out:

* where a robot at either end gets more room without passing anything narrower: the cells it
  reaches by steps to a strictly higher clearance (away from the wall beside it, up to the middle
  of its corridor or room), within 1 m. A start beside a wall is not a gap the robot passes; a
  start in a corridor still passes the corridor (its middle is flat, no step climbs along it);
* room beyond ``GAP_CAP_M`` (1 m): the paths keep within it of the shortest path, so that a
  detour through another door never counts as the way this trial goes, and a gap of 1 m or
  more is reported as 1.0 (wide open).

Sub-cell precision. The raster's clearance is measured from cell centres, so on the ridge of a
passage of n cells it is n / 2 cells for odd n but n / 2 - 1/2 for even n (the ridge falls between
two centres): half a cell (2.5 cm at 0.05 m) short, as much as a door's spare against a 0.1 m
margin. A cell that is a top along an axis or a diagonal (no neighbour on that line higher) is
lifted to the top of the tent through it and its two neighbours, each side of slope
(C - lower neighbour) / step: by (higher neighbour - lower neighbour) / 2. That is exact for
passages aligned with the raster (a door of n cells gives n·res / 2, whatever n's parity) and
within half a cell at other angles (measured on doors at 10-80°: -0.46 to +0.13 of a cell against
the exact width). Only a cell that is a top across some line is lifted, so a bottleneck, which is
a minimum along the path, is not lifted along the path.

The search, in a box round the path: the tube is the free cells within 1 m of the path's cells;
label its cells valued at least a threshold (8-connected), and bisect the threshold over the values
present to the largest at which the two ends' climbs are joined. Where: among the cells of that
value joining them, the one nearest both ends' pieces at the next value (in a door, not the
corners of its mouths, which hold the same value), then nearest the path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
from numpy.typing import NDArray

from navkit.grid_planning import densify
from scenarios.schema import GAP_CAP_M
from scenarios.world import World


@dataclass(frozen=True)
class Gap:
    """The narrowest gap of a path: ``gap_m`` (beyond the radius, on each side) and where it is."""

    gap_m: float
    where: tuple[float, float] | None  # (x, y) of the bottleneck cell's centre; None when wide open


def ridge_clearance(clearance: NDArray, resolution: float, rows: int = 1024) -> NDArray[np.float32]:
    """(H, W) float32: ``clearance`` with the tops of tents lifted to the fitted ridge (module
    docstring); computed ``rows`` at a time, so that a large raster needs little more than the result."""
    h, w = clearance.shape
    lifted = np.empty((h, w), np.float32)
    for top in range(0, h, rows):
        lo, hi = max(top - 1, 0), min(top + rows + 1, h)  # a row of context each side
        stripe = np.asarray(clearance[lo:hi], dtype=np.float32)
        padded = np.pad(stripe, 1)  # outside the raster: not free
        n = hi - lo
        best = stripe.copy()
        for dr, dc in ((0, 1), (1, 0), (1, 1), (1, -1)):
            before = padded[1 - dr : 1 - dr + n, 1 - dc : 1 - dc + w]
            after = padded[1 + dr : 1 + dr + n, 1 + dc : 1 + dc + w]
            high, low = np.maximum(before, after), np.minimum(before, after)
            # a tent of slope k = (C - low) / step, its top between C and the higher sample, stands
            # (high - low) / 2 above C
            rise = (high - low) / 2
            rise[(stripe <= 0) | (stripe < high)] = 0
            np.maximum(best, stripe + rise, out=best)
        lifted[top : min(top + rows, h)] = best[top - lo : top - lo + min(rows, h - top)]
    return lifted


class GapGauge:
    """Measures the narrowest gaps of paths in one world for a robot of ``radius`` (the ridge
    clearance is computed once, over the whole raster, at the first measure)."""

    def __init__(self, world: World, radius: float) -> None:
        self.world = world
        self.radius = float(radius)

    @cached_property
    def ridge(self) -> NDArray[np.float32]:
        return ridge_clearance(self.world.clearance, self.world.resolution)

    def measure(self, path: NDArray) -> Gap:
        """The narrowest gap (m, beyond the radius) of the start-to-goal ``path`` (K, 2)."""
        tube = self._tube(path)
        if tube.joined(GAP_CAP_M) is not None:
            return Gap(GAP_CAP_M, None)
        floor = float(tube.values[tube.path[:, 0], tube.path[:, 1]].min())  # the shortest path itself holds this
        if not np.isfinite(floor):  # the ends climb to each other
            return Gap(GAP_CAP_M, None)
        candidates = np.unique(tube.values[(tube.values > floor) & (tube.values < GAP_CAP_M)])
        best, low, high = floor, 0, len(candidates) - 1
        while low <= high:  # the largest candidate at which the ends are still joined
            mid = (low + high) // 2
            if tube.joined(float(candidates[mid])) is not None:
                best, low = float(candidates[mid]), mid + 1
            else:
                high = mid - 1
        apart = float(candidates[low]) if low < len(candidates) else GAP_CAP_M  # the least value that parts them
        x, y = self.world.to_world(tube.bottleneck(best, apart) + tube.corner)
        return Gap(max(best, 0.0), (float(x), float(y)))

    def _tube(self, path: NDArray) -> _Tube:
        """The cells within ``GAP_CAP_M`` of ``path`` in a box round it, valued by their room beyond the radius."""
        world, res = self.world, self.world.resolution
        shape = np.array(world.shape)
        cells = np.clip(world.to_cell(densify(path, res / 2.0)), 0, shape - 1)
        pad = int(math.ceil(GAP_CAP_M / res)) + 2
        lo = np.maximum(cells.min(axis=0) - pad, 0)
        hi = np.minimum(cells.max(axis=0) + pad + 1, shape)
        clear = self.ridge[lo[0] : hi[0], lo[1] : hi[1]]
        local = cells - lo
        not_path = np.ones(clear.shape, np.uint8)
        not_path[local[:, 0], local[:, 1]] = 0
        from_path = cv2.distanceTransform(not_path, cv2.DIST_L2, cv2.DIST_MASK_PRECISE) * res
        inside = (from_path <= GAP_CAP_M) & (clear > 0)
        inside[local[:, 0], local[:, 1]] = True
        values = np.where(inside, clear - np.float32(self.radius), np.float32(-np.inf))
        reach = int(math.ceil(GAP_CAP_M / res))
        ends = [ascent(values, local[0], reach), ascent(values, local[-1], reach)]
        for end in ends:
            values[end] = np.inf
        return _Tube(lo, local, from_path, values)


NEIGHBOURS = ((-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1))


def ascent(values: NDArray[np.float32], cell: NDArray, reach: int) -> NDArray[np.bool_]:
    """(H, W) the cells reached from ``cell`` by steps to a strictly higher 8-neighbour within
    ``reach`` cells of it: where a robot at that end gets more room without passing anything
    narrower (away from the wall beside it, up to the middle of its room or corridor)."""
    shape = np.array(values.shape)
    r0, c0 = np.maximum(cell - reach, 0)
    r1, c1 = np.minimum(cell + reach + 1, shape)
    window = values[r0:r1, c0:c1]
    h, w = window.shape
    around = np.pad(window, 1, constant_values=np.inf)  # beyond the window: no step from there
    zone = np.zeros((h + 2, w + 2), bool)
    zone[cell[0] - r0 + 1, cell[1] - c0 + 1] = True
    while True:
        grown = zone.copy()
        for dr, dc in NEIGHBOURS:
            source = np.s_[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w]
            grown[1:-1, 1:-1] |= zone[source] & (window > around[source])
        if np.array_equal(grown, zone):
            break
        zone = grown
    out = np.zeros(values.shape, bool)
    out[r0:r1, c0:c1] = zone[1:-1, 1:-1]
    return out


@dataclass(frozen=True)
class _Tube:
    """The box a path's gap is searched in: its corner cell in the raster, the path's cells in it,
    each cell's distance (m) from the path and its value (room beyond the radius; -inf outside
    the tube, +inf where a robot at either end climbs to without passing anything, ``ascent``)."""

    corner: NDArray[np.int64]
    path: NDArray[np.int64]  # (M, 2) cells of the path, in the box
    from_path: NDArray[np.float32]
    values: NDArray[np.float32]

    def labels(self, threshold: float) -> NDArray[np.int32]:
        """The 8-connected pieces of the cells valued at least ``threshold``."""
        _, labels = cv2.connectedComponents((self.values >= threshold).view(np.uint8), connectivity=8)
        return np.asarray(labels, dtype=np.int32)

    def joined(self, threshold: float) -> NDArray[np.bool_] | None:
        """The cells joining the path's two ends through values >= ``threshold``, or None if they are apart."""
        labels = self.labels(threshold)
        start, goal = labels[tuple(self.path[0])], labels[tuple(self.path[-1])]
        return labels == start if start == goal and start > 0 else None

    def bottleneck(self, best: float, apart: float) -> NDArray[np.int64]:
        """The cell (in the box) where the ends' pieces at ``apart`` come nearest through the cells
        of value ``best`` that join them: in a door, not the mouths' corners, which hold that value too."""
        labels = self.labels(apart)
        sides = [labels == labels[tuple(cell)] for cell in (self.path[0], self.path[-1])]
        near = [cv2.distanceTransform((~side).view(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE) for side in sides]
        joining = self.joined(best)
        cut = np.argwhere((joining if joining is not None else np.isfinite(self.values)) & (self.values < apart))
        if not len(cut):
            return self.path[0]
        through = near[0][cut[:, 0], cut[:, 1]] + near[1][cut[:, 0], cut[:, 1]]
        order = np.lexsort((self.from_path[cut[:, 0], cut[:, 1]], np.round(through, 3)))
        return cut[order[0]]


def narrowest_gap(world: World, radius: float, path: NDArray) -> Gap:
    """The narrowest gap of one path (``GapGauge`` measures many in one world without repeating its set-up)."""
    return GapGauge(world, radius).measure(path)
