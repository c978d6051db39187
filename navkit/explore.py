"""Moves toward open space while a system does not know where it is (a start-up without a pose):
a path in the robot's own scan (``navkit.scan_grid.ScanGrid``) to new ground, followed by the
system's follower in the odometry frame of the pose it started from, every blind move checked
against each new scan. NavTopo's start-up explores so when no hypothesis gets anywhere; the metric
baseline's kidnapped start, while its global searches have not confirmed a pose.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from navkit.follower import PathFollower
from navkit.geometry import between, distance_to_polyline, transform_points
from navkit.raster import FREE, inside
from navkit.scan import obstacle_points
from navkit.scan_grid import GridConfig, ScanGrid
from navkit.types import Command, Observation

ROOMY_M = 0.3  # m beyond the robot's radius free all round: an exploring move among look-alikes may begin
FAR_LOOK_M = 10.0  # m: how far along each direction an exploring move weighs the new ground the scan shows


class Explorer:
    """The start-up's moves toward open space, and the check of every blind move against the scan.

    An exploring move is a path in the robot's own scan to new ground (``_open_space_path``),
    followed by the shared follower in the odometry frame of the pose it started from, until the
    follower reaches its end or the start-up odometer has run ``explore_distance`` further."""

    def __init__(
        self,
        follower: PathFollower,
        grid_config: GridConfig,
        explore_distance: float,
        robot_radius: float,
        radii: tuple[float, float],
        check_distance: float,
    ) -> None:
        self.follower = follower  # the system's: one path is followed at a time
        self.grid_config = grid_config
        self.explore_distance = explore_distance  # m of odometer a move runs
        self.robot_radius = robot_radius
        self.radii = radii  # (with a margin, alone): the exploring plan's levels, as the system's local planner's
        self.check_distance = check_distance  # m of the path ahead checked against the scan
        self.reset()

    def reset(self) -> None:
        self.move: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None  # (odom at start, path in that frame)
        self.until = 0.0  # the start-up odometer reading where the current exploring move ends
        self._progress_mark: tuple[float, float] | None = None  # (stamp, start-up odometer) of the last progress
        self.trail: list[NDArray[np.float64]] = []  # where the robot drove (odometry frame)
        self.heading: float | None = None  # the last exploring move's direction (odometry frame, rad)

    def record(self, odom: NDArray) -> None:
        """Where the robot drives, every 0.25 m: exploring moves lead away from it."""
        here = np.asarray(odom, dtype=np.float64)[:2].copy()
        if not self.trail or np.hypot(*(here - self.trail[-1])) >= 0.25:
            self.trail.append(here)

    def under_way(self, odometer: float) -> bool:
        """An exploring move is running and has not reached its end: it runs to its end."""
        return self.move is not None and odometer < self.until and not self.follower.reached

    def roomy(self, obs: Observation) -> bool:
        """Nothing the scan shows within ``ROOMY_M`` beyond the robot's radius: room to turn and
        set off in any direction (not in a doorway)."""
        points = obstacle_points(obs.points, self.grid_config)
        if not len(points):
            return True
        return float(np.hypot(points[:, 0], points[:, 1]).min()) >= self.robot_radius + ROOMY_M

    def no_progress(self, stamp: float, odometer: float) -> bool:
        """While not localized: less than 0.3 m of motion in the last 5 s."""
        if self._progress_mark is None or odometer - self._progress_mark[1] >= 0.3:
            self._progress_mark = (stamp, odometer)
            return False
        return stamp - self._progress_mark[0] > 5.0

    def stop(self) -> None:
        """Give up the exploring move (the robot drives by a hypothesis instead)."""
        self.move = None

    def begin(self, stamp: float, odometer: float) -> None:
        """A new exploring move, ``explore_distance`` of odometer from here; its path is planned at the next ``step``."""
        self.move = None
        self.until = odometer + self.explore_distance
        self._progress_mark = (stamp, odometer)

    def step(self, obs: Observation, counters: dict[str, int]) -> Command:
        """Drive toward the most open direction of the robot's own scan (``explore_moves`` and
        ``explore_blocked`` counted in ``counters``). The way ahead is checked against every new scan:
        a path planned through cells the first scan did not see (a wall seen edge-on from a doorway)
        is given up at the first scan that shows a wall on it."""
        if self.move is not None and len(self.scan_on_path(obs, between(self.move[0], obs.odom))):
            self.move = None
            self.follower.clear()
            counters["explore_blocked"] += 1
        if self.move is None or self.follower.reached or not self.follower.has_path:
            path = self._open_space_path(obs)
            if path is None:
                return Command(0.0, self.follower.config.max_angular / 2)
            self.move = (np.asarray(obs.odom, dtype=np.float64).copy(), path)
            self.heading = float(obs.odom[2] + np.arctan2(path[-1, 1], path[-1, 0]))
            self.follower.set_path(path)
            counters["explore_moves"] += 1
        start_odom, _ = self.move
        return self.follower.command(between(start_odom, obs.odom))

    def scan_on_path(self, obs: Observation, pose: NDArray) -> NDArray[np.float64]:
        """The scan's obstacle returns (in the path's frame, the robot at ``pose`` there) within the
        robot's radius of the path ahead: the robot would touch them."""
        if not self.follower.has_path:
            return np.zeros((0, 2))
        ahead = np.vstack([pose[None, :2], self.follower.path_ahead(self.check_distance)])
        points = np.asarray(obstacle_points(obs.points, self.grid_config)[:, :2], dtype=np.float64)
        # returns farther from the robot than the way ahead reaches (plus the radius) cannot touch it
        reach = float(np.hypot(*(ahead - pose[:2]).T).max()) + self.robot_radius
        xy = transform_points(pose, points[np.hypot(points[:, 0], points[:, 1]) <= reach])
        return xy[distance_to_polyline(xy, ahead) < self.robot_radius]

    def _open_space_path(self, obs: Observation) -> NDArray[np.float64] | None:
        """A path in the robot's own scan to new ground: of the free points ``explore_distance`` (or
        twice, or half that) away, the one in the direction whose free ground, as far as the scan
        shows it within ``FAR_LOOK_M``, lies farthest from where the start-up has already driven;
        on ties, the point itself farthest from it, then forward. The way out of a room leads
        through its door, not round the room again (judged by the points within reach alone, a room
        toured left nothing new, and the explorer went round it for 40 s), and along a corridor
        onward rather than into the next room (on a wing of identical rooms only the corridor's
        ends tell the places apart). No move turns back (more than 90° from the last one) while a
        direction that does not shows new ground: what a scan shows through a door changes as the
        robot moves, and a room's two doors each seen newest in turn sent the robot back and forth
        between them for 80 s."""
        scan = ScanGrid.of(obs.points, self.grid_config, *self.radii)
        grid, frame = scan.grid, scan.frame
        passable = scan.mask(3) & (grid == FREE)  # the tight radius, not occupied
        angles = np.radians(np.arange(0.0, 360.0, 15.0))
        reach = self.explore_distance
        directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        ends = np.vstack([directions * reach * scale for scale in (2.0, 1.0, 0.5)])
        cells = frame.to_cell(ends)
        on_grid = inside(cells, passable.shape)
        ok = np.flatnonzero(on_grid)[passable[cells[on_grid, 0], cells[on_grid, 1]]]
        if not len(ok):
            return None
        trail = np.array(self.trail) if self.trail else np.zeros((0, 2))
        odom = np.asarray(obs.odom, dtype=np.float64)

        def novelty(points: NDArray) -> NDArray[np.float64]:  # (N, 2) robot frame -> m from the trail
            if not len(trail):
                return np.zeros(len(points))
            in_odom = transform_points(odom, points)
            return np.min(np.hypot(*(in_odom[:, None, :] - trail[None, :, :]).transpose(2, 0, 1)), axis=1)

        # what lies beyond: the newest ground the scan shows free along each direction (a room
        # toured leaves no new ground within reach, but the corridor seen through its door does)
        steps = np.arange(0.5, FAR_LOOK_M + 0.25, 0.5)
        along = directions[:, None, :] * steps[None, :, None]  # (directions, steps, 2)
        samples = frame.to_cell(along.reshape(-1, 2))
        on = inside(samples, grid.shape)
        free = np.zeros(len(samples), bool)
        free[on] = grid[samples[on, 0], samples[on, 1]] == FREE
        free = np.logical_and.accumulate(free.reshape(along.shape[:2]), axis=1)  # up to the first cell not seen free
        beyond = np.where(free, novelty(along.reshape(-1, 2)).reshape(free.shape), 0.0).max(axis=1)
        near = novelty(ends[ok])
        far = np.tile(beyond, 3)[ok]
        forward = np.cos(np.tile(angles, 3))[ok]
        if self.heading is not None:
            onward = np.cos(np.tile(angles, 3)[ok] + odom[2] - self.heading) >= 0.0
            if (onward & (far >= 1.0)).any():
                ok, near, far, forward = ok[onward], near[onward], far[onward], forward[onward]
        # the newest ground along the direction in 1 m steps, then the end's novelty in 0.5 m
        # steps, then forward
        order = np.lexsort((-forward, -np.round(near / 0.5), -np.round(far)))
        for k in ok[order][:8]:
            planned = scan.plan(ends[k])
            if planned is not None:
                return planned.points
        return None
