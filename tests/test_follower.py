"""The path follower drives a simulated unicycle along paths (ground truth: the path itself)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from navkit import grid_search
from navkit.follower import FollowerConfig, PathFollower
from navkit.geometry import compose, transform_points, wrap_angle
from navkit.raster import GridFrame

L_PATH = np.array([[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]])


def polyline_length(points: np.ndarray) -> float:
    return float(np.hypot(*np.diff(points, axis=0).T).sum())


def distance_to_polyline(point: np.ndarray, points: np.ndarray) -> float:
    a, b = points[:-1], points[1:]
    t = np.clip(np.einsum("ij,ij->i", point - a, b - a) / np.einsum("ij,ij->i", b - a, b - a), 0, 1)
    return float(np.hypot(*(a + t[:, None] * (b - a) - point).T).min())


def drive(follower: PathFollower, pose, dt: float = 0.1, max_steps: int = 600, substeps: int = 1):
    """Integrate a unicycle under the follower's commands (one a tick of ``dt``, in ``substeps``
    Euler steps) until it reports `reached`; the poses at the ticks, and the commands."""
    pose = np.asarray(pose, dtype=np.float64).copy()
    poses, commands = [pose.copy()], []
    for _ in range(max_steps):
        command = follower.command(pose)
        commands.append(command)
        if follower.reached:
            break
        for _ in range(substeps):
            pose[0] += command.linear * math.cos(pose[2]) * dt / substeps
            pose[1] += command.linear * math.sin(pose[2]) * dt / substeps
            pose[2] = wrap_angle(pose[2] + command.angular * dt / substeps)
        poses.append(pose.copy())
    return np.array(poses), commands


def test_config_defaults_and_unknown_keys():
    config = FollowerConfig()
    assert (config.max_linear, config.max_angular, config.lookahead, config.goal_tolerance) == (
        1.0,
        1.5,
        0.6,
        0.35,  # the protocol's stop tolerance
    )
    with pytest.raises(ValidationError):
        FollowerConfig(max_speed=2.0)
    with pytest.raises(ValidationError):
        FollowerConfig(max_linear=-1.0)


@pytest.mark.parametrize("dt", [0.1, 0.2])
def test_robot_facing_away_turns_in_place_then_follows_an_l_path_to_its_end(dt):
    config = FollowerConfig()
    follower = PathFollower(config)
    follower.set_path(L_PATH)
    poses, commands = drive(follower, [0.0, 0.0, math.pi], dt=dt)

    # at first it turns in place (linear exactly 0) until the heading error toward the path
    # (+x, the robot is still at its start) falls below turn_in_place_until, then it drives
    first_move = next(i for i, c in enumerate(commands) if c.linear > 0.0)
    error = np.abs(wrap_angle(poses[: first_move + 1, 2]))
    assert first_move >= int(3.0 / (config.max_angular * dt))  # turning pi - 0.1 rad takes time
    assert all(c.linear == 0.0 and abs(c.angular) > 0.0 for c in commands[:first_move])
    assert (error[:first_move] >= config.turn_in_place_until).all()
    assert error[first_move] < config.turn_in_place_until
    assert np.allclose(poses[: first_move + 1, :2], 0.0)  # no translation while turning

    assert follower.reached and follower.at_goal(poses[-1])
    assert np.hypot(*(poses[-1, :2] - L_PATH[-1])) <= config.goal_tolerance
    travelled = polyline_length(poses[:, :2])
    assert travelled <= 1.05 * polyline_length(L_PATH)
    # the corner is not cut: the robot stays close to the path all along
    assert max(distance_to_polyline(p, L_PATH) for p in poses[:, :2]) < 0.2
    assert commands[-1].linear == 0.0 and commands[-1].angular == 0.0
    assert follower.command(poses[-1]).linear == 0.0  # stays stopped


def test_following_a_theta_star_path_around_a_wall_keeps_clear_of_it():
    # 8 m x 12 m room at 0.05 m, a 0.2 m wall from the bottom edge up to y = 5.5 m
    resolution, radius = 0.05, 0.3
    rows, cols = np.mgrid[0:160, 0:240]
    x, y = (cols + 0.5) * resolution, (rows + 0.5) * resolution
    room = ~((x > 5.9) & (x < 6.1) & (y < 5.5))
    free = grid_search.inflate_free(room, radius, resolution)
    start, goal = np.array([3.0, 1.0, 0.0]), np.array([9.0, 1.0])
    frame = GridFrame(np.zeros(2), resolution)
    cells = grid_search.theta_star(free, frame.to_cell(start[:2]), frame.to_cell(goal))
    path = frame.to_world(cells)
    path[-1] = goal  # the planner's last vertex is the goal's cell centre: end on the goal itself

    follower = PathFollower()
    follower.set_path(path)
    poses, _ = drive(follower, start)
    assert follower.reached and np.hypot(*(poses[-1, :2] - goal)) <= 0.5
    assert polyline_length(poses[:, :2]) <= 1.05 * polyline_length(path)
    gap_x = np.maximum.reduce([5.9 - poses[:, 0], np.zeros(len(poses)), poses[:, 0] - 6.1])
    gap_y = np.maximum(poses[:, 1] - 5.5, 0.0)
    wall_distance = np.hypot(gap_x, gap_y)
    # the path keeps `radius` (to half a cell); the follower may leave it by corner_tolerance
    assert wall_distance.min() >= radius - resolution / 2 - follower.config.corner_tolerance


def test_speeds_respect_the_limits_and_slow_down_near_the_end():
    config = FollowerConfig(max_linear=0.8, max_angular=1.2)
    follower = PathFollower(config)
    follower.set_path([[0.0, 0.0], [10.0, 0.0]])
    poses, commands = drive(follower, [0.0, 0.3, 0.4])
    assert follower.reached
    assert all(0.0 <= c.linear <= 0.8 and abs(c.angular) <= 1.2 for c in commands)
    speeds = np.array([c.linear for c in commands[:-1]])
    assert speeds.max() == pytest.approx(0.8, abs=1e-3)
    near_end = np.hypot(*(poses[: len(speeds), :2] - [10.0, 0.0]).T) < 0.8
    assert near_end.any() and speeds[near_end].max() < 0.8


def test_progress_is_monotone_and_does_not_jump_onto_a_path_that_doubles_back():
    hairpin = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 1.2], [0.0, 1.2]])
    follower = PathFollower()
    follower.set_path(hairpin)
    # next to the return leg (0.2 m) but a metre off the first leg: the progress stays on the
    # first leg, moving at most one projection window ahead
    follower.command([2.0, 1.0, 0.0])
    assert 0.0 < follower.progress <= follower.config.progress_window + 1e-9

    follower.set_path(hairpin)
    progress = []
    pose = np.array([0.0, 0.0, 0.0])
    for _ in range(400):
        command = follower.command(pose)
        progress.append(follower.progress)
        if follower.reached:
            break
        pose[0] += command.linear * math.cos(pose[2]) * 0.1
        pose[1] += command.linear * math.sin(pose[2]) * 0.1
        pose[2] = wrap_angle(pose[2] + command.angular * 0.1)
    assert follower.reached
    assert np.all(np.diff(progress) >= 0.0)
    assert max(progress) == pytest.approx(polyline_length(hairpin))
    assert pose[0] < 0.5 and abs(pose[1] - 1.2) < 0.2  # it went round the hairpin


def test_a_closed_route_is_driven_all_the_way_round():
    loop = np.array([[0.0, 0.0], [3.0, 0.0], [3.0, 3.0], [0.0, 3.0], [0.0, 0.0]])
    follower = PathFollower()
    follower.set_path(loop)
    assert follower.command([0.0, 0.0, 0.0]).linear > 0.0  # at its own end, but not done
    poses, _ = drive(follower, [0.0, 0.0, 0.0])
    assert follower.reached
    assert polyline_length(poses[:, :2]) >= polyline_length(loop) - 0.5 - 0.2
    assert np.hypot(*poses[-1, :2]) <= follower.config.goal_tolerance


def test_commands_do_not_depend_on_the_frame():
    frame = np.array([12.0, -5.0, 2.1])
    pose = np.array([0.7, 0.2, 1.0])
    here, there = PathFollower(), PathFollower()
    here.set_path(L_PATH)
    there.set_path(transform_points(frame, L_PATH))
    for _ in range(3):  # a few ticks, so progress is compared too
        a, b = here.command(pose), there.command(compose(frame, pose))
        assert a.linear == pytest.approx(b.linear) and a.angular == pytest.approx(b.angular)
        pose = pose + [0.1, 0.0, 0.05]


def test_no_path_or_reached_gives_zero_commands():
    follower = PathFollower()
    assert follower.command([0.0, 0.0, 0.0]).linear == 0.0 and not follower.reached
    follower.set_path([[0.2, 0.1]])  # a single point within tolerance
    assert follower.at_goal([0.0, 0.0, 1.0])
    assert follower.command([0.0, 0.0, 1.0]) == follower.command([5.0, 5.0, 0.0])
    assert follower.reached
    follower.set_path(L_PATH)  # a new path resets
    assert not follower.reached and follower.progress == 0.0
    with pytest.raises(ValueError):
        follower.set_path(np.zeros((3, 3)))


@pytest.mark.parametrize("turn_deg", [25, 45, 90, 135])
def test_at_five_hertz_corners_are_driven_without_swinging_off_the_path(turn_deg):
    """At 5 Hz a robot at full speed moves 0.2 m a tick. Before the corner rules (slow down, pass
    within 5 cm, turn in place to face the next stretch) it swung about 0.06 m off the path at
    every corner; door jambs are passed with a few centimetres to spare."""
    a = math.radians(turn_deg)
    path = np.array([[-3.0, 0.0], [0.0, 0.0], [3.0 * math.cos(a), 3.0 * math.sin(a)]])
    follower = PathFollower(FollowerConfig())
    follower.set_path(path)
    poses, _ = drive(follower, [-3.0, 0.0, 0.0], dt=0.2, max_steps=300, substeps=20)
    assert follower.reached
    deviation = max(distance_to_polyline(p[:2], path) for p in poses)
    assert deviation < 0.035, deviation  # before: 0.057-0.066 m


def test_past_a_corner_the_robot_faces_the_next_stretch_before_driving_on():
    path = np.array([[-3.0, 0.0], [0.0, 0.0], [3.0 * math.cos(0.45), 3.0 * math.sin(0.45)]])  # 26 degrees
    follower = PathFollower(FollowerConfig())
    follower.set_path(path)
    poses, commands = drive(follower, [-3.0, 0.0, 0.0], dt=0.2, max_steps=300)
    at_corner = next(i for i, p in enumerate(poses) if np.hypot(*p[:2]) <= follower.config.corner_tolerance)
    # below the turn-in-place threshold (0.5 rad), yet the robot turns on the spot at the corner
    assert commands[at_corner].linear == 0.0 and commands[at_corner].angular > 0.0
    first_drive = next(i for i in range(at_corner, len(commands)) if commands[i].linear > 0.0)
    heading_error = abs(wrap_angle(math.atan2(*(follower.path[-1] - poses[first_drive][:2])[::-1]) - poses[first_drive][2]))
    assert heading_error < 0.1 + 0.02


def test_a_path_replaced_mid_turn_is_faced_before_the_robot_drives():
    """A turn in place under way goes on toward a new path until ``turn_in_place_until``: a plan
    replaced mid-turn left the robot 14 degrees off the new way (under the 0.5 rad threshold) and it
    drove off so, into the jamb of the door it stood in."""
    follower = PathFollower(FollowerConfig())
    follower.set_path(np.array([[0.0, 0.0], [-2.0, 0.0]]))  # behind the robot: it turns in place
    pose = np.array([0.0, 0.0, 0.0])
    command = follower.command(pose)
    assert command.linear == 0.0 and command.angular != 0.0
    pose[2] = math.radians(-33.0)  # mid-turn, a new plan: the way on at -19 degrees
    way = math.radians(-19.0)
    follower.set_path(np.array([[0.0, 0.0], [3.0 * math.cos(way), 3.0 * math.sin(way)]]))
    poses, commands = drive(follower, pose, dt=0.2, max_steps=300)
    first_drive = next(i for i, c in enumerate(commands) if c.linear > 0.0)
    assert first_drive > 0 and abs(wrap_angle(poses[first_drive][2] - way)) < 0.1 + 0.02
    # a robot not turning drives off under the threshold as before
    fresh = PathFollower(FollowerConfig())
    fresh.set_path(np.array([[0.0, 0.0], [3.0 * math.cos(way), 3.0 * math.sin(way)]]))
    assert fresh.command(np.array([0.0, 0.0, math.radians(-33.0)])).linear > 0.0


def test_advance_is_the_progress_command_would_find_and_moves_it_once():
    """A check between two commands (a passage's) asks the progress at the robot's position now: the
    last command's lags a tick behind, and a path point it counted ahead lay behind the robot."""
    follower = PathFollower(FollowerConfig())
    follower.set_path(np.array([[0.0, 0.0], [4.0, 0.0]]))
    follower.command(np.array([0.0, 0.0, 0.0]))
    assert follower.progress == pytest.approx(0.0)
    assert follower.advance(np.array([0.2, 0.05])) == pytest.approx(0.2)
    assert follower.advance(np.array([0.2, 0.05])) == pytest.approx(0.2)
    follower.command(np.array([0.2, 0.05, 0.0]))
    assert follower.progress == pytest.approx(0.2)
    assert PathFollower(FollowerConfig()).advance(np.array([1.0, 0.0])) == 0.0  # no path


@pytest.mark.parametrize("off_deg", [8.0, 12.0, 16.0])
def test_a_narrow_passage_is_driven_slowly_so_a_heading_off_does_not_drift_onto_a_jamb(off_deg):
    """A door at the robot's width leaves ten centimetres a side. A robot entering it with its
    heading a few degrees off (a path re-planned or re-fitted in the doorway) drifted sideways at
    full speed before the angular correction caught it: 0.036 / 0.050 / 0.060 m at 8 / 12 / 16
    degrees over the first metre (a generated slam-ring, precise: it met the jamb). Over a stretch
    marked ``slow_between`` the speed is ``passage_speed``, and the drift a third of that."""
    path = np.array([[0.0, 0.0], [0.0, 3.0]])
    start = [0.0, 0.0, math.radians(90.0 + off_deg)]
    drifts = {}
    for slow in (False, True):
        follower = PathFollower(FollowerConfig(passage_speed=0.3))
        follower.set_path(path)
        if slow:
            follower.slow_between(0.0, 1.0)
        poses, commands = drive(follower, start, dt=0.2, max_steps=300, substeps=20)
        assert follower.reached
        in_door = poses[:, 1] <= 1.0
        drifts[slow] = float(np.abs(poses[in_door, 0]).max())
        speeds = [c.linear for c, inside in zip(commands, in_door[: len(commands)], strict=True) if inside]
        assert max(speeds) <= (follower.config.passage_speed if slow else follower.config.max_linear) + 1e-9
    assert drifts[True] < 0.025 < drifts[False], drifts
    # past the stretch the robot drives at full speed again
    assert max(c.linear for c in commands) > 0.95 * follower.config.max_linear
