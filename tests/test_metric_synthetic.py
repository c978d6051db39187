"""A tiny synthetic 3D lidar for the metric-baseline tests, and tests of it.

The world is a 2D height raster (0.05 m cells): 0 is floor, a positive value a solid block of
that height (walls 2.6 m, furniture lower). The lidar matches the simulated one: mounted at
0.6 m, 16 channels over [-15°, 15°], 1° horizontal steps, 15 m range, floor hits returned, no
ceiling. Rays are marched in 0.02 m steps, then each hit is refined by bisection (numpy,
~50 ms a scan).

The other ``test_metric_*`` files import the helpers from here (pytest puts ``tests/`` on the path).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from navkit import geometry as se2

WALL_HEIGHT = 2.6
MOUNT_HEIGHT = 0.6
MAX_RANGE = 15.0
CHANNELS = np.deg2rad(np.linspace(-15.0, 15.0, 16))
AZIMUTHS = np.deg2rad(np.arange(360.0))
STEP = 0.02


@dataclass
class World:
    """heights[row, col]: block height of the cell at x = origin_x + (col + 0.5) res, y likewise."""

    heights: np.ndarray
    origin: np.ndarray
    resolution: float = 0.05

    @classmethod
    def solid(cls, xmin: float, ymin: float, xmax: float, ymax: float, res: float = 0.05):
        shape = (int(round((ymax - ymin) / res)), int(round((xmax - xmin) / res)))
        return cls(np.full(shape, WALL_HEIGHT, np.float32), np.array([xmin, ymin]), res)

    def _box(self, xmin, ymin, xmax, ymax):
        res = self.resolution
        c0 = int(round((xmin - self.origin[0]) / res))
        c1 = int(round((xmax - self.origin[0]) / res))
        r0 = int(round((ymin - self.origin[1]) / res))
        r1 = int(round((ymax - self.origin[1]) / res))
        return slice(max(r0, 0), max(r1, 0)), slice(max(c0, 0), max(c1, 0))

    def carve(self, xmin: float, ymin: float, xmax: float, ymax: float) -> World:
        """Make an axis-aligned rectangle free floor."""
        self.heights[self._box(xmin, ymin, xmax, ymax)] = 0.0
        return self

    def block(self, xmin, ymin, xmax, ymax, height: float = WALL_HEIGHT) -> World:
        """Put a solid block (a pillar, a box of furniture) into the world."""
        self.heights[self._box(xmin, ymin, xmax, ymax)] = height
        return self

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        col = np.floor((x - self.origin[0]) / self.resolution).astype(np.int64)
        row = np.floor((y - self.origin[1]) / self.resolution).astype(np.int64)
        inside = (row >= 0) & (row < self.heights.shape[0]) & (col >= 0)
        inside &= col < self.heights.shape[1]
        out = np.full(x.shape, WALL_HEIGHT, np.float32)
        out[inside] = self.heights[row[inside], col[inside]]
        return out

    @property
    def free_mask(self) -> np.ndarray:
        return self.heights <= 0.0


def scan(world: World, robot_pose: np.ndarray) -> np.ndarray:
    """(N, 3) float32 returns in the robot frame, z up from the floor, as the simulator gives."""
    steps = np.arange(1, int(MAX_RANGE / STEP) + 1) * STEP  # (K,)
    world_yaw = robot_pose[2] + AZIMUTHS  # (A,)
    xs = robot_pose[0] + np.cos(world_yaw)[:, None] * steps[None, :]
    ys = robot_pose[1] + np.sin(world_yaw)[:, None] * steps[None, :]
    heights = world.height_at(xs, ys)  # (A, K)
    beam_z = MOUNT_HEIGHT + np.tan(CHANNELS)[:, None] * steps[None, :]  # (C, K)
    hit = (beam_z[None, :, :] <= heights[:, None, :]) | (beam_z[None, :, :] <= 0.0)
    first = np.argmax(hit, axis=2)  # (A, C)
    has_hit = hit.max(axis=2)
    # refine each hit between the last free sample and the first blocked one (bisection)
    lo = np.where(first > 0, steps[np.maximum(first - 1, 0)], 0.0)
    hi = steps[first]
    cos_a = np.cos(world_yaw)[:, None]
    sin_a = np.sin(world_yaw)[:, None]
    tan_e = np.tan(CHANNELS)[None, :]
    for _ in range(8):
        mid = 0.5 * (lo + hi)
        z = MOUNT_HEIGHT + tan_e * mid
        blocked = z <= world.height_at(robot_pose[0] + cos_a * mid, robot_pose[1] + sin_a * mid)
        blocked |= z <= 0.0
        hi = np.where(blocked, mid, hi)
        lo = np.where(blocked, lo, mid)
    ranges = hi
    # floor hits at their exact distance
    tan_c = np.tan(CHANNELS)
    with np.errstate(divide="ignore"):
        floor_range = np.where(tan_c < 0, -MOUNT_HEIGHT / tan_c, np.inf)
    on_floor = has_hit & (beam_z[np.arange(16)[None, :], first] <= 0.0)
    on_floor &= heights[np.arange(360)[:, None], first] <= 0.0
    ranges = np.where(on_floor, np.broadcast_to(floor_range, ranges.shape), ranges)
    az = np.broadcast_to(AZIMUTHS[:, None], ranges.shape)
    z = MOUNT_HEIGHT + np.tan(CHANNELS)[None, :] * ranges
    pts = np.stack([np.cos(az) * ranges, np.sin(az) * ranges, np.where(on_floor, 0.0, z)], -1)
    return pts[has_hit].astype(np.float32)


def corridor_world() -> World:
    """A 30 m corridor, 2.4 m wide, with door niches, pillars and furniture every few metres."""
    world = World.solid(-3.0, -5.0, 33.0, 5.0).carve(-1.0, -1.2, 31.0, 1.2)
    rng = np.random.default_rng(3)
    for x in np.arange(1.0, 30.0, 2.7):
        side = 1 if rng.random() < 0.5 else -1
        depth = rng.uniform(0.3, 1.2)
        width = rng.uniform(0.8, 1.6)
        y0, y1 = (1.2, 1.2 + depth) if side > 0 else (-1.2 - depth, -1.2)
        world.carve(x, y0, x + width, y1)
    for x in np.arange(2.5, 30.0, 4.1):
        side = 1 if rng.random() < 0.5 else -1
        y = 0.85 * side
        world.block(x, y - 0.15, x + rng.uniform(0.25, 0.6), y + 0.15, rng.uniform(0.5, 2.6))
    return world


def loop_world() -> World:
    """A rectangular ring corridor (10 m x 7 m centre line, 2 m wide) with niches and pillars."""
    world = World.solid(-3.0, -3.0, 13.0, 10.0)
    world.carve(-1.0, -1.0, 11.0, 1.0).carve(-1.0, 6.0, 11.0, 8.0)
    world.carve(-1.0, -1.0, 1.0, 8.0).carve(9.0, -1.0, 11.0, 8.0)
    for x0, y0, x1, y1 in [
        (2.0, 1.0, 3.0, 1.6),
        (5.5, -1.7, 6.5, -1.0),
        (3.5, 8.0, 4.8, 8.7),
        (7.0, 5.3, 8.0, 6.0),
        (-1.6, 3.0, -1.0, 4.2),
        (11.0, 2.0, 11.6, 3.5),
        (1.0, 4.5, 1.5, 5.5),
        (8.4, 1.5, 9.0, 2.3),
    ]:
        world.carve(x0, y0, x1, y1)
    for x0, y0, x1, y1, h in [
        (4.0, 0.5, 4.3, 0.8, 2.6),
        (6.0, 6.2, 6.4, 6.6, 0.9),
        (0.4, 2.0, 0.8, 2.3, 1.5),
        (9.2, 5.0, 9.5, 5.4, 2.6),
    ]:
        world.block(x0, y0, x1, y1, h)
    return world


def room_world() -> World:
    """A 6 m x 4 m box room with a 0.5 m x 0.5 m box of 0.8 m standing in it."""
    return World.solid(-1.0, -1.0, 7.0, 5.0).carve(0.0, 0.0, 6.0, 4.0).block(4.0, 2.5, 4.5, 3.0, 0.8)


def loop_route(step: float, laps: float = 1.15) -> np.ndarray:
    """Poses (M, 3) every ``step`` metres around the ring's centre line, CCW from (0, 0)."""
    corners = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 7.0], [0.0, 7.0], [0.0, 0.0]])
    poses = []
    for a, b in zip(corners[:-1], corners[1:], strict=True):
        length = float(np.linalg.norm(b - a))
        yaw = float(np.arctan2(b[1] - a[1], b[0] - a[0]))
        for s in np.arange(0.0, length, step):
            poses.append([a[0] + (b[0] - a[0]) * s / length, a[1] + (b[1] - a[1]) * s / length, yaw])
    lap = np.array(poses)
    extra = lap[: int(round((laps - 1.0) * len(lap))) + 1]
    return np.concatenate([lap, extra])


def drifting_odometry(true_poses: np.ndarray, scale: float, yaw_per_m: float) -> np.ndarray:
    """Odometry that over-reads distance by ``scale`` and turns ``yaw_per_m`` rad/m too much."""
    odom = [true_poses[0].copy()]
    for a, b in zip(true_poses[:-1], true_poses[1:], strict=True):
        delta = se2.between(a, b)
        dist = float(np.hypot(delta[0], delta[1]))
        delta = np.array([delta[0] * (1 + scale), delta[1] * (1 + scale), delta[2] + yaw_per_m * dist])
        odom.append(se2.compose(odom[-1], delta))
    return np.array(odom)


# --- tests of the synthetic sensor itself ----------------------------------------------------


def test_scan_of_a_box_room_has_walls_at_their_true_distance_and_floor_hits():
    world = room_world()
    points = scan(world, np.array([2.0, 2.0, 0.0]))
    assert points.dtype == np.float32 and points.shape[1] == 3
    floor = points[:, 2] == 0.0
    assert floor.sum() > 300  # the lowest beams reach the floor before the walls
    walls = points[points[:, 2] > 0.9]  # above the 0.8 m box
    ahead = walls[np.abs(walls[:, 1]) < 0.05]
    forward = ahead[ahead[:, 0] > 0]
    assert np.allclose(forward[:, 0], 4.0, atol=0.03)  # wall at x = 6 m, robot at x = 2 m


def test_drifting_odometry_over_reads_distance():
    route = loop_route(0.5)
    odom = drifting_odometry(route, scale=0.02, yaw_per_m=0.0)
    assert abs(odom[10, 0] - 1.02 * route[10, 0]) < 1e-9
