"""navkit.obstacles: obstacles the map lacks stay marked until a ray passes them."""

from __future__ import annotations

import numpy as np

from navkit.obstacles import GUARD_HOLD, ObstacleMemory, too_near_ahead


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


def test_a_mark_held_stays_through_rays_that_pass_it_until_its_hold_runs_out():
    """The scan guard's marks (a table's corner between two 1-degree rays, cleared by the next scan
    and found too near again at every tick) are held ``GUARD_HOLD`` updates, then cleared as any."""
    memory = ObstacleMemory()
    corner = np.array([[2.0, 0.0]])
    memory.mark(corner, GUARD_HOLD)
    memory.mark(np.array([[0.0, 2.0]]))  # an ordinary mark: gone at the first scan that passes it
    robot = np.zeros(3)
    for _ in range(GUARD_HOLD):
        memory.update(robot, _ring(5.0), np.zeros((0, 2)), max_range=6.0)
        assert memory.marked(corner).all() and len(memory) == 1
        assert memory.holding or _ == GUARD_HOLD - 1  # its last held update spent
    memory.update(robot, _ring(5.0), np.zeros((0, 2)), max_range=6.0)
    assert len(memory) == 0 and not memory.holding
    memory.mark(corner, 3)
    memory.transform(np.array([1.0, 0.0, 0.0]))
    assert memory.marked(np.array([[1.0, 0.0], [0.0, 0.0]])).tolist() == [True, False]  # held in the new frame


def test_the_scan_guard_finds_returns_the_way_ahead_comes_too_near_to_not_those_it_leaves():
    """The way ahead (robot at the origin, path east then north) passes a table's corner at 0.25 m:
    found at a clearance of 0.32; a return beside the robot that the path leads away from is not
    (the robot already stands in its reach), nor one the path keeps 0.5 m from."""
    path = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]])
    corner, beside, far = [1.0, 0.25], [-0.1, 0.28], [2.5, 1.0]
    found = too_near_ahead(path[1:], path[0], np.array([corner, beside, far]), 0.32)
    assert np.allclose(found, [corner])
    assert len(too_near_ahead(path[1:], path[0], np.array([far]), 0.32)) == 0
    assert len(too_near_ahead(path[1:], path[0], np.zeros((0, 2)), 0.32)) == 0
