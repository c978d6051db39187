"""The PyBullet simulator against analytic ground truth: lidar ranges, odometry, collisions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from navkit import geometry as se2
from navkit.types import Command
from runners.sim import Simulator
from scenarios import load_scenario


def box_room(tmp_path: Path, noise=None, ceiling=True, range_noise=0.0) -> Path:
    spec = {
        "format": "navtopo-scenario/1",
        "name": "room",
        "seed": 5,
        "world": {
            "ceiling": ceiling,
            "wall_height": 2.6,
            "rooms": [{"center": [0, 0], "size": [8, 6], "yaw": 0}],
            "obstacles": [{"center": [3.0, 2.0], "size": [0.4, 0.4], "height": 0.3}],
        },
        "sensor": {"range_noise": range_noise},
        "odometry": {"noise": noise},
        "mapping_route": {"waypoints": [[-3, 0], [3, 0]]},
        "trials": [],
    }
    path = tmp_path / "room.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def expected_range(origin: np.ndarray, direction: np.ndarray, half: tuple[float, float], height: float) -> float:
    """Distance along a ray from inside an axis-aligned box room [-hx,hx]x[-hy,hy]x[0,height]."""
    t = np.inf
    for axis, limit in ((0, half[0]), (1, half[1])):
        if direction[axis] > 1e-12:
            t = min(t, (limit - origin[axis]) / direction[axis])
        elif direction[axis] < -1e-12:
            t = min(t, (-limit - origin[axis]) / direction[axis])
    if direction[2] > 1e-12:
        t = min(t, (height - origin[2]) / direction[2])
    elif direction[2] < -1e-12:
        t = min(t, -origin[2] / direction[2])
    return t


def test_lidar_ranges_match_the_analytic_distances_in_a_box_room(tmp_path):
    scenario = load_scenario(box_room(tmp_path))
    with Simulator(scenario) as sim:
        pose = np.array([-1.0, 0.5, 0.7])
        sim.reset(pose)
        points = sim.scan()
        assert points.dtype == np.float32 and points.shape[1] == 3
        mount = scenario.spec.sensor.mount_height
        # every ray of the sensor, rotated into the world, against the walls / floor / ceiling
        directions = sim.directions
        c, s = np.cos(pose[2]), np.sin(pose[2])
        world_dirs = np.stack(
            [c * directions[:, 0] - s * directions[:, 1], s * directions[:, 0] + c * directions[:, 1], directions[:, 2]], 1
        )
        origin = np.array([pose[0], pose[1], mount])
        expected = np.array([expected_range(origin, d, (4.0, 3.0), 2.6) for d in world_dirs])
        measured = np.linalg.norm(points - np.array([0, 0, mount], np.float32), axis=1)
        assert len(points) == len(directions)  # the room is closed: every ray returns
        # the low obstacle shadows some rays: compare only rays whose end is not at the box
        hit_world = se2.transform_points(pose, points.astype(np.float64))
        near_box = (np.abs(hit_world[:, 0] - 3.0) < 0.25) & (np.abs(hit_world[:, 1] - 2.0) < 0.25) & (hit_world[:, 2] < 0.31)
        assert near_box.sum() > 0  # the 0.3 m box is seen by the lower beams
        np.testing.assert_allclose(measured[~near_box], expected[~near_box], atol=2e-3)
        # floor hits are real returns, at z = 0
        assert np.isclose(points[:, 2].min(), 0.0, atol=1e-3)


def test_range_noise_has_the_configured_spread(tmp_path):
    scenario = load_scenario(box_room(tmp_path, range_noise=0.02, ceiling=False))
    with Simulator(scenario, seed=1) as sim:
        sim.reset([0.0, 0.0, 0.0])
        noisy = sim.scan()
    ranges = np.linalg.norm(noisy - np.array([0, 0, 0.6], np.float32), axis=1)
    horizontal = np.abs(noisy[:, 2] - 0.6) < 1e-1
    assert horizontal.any()
    with Simulator(load_scenario(box_room(tmp_path, ceiling=False)), seed=1) as sim:
        sim.reset([0.0, 0.0, 0.0])
        exact = np.linalg.norm(sim.scan() - np.array([0, 0, 0.6], np.float32), axis=1)
    error = ranges - exact
    assert abs(error.mean()) < 0.003 and error.std() == pytest.approx(0.02, rel=0.1)


def test_odometry_without_noise_is_exactly_the_true_motion(tmp_path):
    scenario = load_scenario(box_room(tmp_path))
    with Simulator(scenario) as sim:
        start = np.array([-3.0, -1.0, 0.3])
        sim.reset(start)
        for k in range(25):  # an S-bend that stays inside the 8 x 6 m room
            sim.step(Command(0.8, 0.6 if k % 10 < 5 else -0.4))
        truth = se2.between(start, sim.true_pose)
        assert np.array_equal(sim.odom_pose, truth)
        assert sim.collisions == 0


def test_odometry_noise_accumulates_drift_with_the_configured_statistics(tmp_path):
    noise = {"translation": 0.02, "rotation_deg_per_m": 0.5}
    scenario = load_scenario(box_room(tmp_path, noise=noise))
    along_errors, yaw_errors = [], []
    for seed in range(60):
        with Simulator(scenario, seed=seed) as sim:
            sim.reset([-3.5, 0.0, 0.0])
            for _ in range(30):  # 6 m straight at 1 m/s
                sim.step(Command(1.0, 0.0))
            truth = se2.between([-3.5, 0.0, 0.0], sim.true_pose)
            along_errors.append(sim.odom_pose[0] - truth[0])
            yaw_errors.append(sim.odom_pose[2] - truth[2])
    distance = 6.0
    # random walks: std grows with the square root of the distance travelled
    assert np.std(along_errors) == pytest.approx(0.02 * np.sqrt(distance), rel=0.3)
    assert np.std(yaw_errors) == pytest.approx(np.radians(0.5) * np.sqrt(distance), rel=0.3)
    assert abs(np.mean(along_errors)) < 3 * 0.02 * np.sqrt(distance) / np.sqrt(60)


def test_a_motion_into_a_wall_stops_at_contact_and_counts_a_collision(tmp_path):
    scenario = load_scenario(box_room(tmp_path))
    radius = scenario.spec.robot.radius
    with Simulator(scenario) as sim:
        sim.reset([-2.0, 0.0, np.pi])  # facing the wall at x = -4
        collided = False
        for tick in range(20):
            collided = sim.step(Command(1.0, 0.0)).collided
            # a step lasts one sensor period, collision or not
            assert sim.time == pytest.approx((tick + 1) / scenario.spec.sensor.rate_hz)
            if collided:
                break
        assert collided and sim.collisions == 1
        # stopped within a bisection step of touching: centre one radius from the wall
        assert sim.true_pose[0] == pytest.approx(-4.0 + radius, abs=0.01)
        assert sim.true_pose[0] >= -4.0 + radius - 1e-6
        # turning in place at contact is allowed
        assert not sim.step(Command(0.0, 1.0)).collided


def test_trajectory_is_sampled_every_substep_and_its_length_is_the_distance(tmp_path):
    scenario = load_scenario(box_room(tmp_path))
    with Simulator(scenario) as sim:
        sim.reset([-3.0, 0.0, 0.0])
        for _ in range(10):
            sim.step(Command(1.0, 0.0))
        rows = sim.trajectory_array()
        assert rows.shape == (1 + 10 * 4, 4)
        assert np.linalg.norm(np.diff(rows[:, 1:3], axis=0), axis=1).sum() == pytest.approx(2.0, abs=1e-9)


def test_two_simulators_in_one_process_do_not_share_a_world(tmp_path):
    room = load_scenario(box_room(tmp_path))
    tiny = load_scenario("tiny")
    with Simulator(room) as a, Simulator(tiny) as b:
        a.reset([0.0, 0.0, 0.0])
        b.reset([1.0, 0.0, 0.0])
        ranges_a = np.linalg.norm(a.scan()[:, :2], axis=1)
        assert ranges_a.max() < 5.1  # only the room's walls, not tiny's
        assert b.mesh_triangles != a.mesh_triangles


def test_a_runs_noise_depends_only_on_the_seed_and_its_stream(tmp_path):
    """Trial k sees the same sensor and odometry noise whatever ran before it in the process."""
    noise = {"translation": 0.02, "rotation_deg_per_m": 0.5}
    scenario = load_scenario(box_room(tmp_path, noise=noise, range_noise=0.02))

    def trial(sim: Simulator, index: int) -> tuple[np.ndarray, np.ndarray]:
        sim.reset([-3.0, 0.0, 0.0], stream=(2, index))
        first = sim.scan()
        for _ in range(5):
            sim.step(Command(1.0, 0.1))
        return first, sim.odom_pose

    with Simulator(scenario, seed=4) as a, Simulator(scenario, seed=4) as b:
        trial(a, 0)
        trial(a, 1)
        scan_a, odom_a = trial(a, 2)
        scan_b, odom_b = trial(b, 2)  # trial 2 alone, in a fresh simulator
        np.testing.assert_array_equal(scan_a, scan_b)
        np.testing.assert_array_equal(odom_a, odom_b)
        other, _ = trial(b, 3)
        assert not np.array_equal(other, scan_b)
