"""Location grids from synthetic lidar clouds of known worlds (no simulator).

``RasterWorld`` and ``lidar_scan`` below are a small ray caster: a 2D raster of column heights
(walls extruded to 2.6 m, boxes of any height) over a flat floor, an optional flat ceiling, and
the benchmark's lidar (16 channels over [-15°, 15°], 1° azimuth steps, 15 m range, mounted at
0.6 m). ``tests/test_scan_matching.py`` reuses them.
"""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from navkit.geometry import between, inverse, transform_points
from navkit.raster import FREE, OCCUPIED, UNKNOWN
from navkit.scan import obstacle_points
from navkit.scan_grid import GridConfig, grid_frame, grid_from_points
from navtopo.local_grid import (
    CroppedGrid,
    decode_png,
    encode_png,
    known_iou,
    known_overlap,
    overlap,
    warp,
    warp_window,
    warped_bounds,
)

WALL_HEIGHT = 2.6
MOUNT_HEIGHT = 0.6
MAX_RANGE = 15.0


class RasterWorld:
    """Column heights on a 0.05 m raster: 0 is open floor, h > 0 a solid column of height h.

    ``heights[row, col]`` covers x in [x0 + col * res, ...), y in [y0 + row * res, ...).
    """

    def __init__(self, x0: float, y0: float, width: float, depth: float, res: float = 0.05):
        self.x0, self.y0, self.res = x0, y0, res
        self.heights = np.zeros((int(round(depth / res)), int(round(width / res))))

    def add_box(self, xmin, xmax, ymin, ymax, height=WALL_HEIGHT):
        c0, c1 = (int(round((v - self.x0) / self.res)) for v in (xmin, xmax))
        r0, r1 = (int(round((v - self.y0) / self.res)) for v in (ymin, ymax))
        block = self.heights[r0:r1, c0:c1]
        np.maximum(block, height, out=block)
        return self

    def add_room_walls(self, xmin, xmax, ymin, ymax, thickness=0.2):
        """Walls whose inner faces are the given rectangle."""
        t = thickness
        self.add_box(xmin - t, xmax + t, ymin - t, ymin)
        self.add_box(xmin - t, xmax + t, ymax, ymax + t)
        self.add_box(xmin - t, xmin, ymin, ymax)
        self.add_box(xmax, xmax + t, ymin, ymax)
        return self

    def height_at(self, x, y):
        cols = np.floor((x - self.x0) / self.res).astype(np.int64)
        rows = np.floor((y - self.y0) / self.res).astype(np.int64)
        inside = (rows >= 0) & (cols >= 0)
        inside &= (rows < self.heights.shape[0]) & (cols < self.heights.shape[1])
        out = np.zeros(np.shape(x))
        out[inside] = self.heights[rows[inside], cols[inside]]
        return out


def lidar_scan(world, robot_pose, ceiling=None, drop_azimuth_deg=None, step=0.02):
    """Returns (N, 3) float32 in the robot frame of a robot at ``robot_pose`` in ``world``.

    ceiling: height of a flat ceiling, or None for open sky. drop_azimuth_deg: (lo, hi) robot-frame
    azimuths (degrees) that give no return at all (an absorbing surface, a sensor dropout).
    """
    elevations = np.radians(np.linspace(-15.0, 15.0, 16))
    azimuths = np.radians(np.arange(360.0))
    ranges = np.arange(step, MAX_RANGE + step, step)  # horizontal distance along a beam
    world_az = robot_pose[2] + azimuths
    xs = robot_pose[0] + np.cos(world_az)[:, None] * ranges
    ys = robot_pose[1] + np.sin(world_az)[:, None] * ranges
    column = world.height_at(xs, ys)  # (azimuths, ranges)
    points = []
    for elevation in elevations:
        slope = np.tan(elevation)
        z = MOUNT_HEIGHT + slope * ranges
        blocked = z[None, :] <= column
        first = np.where(blocked.any(axis=1), blocked.argmax(axis=1), ranges.size - 1)
        r_hit = np.where(blocked.any(axis=1), ranges[first], np.inf)
        if slope < 0:
            r_hit = np.minimum(r_hit, MOUNT_HEIGHT / -slope)
        elif slope > 0 and ceiling is not None:
            r_hit = np.minimum(r_hit, (ceiling - MOUNT_HEIGHT) / slope)
        valid = r_hit <= MAX_RANGE * np.cos(elevation)
        r = r_hit[valid]
        a = azimuths[valid]
        points.append(np.stack([r * np.cos(a), r * np.sin(a), MOUNT_HEIGHT + slope * r], axis=1))
    cloud = np.concatenate(points)
    if drop_azimuth_deg is not None:
        az = np.degrees(np.arctan2(cloud[:, 1], cloud[:, 0])) % 360.0
        cloud = cloud[(az < drop_azimuth_deg[0]) | (az > drop_azimuth_deg[1])]
    return cloud.astype(np.float32)


# A hall 16 m x 12 m (inner faces x in [0, 16], y in [0, 12]), large enough for the upper
# beams to reach the ceiling before a wall, with a 0.3 m box and a 1.0 m box.
ROOM = (0.0, 16.0, 0.0, 12.0)
LOW_BOX = (8.0, 8.6, 3.0, 3.6, 0.3)
HIGH_BOX = (3.0, 3.5, 8.5, 9.0, 1.0)
ROBOT = np.array([6.0, 5.0, 0.4])


def box_room():
    world = RasterWorld(-1.0, -1.0, 18.0, 14.0).add_room_walls(*ROOM)
    world.add_box(*LOW_BOX)
    world.add_box(*HIGH_BOX)
    return world


def world_to_grid_cells(world_xy, robot_pose, config):
    """Cells of the robot-centred grid under world points (N, 2)."""
    return grid_frame(config).to_cell(transform_points(inverse(robot_pose), world_xy))


def cells_of_rect(xmin, xmax, ymin, ymax, robot_pose, config, step=0.05):
    xs, ys = np.meshgrid(np.arange(xmin, xmax, step), np.arange(ymin, ymax, step))
    return world_to_grid_cells(np.stack([xs.ravel(), ys.ravel()], 1), robot_pose, config)


@pytest.fixture(scope="module")
def room_grid():
    config = GridConfig()
    cloud = lidar_scan(box_room(), ROBOT, ceiling=WALL_HEIGHT)
    return config, cloud, grid_from_points(cloud, config)


def test_config_defaults_and_validation():
    config = GridConfig()
    assert config.size == 300 and config.resolution == 0.1 and config.radius == 15.0
    with pytest.raises(ValidationError):
        GridConfig(radius_m=3.0)
    with pytest.raises(ValidationError):
        GridConfig(floor_height=1.0, ceiling_height=0.5)


def test_obstacle_band_keeps_a_low_box_and_drops_floor_and_ceiling():
    config = GridConfig()
    points = np.array(
        [[1, 0, 0.0], [1, 0, 0.05], [1, 0, 0.3], [1, 0, 1.2], [1, 0, 2.0], [1, 0, 2.6]],
        dtype=np.float32,
    )
    kept = obstacle_points(points, config)
    assert kept.dtype == np.float32
    np.testing.assert_allclose(kept[:, 2], [0.3, 1.2])


def test_cell_conversions_round_trip():
    config = GridConfig()
    xy = np.array([[0.05, 0.05], [-0.05, -0.05], [2.04, -7.31]])
    cells = grid_frame(config).to_cell(xy)
    assert cells[0].tolist() == [150, 150] and cells[1].tolist() == [149, 149]
    assert cells[2].tolist() == [150 - 74, 150 + 20]  # row from y, col from x
    np.testing.assert_allclose(grid_frame(config).to_world(cells), [[0.05, 0.05], [-0.05, -0.05], [2.05, -7.35]])
    # the location grid's arithmetic exactly: floor(x / res) + half, centres (c - half + 0.5) * res
    points = np.random.default_rng(0).uniform(-15.0, 15.0, (1000, 2))
    half = config.size // 2
    expected = np.floor(points[:, ::-1] / config.resolution).astype(np.int64) + half
    assert np.array_equal(grid_frame(config).to_cell(points), expected)
    assert np.array_equal(grid_frame(config).to_world(expected), (expected[:, ::-1] - half + 0.5) * config.resolution)


def test_box_room_grid_has_free_interior_and_occupied_walls(room_grid):
    config, _, grid = room_grid
    assert grid.dtype == np.uint8 and grid.shape == (300, 300)
    assert set(np.unique(grid)) <= {UNKNOWN, FREE, OCCUPIED}

    # every wall face is occupied (within one cell: walls are dotted at 1° steps)
    x0, x1, y0, y1 = ROOM
    s = np.linspace(0.05, 0.95, 60)
    faces = np.concatenate(
        [
            np.stack([x0 + (x1 - x0) * s, np.full_like(s, y0 - 0.05)], 1),
            np.stack([x0 + (x1 - x0) * s, np.full_like(s, y1 + 0.05)], 1),
            np.stack([np.full_like(s, x0 - 0.05), y0 + (y1 - y0) * s], 1),
            np.stack([np.full_like(s, x1 + 0.05), y0 + (y1 - y0) * s], 1),
        ]
    )
    occupied = np.pad(grid == OCCUPIED, 1)
    near_wall = np.zeros_like(occupied)
    for dr in (-1, 0, 1):
        for dc in (-1, 0, 1):
            near_wall |= np.roll(occupied, (dr, dc), axis=(0, 1))
    rows, cols = world_to_grid_cells(faces, ROBOT, config).T
    assert near_wall[rows + 1, cols + 1].mean() > 0.97

    # the interior is free, except the boxes and what they hide from the robot
    interior = cells_of_rect(x0 + 0.15, x1 - 0.15, y0 + 0.15, y1 - 0.15, ROBOT, config)
    interior_xy = transform_points(ROBOT, grid_frame(config).to_world(interior))
    hidden = np.zeros(len(interior), dtype=bool)
    for bx0, bx1, by0, by1, _ in (LOW_BOX, HIGH_BOX):
        for t in np.linspace(0.0, 1.0, 60):  # does the segment robot -> cell cross the box?
            p = ROBOT[:2] + t * (interior_xy - ROBOT[:2])
            in_box = (p[:, 0] > bx0 - 0.15) & (p[:, 0] < bx1 + 0.15)
            in_box &= (p[:, 1] > by0 - 0.15) & (p[:, 1] < by1 + 0.15)
            hidden |= in_box
    visible = interior[~hidden]
    assert len(visible) > 0.8 * len(interior)
    assert np.mean(grid[visible[:, 0], visible[:, 1]] == FREE) > 0.995

    # nothing outside the walls is free
    outside = np.ones(grid.shape, dtype=bool)
    room_cells = cells_of_rect(x0 - 0.35, x1 + 0.35, y0 - 0.35, y1 + 0.35, ROBOT, config)
    outside[room_cells[:, 0], room_cells[:, 1]] = False
    assert np.count_nonzero(outside & (grid == FREE)) == 0
    assert np.count_nonzero(outside & (grid == OCCUPIED)) == 0


def test_low_box_is_an_obstacle_and_the_ceiling_is_not(room_grid):
    config, cloud, grid = room_grid
    assert np.any(np.abs(cloud[:, 2] - WALL_HEIGHT) < 1e-3), "the scan must see the ceiling"
    bx0, bx1, by0, by1, _ = LOW_BOX
    box_cells = cells_of_rect(bx0, bx1, by0, by1, ROBOT, config)
    assert np.count_nonzero(grid[box_cells[:, 0], box_cells[:, 1]] == OCCUPIED) >= 5
    # no occupied cell in the open interior: the ceiling above it is not an obstacle
    x0, x1, y0, y1 = ROOM
    inner = cells_of_rect(x0 + 0.3, x1 - 0.3, y0 + 0.3, y1 - 0.3, ROBOT, config)
    inner_xy = transform_points(ROBOT, grid_frame(config).to_world(inner))
    off_boxes = np.ones(len(inner), dtype=bool)
    for bx0, bx1, by0, by1, _ in (LOW_BOX, HIGH_BOX):
        off_boxes &= ~(
            (inner_xy[:, 0] > bx0 - 0.2)
            & (inner_xy[:, 0] < bx1 + 0.2)
            & (inner_xy[:, 1] > by0 - 0.2)
            & (inner_xy[:, 1] < by1 + 0.2)
        )
    cells = inner[off_boxes]
    assert np.count_nonzero(grid[cells[:, 0], cells[:, 1]] == OCCUPIED) == 0


def test_free_space_stops_at_the_first_obstacle(room_grid):
    """Upper beams pass over the 0.3 m box and hit the wall, yet the floor behind the box
    stays unknown: tracing stops at the first occupied cell."""
    config, _, grid = room_grid
    bx0, bx1, by0, by1, _ = LOW_BOX
    centre = np.array([(bx0 + bx1) / 2, (by0 + by1) / 2])
    direction = (centre - ROBOT[:2]) / np.linalg.norm(centre - ROBOT[:2])
    behind = centre + np.outer([0.6, 0.9, 1.2], direction)
    rows, cols = world_to_grid_cells(behind, ROBOT, config).T
    assert np.all(grid[rows, cols] == UNKNOWN)


def test_directions_without_returns_stay_unknown():
    config = GridConfig()
    world = box_room()
    cloud = lidar_scan(world, ROBOT, ceiling=None, drop_azimuth_deg=(160.0, 200.0))
    grid = grid_from_points(cloud, config)
    # straight behind the robot (robot-frame azimuth 180°): no return, no free cell past 1 m
    behind = np.stack([-np.arange(1.0, 2.5, 0.1), np.zeros(15)], axis=1)
    rows, cols = grid_frame(config).to_cell(behind).T
    assert np.all(grid[rows, cols] == UNKNOWN)
    # while in front everything up to the wall is free
    ahead = np.stack([np.arange(0.5, 4.0, 0.1), np.zeros(35)], axis=1)
    rows, cols = grid_frame(config).to_cell(ahead).T
    assert np.all(grid[rows, cols] == FREE)


def test_warp_moves_a_cell_to_where_the_other_frame_sees_it():
    """warp(grid, T) is the grid seen from frame T: a point p of the grid's frame lands at
    transform_points(inverse(T), p) — the convention of navkit.geometry."""
    config = GridConfig()
    rng = np.random.default_rng(3)
    for _ in range(50):
        grid = np.zeros((config.size, config.size), dtype=np.uint8)
        cell = grid_frame(config).to_cell(rng.uniform(-5.0, 5.0, (1, 2)))
        grid[cell[0, 0], cell[0, 1]] = OCCUPIED
        pose = np.array([rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-np.pi, np.pi)])
        # a single cell may vanish under nearest-neighbour rotation: test a 3x3 patch's centre
        grid[cell[0, 0] - 1 : cell[0, 0] + 2, cell[0, 1] - 1 : cell[0, 1] + 2] = OCCUPIED
        expected = transform_points(inverse(pose), grid_frame(config).to_world(cell))[0]
        moved = grid_frame(config).to_world(np.argwhere(warp(grid, pose, config) == OCCUPIED))
        assert np.linalg.norm(moved.mean(axis=0) - expected) < 0.05
    # a pure translation by whole cells is exact
    grid = np.zeros((config.size, config.size), dtype=np.uint8)
    grid[100, 200] = OCCUPIED
    shifted = warp(grid, np.array([1.0, -0.5, 0.0]), config)
    assert np.argwhere(shifted == OCCUPIED).tolist() == [[105, 190]]


def test_a_window_of_a_warp_is_that_part_of_the_whole_warp(room_grid):
    """warp_window reads the cropped cells straight into a window of the output: the same cells as
    warping the whole grid and cutting the window out (but for a rare nearest-neighbour tie that
    the shifted fixed-point map rounds the other way), and warped_bounds holds every known one."""
    config, _, grid = room_grid
    cropped = CroppedGrid.from_grid(grid)
    rng = np.random.default_rng(5)
    size = 500  # a union grid's canvas
    for _ in range(30):
        pose = np.array([rng.uniform(-6, 6), rng.uniform(-6, 6), rng.uniform(-np.pi, np.pi)])
        whole = warp(grid, pose, config, size=size)
        r0, r1, c0, c1 = warped_bounds(cropped, pose, config.resolution, size)
        known = np.argwhere(whole != UNKNOWN)
        assert len(known) > 1000
        assert known[:, 0].min() >= r0 and known[:, 0].max() < r1 and known[:, 1].min() >= c0 and known[:, 1].max() < c1
        window = warp_window(cropped, pose, config.resolution, size, (r0, r1, c0, c1))
        assert np.count_nonzero(window != whole[r0:r1, c0:c1]) <= 3
        # any window, even one reaching past the known cells
        part = (r0 + 7, r1 - 11, c0 - 5 if c0 >= 5 else c0, c1)
        assert (
            np.count_nonzero(
                warp_window(cropped, pose, config.resolution, size, part) != whole[part[0] : part[1], part[2] : part[3]]
            )
            <= 3
        )
    empty = CroppedGrid.from_grid(np.zeros_like(grid))
    assert warped_bounds(empty, np.zeros(3), config.resolution, size) == (0, 0, 0, 0)
    assert (warp_window(empty, np.zeros(3), config.resolution, size, (0, 4, 0, 6)) == UNKNOWN).all()


def test_grids_of_two_poses_line_up_with_the_between_pose():
    config = GridConfig()
    world = box_room()
    pose_a, pose_b = ROBOT, np.array([8.2, 6.5, -1.1])
    grid_a = grid_from_points(lidar_scan(world, pose_a, ceiling=WALL_HEIGHT), config)
    grid_b = grid_from_points(lidar_scan(world, pose_b, ceiling=WALL_HEIGHT), config)
    a_in_b = warp(grid_a, between(pose_a, pose_b), config)
    right = known_iou(a_in_b, grid_b)
    wrong = known_iou(warp(grid_a, between(pose_b, pose_a), config), grid_b)
    assert right > 0.85 and wrong < 0.6
    # overlap(reference, query, pose of query in reference): shared known area over the smaller one
    assert overlap(grid_a, grid_b, between(pose_a, pose_b), config) == pytest.approx(
        known_overlap(grid_a, warp(grid_b, between(pose_b, pose_a), config)), abs=1e-9
    )
    assert overlap(grid_a, grid_b, between(pose_a, pose_b), config) > 0.9
    assert overlap(grid_a, grid_b, between(pose_b, pose_a), config) < 0.8  # the walls, not the area, tell poses apart
    assert known_iou(grid_a, np.zeros_like(grid_a)) == 0.0 and known_overlap(grid_a, np.zeros_like(grid_a)) == 0.0
    # a grid that sees more (here: all of a room the other sees half of) still overlaps fully
    half = grid_a.copy()
    half[:, : config.size // 2] = 0
    assert known_overlap(grid_a, half) == pytest.approx(1.0) and known_iou(grid_a, half) < 0.7


def test_compact_forms_round_trip_and_are_small(room_grid):
    _, _, grid = room_grid
    cropped = CroppedGrid.from_grid(grid)
    np.testing.assert_array_equal(cropped.to_grid(), grid)
    assert cropped.nbytes < 40_000  # the hall (turned 23°) is a part of the 30 m square
    data = encode_png(grid)
    assert len(data) < 5_000
    np.testing.assert_array_equal(decode_png(data), grid)
    with pytest.raises(ValueError):
        decode_png(b"not a png")
    empty = CroppedGrid.from_grid(np.zeros((300, 300), dtype=np.uint8))
    assert empty.cells.size == 0 and not empty.to_grid().any()
