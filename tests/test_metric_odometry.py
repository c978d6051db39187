"""Lidar odometry of the metric baseline (kiss-icp) against the synthetic lidar's true poses."""

from __future__ import annotations

import numpy as np
import pytest
from test_metric_synthetic import World, corridor_world, loop_world, scan

from navkit import geometry as se2
from navkit.odometry import (
    LidarOdometry,
    OdometryConfig,
    crop_floor_and_ceiling,
    point_to_line,
    se2_to_se3,
    se3_to_se2,
)


@pytest.fixture(scope="module")
def corridor_drive():
    """True poses every 0.25 m along 20 m of a furnished corridor, and their scans."""
    true = np.array([[x, 0.0, 0.0] for x in np.arange(1.0, 21.01, 0.25)])
    world = corridor_world()
    return true, [scan(world, pose) for pose in true]


def _drive(odometry: LidarOdometry, true, scans, wheel) -> np.ndarray:
    return np.array([odometry.update(s, w) for s, w in zip(scans, wheel, strict=True)])


def test_lidar_odometry_on_a_corridor_drive_matches_the_true_displacement_within_1_percent(
    corridor_drive,
):
    true, scans = corridor_drive
    still = np.repeat(true[:1], len(true), axis=0)  # no wheel information at all
    estimate = _drive(LidarOdometry(OdometryConfig(seed_with_wheel=False)), true, scans, still)
    driven = se2.distance(true[0], true[-1])
    assert abs(se2.distance(estimate[0], estimate[-1]) - driven) < 0.01 * driven
    assert se2.distance(estimate[-1], true[-1]) < 0.01 * driven
    assert abs(estimate[-1, 2]) < np.deg2rad(1.0)


def test_lidar_corrects_a_wheel_odometry_that_over_reads_by_5_percent(corridor_drive):
    true, scans = corridor_drive
    wheel = true.copy()
    wheel[:, 0] = true[0, 0] + 1.05 * (true[:, 0] - true[0, 0])
    estimate = _drive(LidarOdometry(OdometryConfig(seed_with_wheel=True)), true, scans, wheel)
    driven = se2.distance(true[0], true[-1])
    assert se2.distance(estimate[-1], true[-1]) < 0.01 * driven
    assert se2.distance(wheel[-1], true[-1]) > 0.04 * driven  # the seed alone was wrong


def test_lidar_pose_is_reported_in_the_wheel_odometry_frame(corridor_drive):
    """The first wheel pose anchors the lidar estimate: both sources share one frame."""
    true, scans = corridor_drive
    offset = np.array([2.0, -1.0, 0.5])
    wheel = se2.compose(offset, se2.compose(se2.inverse(true[0]), true[:12]))
    lidar = _drive(LidarOdometry(), true[:12], scans[:12], wheel)
    assert np.allclose(lidar[0], offset)
    assert se2.distance(lidar[-1], wheel[-1]) < 0.05
    wheel_only = _drive(LidarOdometry(OdometryConfig(source="wheel")), true[:12], scans[:12], wheel)
    assert np.allclose(wheel_only, wheel)
    assert LidarOdometry(OdometryConfig(source="wheel")).nbytes == 0


def test_a_scan_without_structure_keeps_the_predicted_motion(corridor_drive):
    true, scans = corridor_drive
    odometry = LidarOdometry()
    odometry.update(scans[0], true[0])
    floor_only = scans[1][scans[1][:, 2] == 0.0]
    pose = odometry.update(floor_only, true[1])  # nothing to register: the wheel delta is kept
    assert se2.distance(pose, true[1]) < 1e-6
    assert odometry.nbytes > 0


def test_se2_se3_round_trip():
    pose = np.array([1.5, -2.0, 2.9])
    assert np.allclose(se3_to_se2(se2_to_se3(pose)), pose)
    with pytest.raises(ValueError):
        OdometryConfig(source="imu")


def _walls(world: World, pose: np.ndarray) -> np.ndarray:
    """(N, 2) wall returns of a scan from ``pose``, in the robot frame."""
    return crop_floor_and_ceiling(scan(world, pose), 0.15, 1.5)[:, :2]


def _to_world(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return points @ np.array([[c, s], [-s, c]]) + pose[:2]


def test_point_to_line_puts_a_scan_on_the_walls_of_another_scan_taken_elsewhere():
    """The map is one scan from 0.6 m away (its returns sample the walls at other points than the
    scan's own, the sampling that pulls point-to-point ICP); from a guess 0.12 m and 1.5° off,
    with the prior made weak, the refinement finds the true pose."""
    world = loop_world()
    true = np.array([4.3, 0.2, 0.1])
    seen_from = np.array([3.7, -0.1, -0.05])
    map_points = _to_world(_walls(world, seen_from), seen_from)
    guess = true + np.array([0.08, -0.09, np.radians(1.5)])
    weak_prior = OdometryConfig(line_prior_xy=10.0, line_prior_yaw_deg=90.0)
    estimate = point_to_line(_walls(world, true), map_points, guess, weak_prior)
    assert np.hypot(*(estimate[:2] - true[:2])) < 0.005
    assert abs(se2.wrap_angle(estimate[2] - true[2])) < np.radians(0.06)


def test_point_to_line_leaves_the_unconstrained_direction_of_a_bare_corridor_to_the_prior():
    """Two straight walls fix the heading and the cross-corridor position, nothing the position
    along it: that stays where the prior puts it."""
    world = World.solid(-3.0, -3.0, 43.0, 3.0).carve(-1.0, -1.2, 41.0, 1.2)
    true = np.array([20.0, 0.3, 0.02])
    map_points = _to_world(_walls(world, true - [0.5, 0.0, 0.0]), true - [0.5, 0.0, 0.0])
    guess = true + np.array([0.15, -0.1, np.radians(2.0)])
    prior = true + np.array([0.05, 0.2, np.radians(-1.0)])
    estimate = point_to_line(_walls(world, true), map_points, guess, OdometryConfig(), prior)
    assert abs(estimate[1] - true[1]) < 0.01
    assert abs(se2.wrap_angle(estimate[2] - true[2])) < np.radians(0.1)
    assert abs(estimate[0] - prior[0]) < 0.01


def test_point_to_line_takes_the_position_along_a_corridor_from_its_door_jambs():
    """A corridor whose walls are straight but for one door niche: the niche's jambs lie on no
    line, yet they fix where along the corridor the scan was taken, against a prior 0.08 m off
    there (a few jamb returns against the prior: most of the way, not all of it). Without them
    (``line_corner_ratio`` 0) the position along the corridor stays the prior's."""
    world = World.solid(-3.0, -3.0, 43.0, 3.0).carve(-1.0, -1.2, 41.0, 1.2).carve(20.8, 1.2, 21.7, 1.4)
    true = np.array([20.0, 0.3, 0.02])
    seen_from = true - [0.5, 0.0, 0.0]
    map_points = _to_world(_walls(world, seen_from), seen_from)
    guess = true + np.array([0.05, -0.03, np.radians(1.0)])
    prior = true + np.array([0.08, 0.0, 0.0])
    estimate = point_to_line(_walls(world, true), map_points, guess, OdometryConfig(), prior)
    assert abs(estimate[0] - true[0]) < 0.025
    assert abs(estimate[1] - true[1]) < 0.005
    assert abs(se2.wrap_angle(estimate[2] - true[2])) < np.radians(0.05)
    walls_only = point_to_line(_walls(world, true), map_points, guess, OdometryConfig(line_corner_ratio=0.0), prior)
    assert abs(walls_only[0] - prior[0]) < 0.005
