"""Global occupancy grid of the metric baseline: ray tracing, map_server files, map quality."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml
from test_metric_synthetic import room_world, scan

from baselines.metric_grid.occupancy import (
    GridMap,
    OccupancyGrid,
    map_quality,
    wall_mask,
)
from baselines.metric_grid.scan2d import free_endpoints, free_ranges, keyframe_scan
from navkit.raster import FREE, OCCUPIED, UNKNOWN

ROOM_POSES = np.array([[1.0, 1.0, 0.3], [3.0, 2.0, 1.0], [5.0, 1.0, 2.5], [2.0, 3.2, -1.0]])


@pytest.fixture(scope="module")
def room_map():
    world = room_world()
    scans = [keyframe_scan(scan(world, pose)) for pose in ROOM_POSES]
    return world, OccupancyGrid.from_keyframes(ROOM_POSES, scans)


def _values_at(grid_map: GridMap, xy) -> np.ndarray:
    cells = grid_map.cell_of(xy)
    return grid_map.cells[cells[:, 0], cells[:, 1]]


def test_a_room_traced_from_four_keyframes_has_its_walls_occupied_and_interior_free(room_map):
    world, grid = room_map
    grid_map = grid.to_map()
    recall, precision = map_quality(
        grid_map.cells == OCCUPIED,
        grid_map.origin,
        grid_map.resolution,
        wall_mask(world.free_mask),
        world.origin,
        world.resolution,
    )
    assert recall >= 0.98 and precision >= 0.98
    # the interior away from the box and its shadow is free, every cell of it
    ys, xs = np.mgrid[0.25:3.76:0.1, 0.25:3.5:0.1]
    assert np.all(_values_at(grid_map, np.c_[xs.ravel(), ys.ravel()]) == FREE)
    # the 0.8 m box (x 4-4.5, y 2.5-3) is an obstacle: its faces that were seen are occupied
    occupied = grid_map.centres(grid_map.cells == OCCUPIED)
    for face_point in ([4.0, 2.75], [4.25, 2.5]):
        assert np.min(np.linalg.norm(occupied - face_point, axis=1)) < 0.15
    # beyond the walls nothing was seen
    beyond = np.array([[-0.5, 2.0], [6.5, 2.0]])
    assert np.all(_values_at(grid.to_map(crop=False), beyond) == UNKNOWN)


@pytest.mark.parametrize("image_format", ["png", "pgm"])
def test_map_server_round_trip_keeps_origin_and_cells(room_map, tmp_path, image_format):
    _, grid = room_map
    grid_map = grid.to_map()
    yaml_path = grid_map.save(tmp_path / "map.yaml", image_format=image_format)
    meta = yaml.safe_load(yaml_path.read_text())
    assert meta["image"] == f"map.{image_format}" and meta["mode"] == "trinary" and meta["negate"] == 0
    assert meta["occupied_thresh"] == 0.65 and meta["free_thresh"] == 0.196
    assert meta["origin"] == [*grid_map.origin.tolist(), 0.0]
    loaded = GridMap.load(yaml_path)
    assert np.array_equal(loaded.cells, grid_map.cells)
    assert np.array_equal(loaded.origin, grid_map.origin)
    assert loaded.resolution == grid_map.resolution
    assert loaded.nbytes == grid_map.nbytes == grid_map.cells.nbytes + 16 + 8
    # row 0 of the image is the largest y; occupied black, free 254, unknown 205
    image = cv2.imread(str(tmp_path / f"map.{image_format}"), cv2.IMREAD_UNCHANGED)
    assert image.shape == grid_map.cells.shape
    lut = {UNKNOWN: 205, FREE: 254, OCCUPIED: 0}
    assert np.array_equal(image[0], np.vectorize(lut.get)(grid_map.cells[-1]))


def test_an_ascii_pgm_with_comments_and_other_thresholds_loads(tmp_path):
    (tmp_path / "m.pgm").write_text("P2\n# a comment\n3 2\n255\n0 254 128\n254 254 10\n")
    (tmp_path / "m.yaml").write_text(
        "image: m.pgm\nresolution: 0.05\norigin: [1.0, -2.0, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.25\n"
    )
    loaded = GridMap.load(tmp_path / "m.yaml")
    # image row 0 (top) is the largest y: it becomes the last row
    assert loaded.cells.tolist() == [[FREE, FREE, OCCUPIED], [OCCUPIED, FREE, UNKNOWN]]
    assert loaded.origin.tolist() == [1.0, -2.0] and loaded.resolution == 0.05


def test_bounds_grow_without_moving_what_is_mapped(room_map):
    world, grid = room_map
    before = grid.to_map(crop=False)
    far = OccupancyGrid.from_keyframes(ROOM_POSES, [keyframe_scan(scan(world, p)) for p in ROOM_POSES])
    far.integrate(np.array([60.0, -40.0, 0.0]), np.array([[1.0, 0.0]]), free_ranges(np.array([[1.0, 0.0]])))
    after = far.to_map(crop=False)
    assert after.cells.shape[0] > before.cells.shape[0] and after.cells.shape[1] > before.cells.shape[1]
    ys, xs = np.mgrid[-0.95:4.96:0.1, -0.95:6.96:0.1]
    xy = np.c_[xs.ravel(), ys.ravel()]
    assert np.array_equal(_values_at(before, xy), _values_at(after, xy))
    assert _values_at(after, np.array([[61.05, -39.95]]))[0] == OCCUPIED
    assert far.nbytes == far.logodds.nbytes + 16


def test_free_ranges_keep_the_farthest_return_per_degree():
    points = np.array([[2.0, 0.0, 0.0], [5.0, 0.0, 1.0], [0.0, 3.0, 0.5], [-1.0, -0.0, 0.0]])
    ranges = free_ranges(points)
    assert ranges.dtype == np.float16 and ranges.shape == (360,)
    assert ranges[0] == 5.0 and ranges[90] == 3.0 and ranges[180] == 1.0
    assert np.count_nonzero(ranges) == 3
    assert np.allclose(free_endpoints(ranges), [[5.0, 0.0], [0.0, 3.0], [-1.0, 0.0]], atol=1e-6)


def test_map_quality_counts_walls_found_and_cells_that_are_walls():
    gt_free = np.zeros((40, 40), bool)
    gt_free[5:35, 5:35] = True  # 0.05 m cells: a 1.5 m square room
    walls = wall_mask(gt_free)
    assert walls.sum() == 4 * 31  # the ring of cells around the free square
    origin = np.zeros(2)
    exact = walls.copy()
    assert map_quality(exact, origin, 0.05, walls, origin, 0.05) == (1.0, 1.0)
    shifted = np.roll(walls, (8, 8), axis=(0, 1))  # 0.4 m up and right: most cells off the walls
    recall, precision = map_quality(shifted, origin, 0.05, walls, origin, 0.05)
    assert recall < 0.7 and precision < 0.7
    half = walls.copy()
    half[:, :20] = False  # only the right half mapped: precise but half the walls
    recall, precision = map_quality(half, origin, 0.05, walls, origin, 0.05)
    assert precision == 1.0 and 0.4 < recall < 0.7
