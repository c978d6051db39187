"""Pose graph of the metric baseline: keyframes, verified loop closures, gtsam, save/load."""

from __future__ import annotations

import numpy as np
import pytest
from test_metric_synthetic import World, drifting_odometry, loop_route, loop_world, scan

from baselines.metric_grid.pose_graph import PoseGraph, PoseGraphConfig
from baselines.metric_grid.scan2d import keyframe_scan
from navkit import geometry as se2


@pytest.fixture(scope="module")
def loop_drive():
    """One lap (plus 2 m) of a furnished ring corridor: true poses every 0.375 m and their
    keyframe scans (obstacle points, free ranges)."""
    true = loop_route(0.375, laps=1.05)
    world = loop_world()
    return true, [keyframe_scan(scan(world, pose)) for pose in true]


def _build(config: PoseGraphConfig, odometry, scans, true):
    graph = PoseGraph(config)
    keyframe_truth = []
    for odom_pose, (points, ranges), true_pose in zip(odometry, scans, true, strict=True):
        if graph.add_scan(odom_pose, points, ranges):
            keyframe_truth.append(true_pose)
    return graph, np.array(keyframe_truth)


@pytest.mark.parametrize("optimizer", ["isam2", "lm"])
def test_a_loop_with_injected_drift_is_closed(loop_drive, optimizer):
    true, scans = loop_drive
    # odometry over-reads distance by 2 % and turns 0.5°/m too much: > 1 m off after one lap
    odometry = drifting_odometry(true, scale=0.02, yaw_per_m=np.deg2rad(0.5))
    graph, truth = _build(PoseGraphConfig(optimizer=optimizer), odometry, scans, true)
    assert se2.distance(graph.keyframes[-1].odom_pose, truth[-1]) > 1.0
    assert len(graph.loops) >= 3
    assert all(lc.new - lc.old > 20 for lc in graph.loops)  # far along the trajectory
    poses = graph.optimize()
    # the map frame is the first keyframe's odometry frame, which is the true frame here
    assert se2.distance(poses[-1], truth[-1]) < 0.1
    yaw_error = abs(se2.wrap_angle(poses[-1, 2] - truth[-1, 2]))
    assert yaw_error < np.deg2rad(1.0)
    # every verified loop agrees with the true relative pose
    for lc in graph.loops:
        true_rel = se2.between(truth[lc.old], truth[lc.new])
        assert se2.distance(lc.pose, true_rel) < 0.1


def test_keyframes_every_0_75_m_or_20_degrees():
    graph = PoseGraph(PoseGraphConfig(loop={"enabled": False}))
    points = np.random.default_rng(0).uniform(-5, 5, (200, 2))
    added = [graph.add_scan([0.1 * i, 0.0, 0.0], points) for i in range(20)]
    assert np.flatnonzero(added).tolist() == [0, 8, 16]  # 0.8 m apart (>= 0.75 m)
    assert not graph.add_scan([1.9, 0.0, np.deg2rad(10)], points)
    assert graph.add_scan([1.9, 0.0, np.deg2rad(25)], points)  # turning in place
    assert graph.travel == pytest.approx(1.9)


def test_a_featureless_corridor_gives_no_loop_closure():
    """Walls alone cannot fix the position along a corridor: the registration is refused
    rather than trusted, whatever the initial guess."""
    world = World.solid(-3.0, -4.0, 40.0, 4.0).carve(-1.0, -1.0, 39.0, 1.0)
    graph = PoseGraph()
    first = keyframe_scan(scan(world, np.array([15.0, 0.0, 0.0])))
    second = keyframe_scan(scan(world, np.array([17.0, 0.0, 0.0])))
    assert graph.add_scan([0.0, 0.0, 0.0], *first)
    # odometry says 0.8 m were driven, the truth is 2 m: ICP slides along the walls and fits
    # perfectly anywhere, so only the geometric-constraint check can tell
    assert graph.add_scan([0.8, 0.0, 0.0], *second)
    assert graph.verify_loop(0, 1) is None


def test_save_and_load_keep_keyframes_loops_and_bytes(tmp_path, loop_drive):
    true, scans = loop_drive
    odometry = drifting_odometry(true, scale=0.02, yaw_per_m=np.deg2rad(0.3))
    graph, _ = _build(PoseGraphConfig(), odometry, scans, true)
    graph.save(tmp_path / "graph")
    loaded = PoseGraph.load(tmp_path / "graph")
    assert loaded.nbytes == graph.nbytes
    assert np.allclose(loaded.poses(), graph.poses())
    assert [(lc.old, lc.new) for lc in loaded.loops] == [(lc.old, lc.new) for lc in graph.loops]
    for a, b in zip(graph.keyframes, loaded.keyframes, strict=True):
        assert np.array_equal(a.points, b.points) and np.array_equal(a.free_ranges, b.free_ranges)
    # the rebuilt factor graph optimises to the same poses
    assert np.allclose(loaded.optimize(), graph.optimize(), atol=1e-4)
    # exact bytes: the arrays, nothing guessed
    expected = sum(kf.odom_pose.nbytes + 8 + kf.points.nbytes + kf.free_ranges.nbytes for kf in graph.keyframes)
    expected += graph.poses().nbytes + len(graph.loops) * 64
    assert graph.nbytes == expected


def test_a_corrupt_saved_graph_is_refused(tmp_path):
    graph = PoseGraph()
    graph.add_scan([0.0, 0.0, 0.0], np.zeros((10, 2)))
    graph.save(tmp_path)
    (tmp_path / "pose_graph.json").write_text('{"format": "something-else/1"}')
    with pytest.raises(ValueError, match="format"):
        PoseGraph.load(tmp_path)


def test_a_heading_prior_keeps_the_map_from_turning_where_the_odometry_heading_is_right(loop_drive):
    """Ground truth: odometry whose heading is exact but which over-reads distance by 5 %. The loop
    closures pull the lap together; the odometry factors alone leave the headings free to turn with
    it (0.03 degrees median, 0.11 at worst off the truth), the weak prior on each keyframe's heading
    (``heading_sigma_deg``) holds them to the odometry's, without moving the positions."""
    true, scans = loop_drive
    odometry = drifting_odometry(true, scale=0.05, yaw_per_m=0.0)
    errors = {}
    for heading in (None, 1.0):
        config = PoseGraphConfig(heading_sigma_deg=heading, odometry_sigma_yaw_deg=0.1, odometry_sigma_yaw_deg_per_m=0.1)
        graph, truth = _build(config, odometry, scans, true)
        assert len(graph.loops) >= 3
        poses = graph.optimize()
        yaw = np.abs(se2.wrap_angle(poses[:, 2] - truth[:, 2]))
        errors[heading] = (np.median(yaw), yaw.max(), np.hypot(*(poses[:, :2] - truth[:, :2]).T).max())
    assert errors[1.0][0] < 0.5 * errors[None][0] and errors[1.0][1] < errors[None][1]
    assert errors[1.0][2] < errors[None][2] + 0.02
