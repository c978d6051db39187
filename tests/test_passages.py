"""The passage check both systems run (``navkit.passages``) against a door drawn off where it is:
the path is moved to the middle the scan shows, or the passage is shut when the robot does not fit;
and the metric baseline finds the narrow part of its path where its map leaves less than the first
level's clearance and a cell, a door the map draws a cell too wide included."""

from __future__ import annotations

import numpy as np
import pytest

from baselines.metric_grid.config import PlanningConfig
from baselines.metric_grid.occupancy import GridMap
from baselines.metric_grid.planning import GridPlanner
from navkit.follower import FollowerConfig, PathFollower
from navkit.geometry import distance_to_polyline
from navkit.passages import PassageCheck, PassageConfig
from navkit.raster import FREE, OCCUPIED

RADIUS = 0.3


def door_returns(centre_x: float, width: float, y: float = 0.0) -> np.ndarray:
    """Returns along a wall at ``y`` (x in [-3, 3]) every 2 cm, with a door of ``width`` centred at ``centre_x``."""
    x = np.arange(-3.0, 3.0, 0.02)
    x = x[np.abs(x - centre_x) >= width / 2]
    return np.stack([x, np.full_like(x, y)], axis=1)


def straight_path() -> np.ndarray:
    """From 2 m below the wall straight up through x = 0 to 2 m above it."""
    return np.array([[0.0, -2.0], [0.0, 2.0]])


def roomy_off_door(xy: np.ndarray) -> np.ndarray:
    """The map's verdict: narrow within 0.3 m of the wall (the door), roomy elsewhere."""
    return np.abs(xy[:, 1]) > 0.3


@pytest.mark.parametrize("offset", [-0.15, 0.1])
def test_a_door_off_the_path_moves_the_path_to_its_middle(offset):
    # a 0.85 m door (0.125 m a side for the robot) whose middle the scan shows `offset` off the path
    check = PassageCheck(PassageConfig(), RADIUS)
    path = straight_path()
    check.set_path(path, roomy_off_door)
    assert check.passage is not None and check.passage.entry_arc < 2.0 < check.passage.exit_arc
    assert check.due(stamp=0.0, progress=0.5)
    verdict = check.check(0.0, path, 0.5, door_returns(offset, 0.85), np.array([0.0, -1.5]))
    assert verdict.shut is None and verdict.path is not None
    # the moved path clears both jambs by the radius and the margin
    assert distance_to_polyline(door_returns(offset, 0.85), verdict.path).min() >= RADIUS + PassageConfig().margin - 1e-6
    assert not check.due(stamp=0.1, progress=0.6)  # not again before the period


def test_the_follower_drives_the_passage_slowly_also_once_it_is_moved():
    # ``follow`` and ``step`` hand the follower the passage's stretch (``slow_between``): slow
    # through the door on the planned path and on the path the scan moved, full speed before it
    check = PassageCheck(PassageConfig(), RADIUS)
    follower = PathFollower(FollowerConfig(passage_speed=0.3))
    check.follow(follower, straight_path(), roomy_off_door)
    assert check.passage is not None
    assert follower.command(np.array([0.0, -2.0, np.pi / 2])).linear == pytest.approx(1.0)
    pose = np.array([0.0, -1.0, np.pi / 2])
    verdict = check.step(follower, 0.0, pose, lambda segment, reach: door_returns(0.1, 0.85))
    assert verdict.path is not None and np.array_equal(follower.path, verdict.path)
    speeds = [follower.command(np.array([0.1, y, np.pi / 2])).linear for y in np.linspace(-0.2, 0.2, 5)]  # in the door
    assert 0 < max(speeds) <= follower.config.passage_speed + 1e-9
    assert follower.command(np.array([0.1, 0.9, np.pi / 2])).linear > 0.9  # past it
    # a path moved with the robot in the passage already: slow from where the robot is
    check.follow(follower, straight_path(), roomy_off_door)
    pose = np.array([0.0, -0.2, np.pi / 2])
    verdict = check.step(follower, 1.0, pose, lambda segment, reach: door_returns(0.1, 0.85))
    assert verdict.path is not None
    assert 0 < follower.command(pose).linear <= follower.config.passage_speed + 1e-9


def test_a_door_narrower_than_the_robot_is_shut_near_it():
    check = PassageCheck(PassageConfig(), RADIUS)
    path = straight_path()
    check.set_path(path, roomy_off_door)
    returns = door_returns(0.0, 0.55)
    verdict = check.check(0.0, path, 1.0, returns, np.array([0.0, -1.0]))
    assert verdict.path is None and verdict.shut is not None and len(verdict.shut)
    assert np.abs(verdict.shut[:, 0]).max() < 1.0  # the jambs' returns, not the whole wall


def test_in_the_door_already_a_path_off_its_middle_is_moved_though_the_margin_is_not_reached():
    """A path re-planned at the door's mouth, straight through it 0.1 m off the middle, the door
    narrower than the robot and the margin: the robot is past the passage's entry (no shutting it
    from there); the check turns the way toward the middle, never to less room than the path leaves."""
    check = PassageCheck(PassageConfig(), RADIUS)
    path = np.array([[0.1, -0.6], [0.4, 2.0]])
    check.set_path(path, roomy_off_door)
    assert check.passage is not None and check.passage.entry_arc < 0.1
    returns = door_returns(0.0, 0.66)  # 0.03 m a side in its middle: less than the margin wherever the path goes
    before = distance_to_polyline(returns, path).min()
    robot = path[0] + 0.1 * (path[1] - path[0]) / np.hypot(*(path[1] - path[0]))
    verdict = check.check(0.0, path, 0.1, returns, robot)
    assert verdict.shut is None and verdict.path is not None
    assert distance_to_polyline(returns, verdict.path).min() > before + 0.05


def test_a_door_the_robot_fits_through_is_not_shut_for_a_way_that_bends_round_its_jamb_after_it():
    """The lead after the passage is not moved by the fit: a return beside it (a jamb the way bends
    round past the door) says nothing against the door."""
    check = PassageCheck(PassageConfig(), RADIUS)
    path = np.array([[0.0, -2.0], [0.0, 0.9], [2.0, 1.1]])  # through the door, then hard right
    check.set_path(path, roomy_off_door)
    assert check.passage is not None
    returns = np.vstack([door_returns(0.0, 0.95), [[0.2, 1.15]]])  # a corner 0.23 m from the way past the door
    verdict = check.check(0.0, path, 1.0, returns, np.array([0.0, -1.0]))
    assert verdict.shut is None


def test_a_path_with_room_to_spare_has_no_passage():
    check = PassageCheck(PassageConfig(), RADIUS)
    check.set_path(straight_path(), lambda xy: np.ones(len(xy), bool))
    assert check.passage is None and not check.due(0.0, 0.0)


@pytest.mark.parametrize("door_m, narrow", [(0.95, True), (1.6, False)])
def test_the_baseline_checks_a_door_its_map_draws_near_the_margin(door_m, narrow):
    # a wall across a 6 x 6 m map at y = 0 with a door at x = 0; 0.1 m cells
    cells = np.full((60, 60), FREE, np.uint8)
    cells[30, :] = OCCUPIED
    half = int(round(door_m / 0.1 / 2))
    cells[30, 30 - half : 30 + half] = FREE
    planner = GridPlanner(GridMap(cells, np.array([-3.0, -3.0]), 0.1), RADIUS, PlanningConfig())
    planned = planner.plan([0.05, -2.0], [0.05, 2.0], np.zeros((0, 2)))
    assert planned is not None
    check = PassageCheck(PassageConfig(), RADIUS)
    check.set_path(planned.points, planner.roomy_at)
    assert (check.passage is not None) == narrow


def thick_door(width: float, thickness: float = 0.2) -> np.ndarray:
    """Returns of a wall ``thickness`` thick across y = 0 (x in [-3, 3]) with a door of ``width`` at
    x = 0: both faces of the wall and the jambs' faces, every 2 cm."""
    x = np.arange(-3.0, 3.0, 0.02)
    x = x[np.abs(x) >= width / 2]
    y = np.arange(-thickness / 2, thickness / 2 + 1e-9, 0.02)
    faces = [np.stack([x, np.full_like(x, side * thickness / 2)], axis=1) for side in (-1, 1)]
    jambs = [np.stack([np.full_like(y, side * width / 2), y], axis=1) for side in (-1, 1)]
    return np.vstack(faces + jambs)


@pytest.mark.parametrize("mouth_margin", [None, 0.0])
def test_at_a_doors_mouth_the_door_is_shut_by_the_mouth_margin(mouth_margin):
    """The robot at the mouth of a 0.8 m door (the passage's entry a radius ahead, where the fit
    cannot move it), 0.063 m off its middle: the way in passes the jamb's corner 0.337 m off, under
    the radius and the 0.04 m margin. Judged by the margin the door is shut (the robot then plans
    the same way from the same spot, and shuts it again); by ``mouth_margin`` 0, what the scan
    guard asks, it is followed. A door the robot does not fit through is shut either way."""
    config = PassageConfig(mouth_margin=mouth_margin)
    path = np.array([[0.063, -0.4], [0.063, 2.0]])
    narrow = lambda xy: np.abs(xy[:, 1] - 0.3) > 0.16  # noqa: E731 - the map's verdict: the entry at the wall's face
    check = PassageCheck(config, RADIUS)
    check.set_path(path, narrow)
    assert check.passage is not None and check.passage.entry_arc == pytest.approx(0.3)
    verdict = check.check(0.0, path, 0.0, thick_door(0.8), path[0])
    assert (verdict.shut is not None) == (mouth_margin is None)
    check.set_path(path, narrow)
    assert check.check(0.0, path, 0.0, thick_door(0.55), path[0]).shut is not None
