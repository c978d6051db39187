"""Obstacles the map lacks, remembered until the lidar sees through them: the marking and clearing
of a costmap's obstacle layer (as Nav2's), shared by every system that plans on a map.

A return of the scan's obstacle band that no mapped wall explains is *marked* (kept as a point on a
grid of ``resolution``); a marked point is *cleared* when a later scan's ray in its direction reaches
beyond it. So a closed door stays blocked while the robot drives round the other way (it never sees
through it), and a person who walked away is forgotten as soon as the robot looks there again.

Points are 2D in the frame the caller plans in (the metric map, or a NavTopo location); the robot's
pose is given in that frame; scans are (N, 2+) in the robot frame.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from navkit.follower import PathFollower
from navkit.geometry import distance_to_polyline, inverse, transform_points
from navkit.raster import GridFrame

BINS = 360

#: The scan guard of every system (``too_near_ahead``): the scan's returns the path's next
#: ``GUARD_AHEAD_M`` metres bring the robot nearer than its radius plus ``GUARD_MARGIN_M`` to.
#: A path planned on a map keeps its clearance from the map's walls, which stand where the pose
#: estimate puts them: 0.1-0.2 m off, a path at the radius plus a few centimetres met a table's
#: corner or a jamb that the scan showed where it was (a start in a room no location saw; a pose
#: carried by noisy odometry). The scan and the path share the pose estimate, so the check holds
#: whatever the error. No margin: a path that would touch a return, followed exactly, is the one
#: stopped; at 0.02 m a precise run's path through a narrow passage 0.318 m from a jamb was, the
#: marks closed the passage (returns marked on 0.1 m cells, the planner keeping the radius and half
#: a cell from them), and the trial ended ``no_path`` 3 m from its goal (office02).
GUARD_MARGIN_M = 0.0
GUARD_AHEAD_M = 1.0
#: updates (scans) a return the guard marks is kept whatever later rays show (``ObstacleMemory``)
GUARD_HOLD = 25


def _bins(xy: NDArray) -> NDArray[np.int64]:
    """The 1° azimuth bin of each point (N, 2+) of the robot frame."""
    return (np.floor((np.arctan2(xy[:, 1], xy[:, 0]) + np.pi) / (2 * np.pi) * BINS).astype(np.int64)) % BINS


class ObstacleMemory:
    """Marked obstacle points, cleared by rays that pass them; a point marked with a ``hold`` is kept
    through that many updates whatever the rays do (the scan guard's: a table's corner between two
    rays was cleared by the next scan, found too near again, and the robot stood planning the same
    path at every tick)."""

    def __init__(self, resolution: float = 0.1, clear_margin: float = 0.3, max_points: int = 20000) -> None:
        self.resolution = resolution
        self.clear_margin = clear_margin
        self.max_points = max_points
        self.clear()

    def clear(self) -> None:
        self._cells = np.zeros((0, 2), dtype=np.int64)
        self._hold = np.zeros(0, dtype=np.int64)  # updates each cell is kept through, uncleared

    def __len__(self) -> int:
        return len(self._cells)

    @property
    def frame(self) -> GridFrame:
        """The cells' frame: the planning frame's origin is the corner of cell (0, 0)."""
        return GridFrame(np.zeros(2), self.resolution)

    @property
    def points(self) -> NDArray[np.float64]:
        """(N, 2) the marked points (cell centres) in the planning frame."""
        return self.frame.to_world(self._cells[:, ::-1])

    @property
    def nbytes(self) -> int:
        return int(self._cells.nbytes)

    def update(self, pose: NDArray, scan_xy: NDArray, new_xy: NDArray, max_range: float) -> None:
        """Clear what this scan sees through, then mark its unexplained returns.

        pose: (3,) the robot in the planning frame; scan_xy: (N, 2+) the scan's obstacle returns in
        the robot frame; new_xy: (M, 2) the returns the map does not explain, planning frame;
        max_range: directions without a return are seen through up to this far.
        """
        if len(self._cells):
            keep = ~self._seen_through(pose, np.asarray(scan_xy)[:, :2], max_range) | (self._hold > 0)
            self._cells, self._hold = self._cells[keep], np.maximum(self._hold[keep] - 1, 0)
        self.mark(new_xy)

    @property
    def holding(self) -> bool:
        """Are any marks held (``mark``'s ``hold``) still?"""
        return bool((self._hold > 0).any())

    def marked(self, xy: NDArray) -> NDArray[np.bool_]:
        """Which points (M, 2+) of the planning frame lie on a marked cell."""
        if not len(xy) or not len(self._cells):
            return np.zeros(len(xy), dtype=bool)
        cells = self.frame.to_cell(np.asarray(xy, dtype=np.float64)[:, :2])[:, ::-1]
        labels = np.unique(np.vstack([self._cells, cells]), axis=0, return_inverse=True)[1].ravel()
        return np.isin(labels[len(self._cells) :], labels[: len(self._cells)])

    def mark(self, xy: NDArray, hold: int = 0) -> None:
        """Mark points (M, 2+) of the planning frame, kept uncleared through ``hold`` updates."""
        if len(xy):
            cells = self.frame.to_cell(np.asarray(xy, dtype=np.float64)[:, :2])[:, ::-1]  # kept as [x, y] cells
            self._set(np.vstack([self._cells, cells]), np.concatenate([self._hold, np.full(len(cells), hold, np.int64)]))

    def _set(self, cells: NDArray[np.int64], hold: NDArray[np.int64]) -> None:
        """Keep ``cells`` (N, 2), each once with the longest of its holds; the last ``max_points``."""
        self._cells, labels = np.unique(cells, axis=0, return_inverse=True)
        self._hold = np.zeros(len(self._cells), np.int64)
        np.maximum.at(self._hold, labels.ravel(), hold)
        self._cells, self._hold = self._cells[-self.max_points :], self._hold[-self.max_points :]

    def _seen_through(self, pose: NDArray, scan_xy: NDArray, max_range: float) -> NDArray[np.bool_]:
        """Which marked points lie in front of this scan's first return in their direction."""
        local = transform_points(inverse(pose), self.points)
        distance = np.hypot(local[:, 0], local[:, 1])
        first = np.full(BINS, max_range)
        if len(scan_xy):
            ranges = np.hypot(scan_xy[:, 0], scan_xy[:, 1])
            scan_bins = (
                np.floor((np.arctan2(scan_xy[:, 1], scan_xy[:, 0]) + np.pi) / (2 * np.pi) * BINS).astype(np.int64)
            ) % BINS
            np.minimum.at(first, scan_bins, ranges)
        # a point is seen through when the rays of its bin and both neighbours all reach beyond it
        reach = np.minimum(np.minimum(first, np.roll(first, 1)), np.roll(first, -1))
        return (distance + self.clear_margin < reach[_bins(local)]) & (distance < max_range - self.clear_margin)

    def transform(self, pose: NDArray) -> None:
        """Re-express the points in a new frame: ``pose`` is the new frame's origin in the old one."""
        if len(self._cells):
            moved = transform_points(inverse(pose), self.points)
            self._set(self.frame.to_cell(moved)[:, ::-1], self._hold)


def too_near_ahead(ahead: NDArray, position: NDArray, returns: NDArray, clearance: float) -> NDArray[np.float64]:
    """The scan guard (``GUARD_MARGIN_M``): the returns (N, 2+) that the way ahead (``position``
    (2,), then the path's points ahead of the robot, (K, 2)) comes nearer than ``clearance`` to, and
    nearer than the robot is to them now (a return beside the robot that the path leads away from
    is none: the planner's start already stands in its reach). Empty when the way keeps clear."""
    returns = np.asarray(returns, dtype=np.float64)
    if returns.ndim != 2 or not len(returns) or not len(ahead):
        return np.zeros((0, 2))
    returns = returns[:, :2]
    way = np.vstack([np.asarray(position, dtype=np.float64)[None, :2], np.asarray(ahead, dtype=np.float64)[:, :2]])
    now = np.hypot(*(returns - way[0]).T)
    near = now < clearance + float(np.hypot(*np.diff(way, axis=0).T).sum())
    if not near.any():
        return np.zeros((0, 2))
    distance = distance_to_polyline(returns[near], way)
    hit = (distance < clearance) & (distance < now[near] - 0.01)
    return returns[near][hit]


def scan_guard(follower: PathFollower, memory: ObstacleMemory, pose: NDArray, returns: NDArray, radius: float) -> bool:
    """The scan guard of a system between its plans: does the way ahead of ``follower`` come too near
    (``too_near_ahead``, ``radius`` + ``GUARD_MARGIN_M``) to the scan's ``returns`` (N, 2+, robot
    frame; the robot at ``pose`` (3,) of the planning frame) not yet in ``memory``? Then they are
    marked there, held ``GUARD_HOLD`` updates (True: the caller drops the path and plans again)."""
    if not follower.has_path:
        return False
    follower.advance(pose[:2])
    xy = transform_points(pose, np.asarray(returns, dtype=np.float64)[:, :2])
    near = too_near_ahead(follower.path_ahead(GUARD_AHEAD_M), pose[:2], xy, radius + GUARD_MARGIN_M)
    near = near[~memory.marked(near)]
    if not len(near):
        return False
    memory.mark(near, GUARD_HOLD)
    return True
