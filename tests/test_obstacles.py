"""navkit.obstacles: obstacles the map lacks stay marked until a ray passes them."""

from __future__ import annotations

import numpy as np

from navkit.obstacles import ObstacleMemory


def _ring(radius: float, count: int = 360) -> np.ndarray:
    angles = np.linspace(-np.pi, np.pi, count, endpoint=False)
    return np.stack([radius * np.cos(angles), radius * np.sin(angles)], axis=1)


def test_a_marked_obstacle_stays_until_a_ray_passes_it():
    memory = ObstacleMemory()
    robot = np.array([0.0, 0.0, 0.0])
    door = np.array([[2.0, y] for y in np.arange(-0.5, 0.51, 0.1)])  # a closed door 2 m ahead
    memory.update(robot, np.vstack([door, _ring(5.0)]), door, max_range=6.0)
    assert len(memory) >= 10
    # the robot turns round and drives away: the door is behind walls 1 m away in its scans, still marked
    away = np.array([-3.0, 0.0, np.pi])
    memory.update(away, _ring(1.0), np.zeros((0, 2)), max_range=6.0)
    assert len(memory) >= 10
    # back in front of the open door: the rays reach 5 m beyond it, the marks go
    memory.update(robot, _ring(5.0), np.zeros((0, 2)), max_range=6.0)
    assert len(memory) == 0


def test_marks_move_with_the_frame():
    memory = ObstacleMemory()
    memory.update(np.zeros(3), np.array([[3.0, 0.0]]), np.array([[3.04, 0.04]]), max_range=6.0)
    memory.transform(np.array([1.0, 0.0, np.pi / 2]))  # the new frame's origin at (1, 0), turned left
    assert np.allclose(memory.points, [[0.05, -2.05]], atol=0.051)


def test_the_baseline_keeps_a_shut_door_behind_a_near_wall_its_filtered_scan_leaves_gaps_in():
    """metric_grid's obstacle layer: a door marked 3 m off, then the robot turned so that a wall
    0.7 m away hides it. Every return of the band (1° apart) shows the wall in the door's direction:
    the door stays. The voxel-filtered scan the baseline tracks with keeps one return in 0.2 m of that
    wall, leaving most 1° directions empty, which read as open: it would forget the door."""
    from baselines.metric_grid.config import MetricGridConfig
    from baselines.metric_grid.obstacles import UnmappedObstacles
    from baselines.metric_grid.scan2d import voxel_filter_2d

    class MapExplainsEveryReturn:
        def sample(self, xy: np.ndarray) -> tuple[np.ndarray, ...]:
            return (np.zeros(len(xy)),)

    robot = np.zeros(3)
    angles = np.radians(np.arange(-60.0, 60.0, 1.0))
    wall = np.stack([np.full_like(angles, 0.7), 0.7 * np.tan(angles)], axis=1)  # a wall across, 0.7 m ahead
    door = np.array([[3.0, y] for y in np.arange(-0.5, 0.51, 0.1)])  # behind it
    for rays, kept in ((wall, True), (None, False)):
        layer = UnmappedObstacles(MetricGridConfig().planning)
        layer.memory.mark(door)
        marked = len(layer.points)
        filtered = voxel_filter_2d(wall, 0.2)
        assert len(filtered) < len(wall) / 4
        layer.update(robot, filtered, MapExplainsEveryReturn(), rays=rays)  # type: ignore[arg-type]
        assert (len(layer.points) == marked) is kept
