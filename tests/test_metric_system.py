"""MetricGrid, the metric baseline as a NavigationSystem, on the ``tiny`` scenario in the simulator.

One mapping drive (the first half of the mapping route, ~40 m) serves every test: the map is
checked against the ground-truth walls, saved and loaded, planned on, and navigated.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from scipy.spatial import cKDTree

from baselines.metric_grid.config import PlanningConfig
from baselines.metric_grid.occupancy import GridMap
from baselines.metric_grid.system import MetricGrid, MetricGridConfig, MetricMapError
from navkit import geometry as se2
from navkit.errors import BenchError
from navkit.follower import FollowerConfig, PathFollower
from navkit.raster import FREE, OCCUPIED
from runners.navigation import run_one_trial
from runners.sim import Simulator
from runners.systems import Status, SystemContext, get_system
from scenarios import load_scenario


@pytest.fixture(scope="module")
def tiny():
    return load_scenario("tiny")


@pytest.fixture(scope="module")
def context(tiny):
    return SystemContext(robot=tiny.spec.robot, sensor=tiny.spec.sensor)


@pytest.fixture(scope="module")
def sim(tiny):
    with Simulator(tiny, seed=0) as simulator:
        yield simulator


@pytest.fixture(scope="module")
def mapped(tiny, sim, context, tmp_path_factory):
    """Drive the first half of the mapping route (true-pose follower), build and save the map."""
    sim.reset(tiny.route_start)
    system = MetricGrid.create(MetricGridConfig(), context)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(tiny.route, axis=0).T))])
    follower = PathFollower(FollowerConfig(goal_tolerance=0.3))
    follower.set_path(tiny.route[arc <= arc[-1] / 2])
    for _ in range(2000):
        system.observe(sim.observe())
        command = follower.command(sim.true_pose)
        if follower.reached:
            break
        sim.step(command)
    assert follower.reached and sim.collisions == 0
    growing = system.mapping_stats()
    system.finish_mapping()
    directory = tmp_path_factory.mktemp("metric_map")
    system.save(directory)
    return system, directory, growing


def wall_quality(grid_map: GridMap, scenario, tol: float = 0.2) -> tuple[float, float]:
    """``occupancy.map_quality`` in the scenario frame (the map frame is the route's start pose):
    share of GT wall cells with a mapped occupied cell within ``tol``, and the converse."""
    mapped = se2.transform_points(scenario.route_start, grid_map.centres(grid_map.cells == OCCUPIED))
    walls = scenario.world.to_world(np.argwhere(scenario.world.wall_mask))
    to_mapped, _ = cKDTree(mapped).query(walls, distance_upper_bound=tol + 1e-9)
    to_walls, _ = cKDTree(walls).query(mapped, distance_upper_bound=tol + 1e-9)
    return float(np.isfinite(to_mapped).mean()), float(np.isfinite(to_walls).mean())


def test_half_the_mapping_route_gives_a_grid_whose_walls_match_ground_truth(tiny, mapped):
    system, _, growing = mapped
    recall, precision = wall_quality(system.grid_map, tiny)
    assert recall >= 0.9 and precision >= 0.9, (recall, precision)
    stats = system.mapping_stats()
    assert stats["map_bytes"] == system.grid_map.cells.nbytes + 24  # the trinary grid as loaded
    assert 0 < growing["map_bytes"]  # an online grid gives map bytes while mapping
    parts = ("keyframe_scan_bytes", "kiss_icp_map_bytes", "pose_graph_bytes", "log_odds_grid_bytes")
    assert stats["mapping_state_bytes"] == sum(stats[k] for k in parts)
    assert stats["keyframe_scan_bytes"] > 0 and stats["log_odds_grid_bytes"] > 0
    # the RTAB-MAP-style figure: the keyframes' raw clouds (more than their 2D scans), apart
    assert stats["raw_cloud_bytes"] > stats["keyframe_scan_bytes"] and stats["raw_cloud_bytes"] % 12 == 0
    parts_kept = stats["raw_cloud_bytes"] + stats["keyframe_scan_bytes"] + stats["pose_graph_bytes"] + stats["map_bytes"]
    assert stats["rtabmap_style_bytes"] == parts_kept
    assert stats["kiss_icp_map_bytes"] == 0  # wheel odometry by default: no kiss-icp map
    # a keyframe every 0.75 m of the ~40 m drive (or 20° of turning), and the revisits closed loops
    assert 50 <= stats["keyframes"] <= 120
    assert stats["loop_closures"] >= 1


def test_the_saved_map_server_map_loads_back_with_the_same_grid(mapped, context, tmp_path):
    system, directory, _ = mapped
    names = {p.name for p in directory.iterdir()}
    assert {"map.png", "map.yaml", "pose_graph.json", "pose_graph.npz", "metric_grid.json"} <= names
    loaded = MetricGrid.load(directory, MetricGridConfig(), context)
    assert np.array_equal(loaded.grid_map.cells, system.grid_map.cells)
    assert np.array_equal(loaded.grid_map.origin, system.grid_map.origin)
    assert loaded.grid_map.resolution == system.grid_map.resolution == 0.1
    assert loaded.stats()["map_bytes"] == system.mapping_stats()["map_bytes"]


@pytest.mark.parametrize(
    ("damage", "named"),
    [
        (lambda d: (d / "metric_grid.json").unlink(), "metric_grid.json"),
        (lambda d: (d / "metric_grid.json").write_text("{not json"), "metric_grid.json"),
        (lambda d: (d / "map.yaml").unlink(), "map.yaml"),
        (lambda d: (d / "map.yaml").write_text("image: [unclosed"), "map.yaml"),
        (lambda d: (d / "map.png").unlink(), "map.png"),
        (lambda d: (d / "map.png").write_bytes((d / "map.png").read_bytes()[:200]), "map.png"),
    ],
)
def test_a_damaged_map_folder_fails_with_one_message_naming_the_file(mapped, context, tmp_path, damage, named):
    _, directory, _ = mapped
    copy = tmp_path / "map"
    shutil.copytree(directory, copy)
    damage(copy)
    with pytest.raises(MetricMapError) as error:
        MetricGrid.load(copy, MetricGridConfig(), context)
    message = str(error.value)
    assert named in message and "\n" not in message
    # an input refused (exit code 2) that callers catching ValueError still catch
    assert isinstance(error.value, BenchError) and error.value.exit_code == 2 and isinstance(error.value, ValueError)


def _densify(path: np.ndarray, step: float = 0.02) -> np.ndarray:
    samples = [path[:1]]
    for a, b in zip(path[:-1], path[1:], strict=True):
        n = max(int(np.ceil(np.hypot(*(b - a)) / step)), 1)
        samples.append(a + (b - a) * np.linspace(0, 1, n + 1)[1:, None])
    return np.concatenate(samples)


@pytest.mark.parametrize(("keep_clear", "detour"), [(0.0, 1.05), (None, 1.10)])
def test_theta_star_paths_on_the_inflated_grid_keep_the_robot_radius_from_ground_truth_walls(
    tiny, mapped, context, keep_clear, detour
):
    """The shortest paths (``keep_clear`` 0) and the eased ones (the default) keep the robot's radius
    from the true walls; neither is a detour: within 5 % (shortest) or 10 % (eased off the walls) of
    the ground-truth shortest path."""
    _, directory, _ = mapped
    planning = PlanningConfig() if keep_clear is None else PlanningConfig(keep_clear=keep_clear)
    system = MetricGrid.load(directory, MetricGridConfig(planning=planning), context)
    radius = tiny.spec.robot.radius
    map_from_world = se2.inverse(tiny.route_start)
    for trial in tiny.trials:
        start = se2.transform_points(map_from_world, trial.start[None, :2])[0]
        goal = se2.transform_points(map_from_world, trial.goal[None, :])[0]
        path = system.plan(start, goal)
        assert path is not None
        assert np.allclose(path[0], start) and np.allclose(path[-1], goal)
        world_path = se2.transform_points(tiny.route_start, _densify(path))
        clearance = np.array([tiny.world.clearance_at(p) for p in world_path])
        assert clearance.min() >= radius, (trial, clearance.min())
        length = float(np.hypot(*np.diff(path, axis=0).T).sum())
        assert length <= detour * trial.shortest_m


def test_a_navigation_trial_on_tiny_reaches_the_goal_efficiently(tiny, sim, mapped, context):
    _, directory, _ = mapped
    entry = get_system("metric_grid")
    system = MetricGrid.load(directory, MetricGridConfig(), context)
    record, rows, estimate = run_one_trial(tiny, sim, entry, system, tiny.trials[0], 0, 0)
    assert record.success, record.reason
    assert record.collisions == 0 and record.efficiency >= 0.95
    assert record.planning_ms.count >= 2  # replanned at the fixed rate
    # the tracked pose (map frame) follows the true one within 10 cm: registration follows the map,
    # whose far end (seen from few keyframes of this half route) stands ~5 cm off ground truth
    true_in_map = np.array([se2.between(tiny.route_start, row[1:4]) for row in rows])
    at = np.clip(np.searchsorted(rows[:, 0], estimate[:, 0] - 1e-9), 0, len(rows) - 1)
    assert np.hypot(*(estimate[:, 1:3] - true_in_map[at, :2]).T).max() < 0.1


def _localize(system, sim, tiny, trial, given_in_map, ticks=10):
    """Give ``given_in_map`` as the initial pose, step ``ticks`` times; the estimate and the truth (map frame)."""
    sim.reset(trial.start)
    system.reset()
    system.set_initial_pose(given_in_map)
    system.set_goal(se2.transform_points(se2.inverse(tiny.route_start), trial.goal[None, :])[0])
    truth = se2.between(tiny.route_start, sim.true_pose)
    for _ in range(ticks):
        truth = se2.between(tiny.route_start, sim.true_pose)  # where the scan is taken
        command = system.step(sim.observe())
        sim.step(command)
    return system.pose_estimate(), truth


@pytest.mark.parametrize("error", [[0.15, -0.1, 3.0], [0.5, 0.5, 10.0], [-0.5, 0.4, -10.0]])
def test_a_hand_set_initial_pose_off_by_the_protocols_error_is_corrected_by_registration(tiny, sim, mapped, context, error):
    """The protocol gives the baseline its start off by up to ±0.5 m and ±10°: the window search
    and the scan-to-map fit bring the estimate to the truth before it drives far."""
    _, directory, _ = mapped
    system = MetricGrid.load(directory, MetricGridConfig(), context)
    trial = tiny.trials[0]
    true_in_map = se2.between(tiny.route_start, trial.start)
    given = true_in_map + np.array([error[0], error[1], np.deg2rad(error[2])])
    estimate, truth = _localize(system, sim, tiny, trial, given)
    # within the half cell to which a 0.1 m grid knows a wall (here the corridor's end wall,
    # the only structure that fixes the position along it)
    assert se2.distance(estimate, truth) < 0.06
    assert abs(se2.wrap_angle(estimate[2] - truth[2])) < np.deg2rad(0.5)
    assert system.counters["relocalizations"] >= 1 and system.counters["global_searches"] == 0


def test_a_start_far_from_the_given_pose_is_found_by_the_global_search(tiny, sim, mapped, context):
    _, directory, _ = mapped
    system = MetricGrid.load(directory, MetricGridConfig(), context)
    trial = tiny.trials[1]  # starts in the vertical corridor; we claim it is 6 m away in the first one
    true_in_map = se2.between(tiny.route_start, trial.start)
    wrong = se2.between(tiny.route_start, np.array([4.0, 0.0, 0.0]))
    assert se2.distance(wrong, true_in_map) > 5.0
    estimate, truth = _localize(system, sim, tiny, trial, wrong)
    assert system.counters["global_searches"] >= 1
    assert se2.distance(estimate, truth) < 0.1, (estimate, truth)


def test_a_kidnapped_start_is_found_on_the_whole_map_and_confirmed_over_motion(tiny, sim, mapped, context):
    """The protocol's ``none``: no pose given. The whole map is searched as the robot turns in place,
    then as it explores; the pose is taken only after three finds agree over 90° of turning and 3 m
    of motion, and it is the truth's."""
    _, directory, _ = mapped
    system = MetricGrid.load(directory, MetricGridConfig(), context)
    trial = tiny.trials[1]
    sim.reset(trial.start)
    system.reset()
    system.set_goal(se2.transform_points(se2.inverse(tiny.route_start), trial.goal[None, :])[0])
    found_at, turned, moved = None, 0.0, 0.0
    for tick in range(900):
        truth = se2.between(tiny.route_start, sim.true_pose)
        obs = sim.observe()
        command = system.step(obs)
        if system.tracker.localized:
            found_at = tick
            break
        before = sim.true_pose.copy()
        sim.step(command)
        turned += abs(se2.wrap_angle(sim.true_pose[2] - before[2]))
        moved += float(np.hypot(*(sim.true_pose[:2] - before[:2])))
        assert sim.collisions == 0
    assert found_at is not None and system.tracker.kidnapped
    assert system.counters["global_searches"] >= 3 and turned >= np.radians(90.0) - 0.1 and moved >= 3.0 - 0.1
    estimate = system.pose_estimate()
    assert se2.distance(estimate, truth) < 0.1 and abs(se2.wrap_angle(estimate[2] - truth[2])) < np.deg2rad(1.0)
    first = system.stats()["localizations"][0]
    assert first["given_pose"] is False and first["seconds"] > 0


def test_without_registration_the_given_error_stays(tiny, sim, mapped, context):
    _, directory, _ = mapped
    config = MetricGridConfig.model_validate({"localization": {"enabled": False}, "relocalization": {"enabled": False}})
    blind = MetricGrid.load(directory, config, context)
    trial = tiny.trials[0]
    true_in_map = se2.between(tiny.route_start, trial.start)
    estimate, truth = _localize(blind, sim, tiny, trial, se2.compose(true_in_map, [0.15, -0.1, np.deg2rad(3.0)]), ticks=1)
    assert se2.distance(estimate, truth) > 0.15


def test_an_obstacle_missing_from_the_map_is_seen_and_driven_around(tiny, sim, mapped, context, tmp_path):
    """Erase the cabinet (x 10.95-11.45, y 2.5-3.5) from the map: the first path cuts through it;
    the robot must see it, replan and reach the goal without touching it."""
    _, directory, _ = mapped
    copy = tmp_path / "map"
    shutil.copytree(directory, copy)
    grid_map = GridMap.load(copy / "map.yaml")
    centres = se2.transform_points(tiny.route_start, grid_map.centres(np.ones(grid_map.cells.shape, bool)))
    cabinet = (centres[:, 0] > 10.92) & (centres[:, 0] < 11.5) & (centres[:, 1] > 2.45) & (centres[:, 1] < 3.55)
    cells = grid_map.cells.reshape(-1).copy()
    assert (cells[cabinet] == OCCUPIED).any()
    cells[cabinet] = FREE
    GridMap(cells.reshape(grid_map.cells.shape), grid_map.origin, grid_map.resolution).save(copy / "map.yaml")
    system = MetricGrid.load(copy, MetricGridConfig(), context)
    trial = tiny.trials[0]
    map_from_world = se2.inverse(tiny.route_start)
    start = se2.transform_points(map_from_world, trial.start[None, :2])[0]
    goal = se2.transform_points(map_from_world, trial.goal[None, :])[0]
    blind_path = system.plan(start, goal)
    world_path = se2.transform_points(tiny.route_start, _densify(blind_path))
    near_cabinet = (world_path[:, 0] < 11.45 + tiny.spec.robot.radius) & (np.abs(world_path[:, 1] - 3.0) < 0.5)
    assert near_cabinet.any(), "the test needs a first path that runs into the erased cabinet"
    record, _, _ = run_one_trial(tiny, sim, get_system("metric_grid"), system, trial, 0, 0)
    assert record.success and record.collisions == 0, record.reason
    assert system.counters["replans_blocked"] >= 1
    assert system.status.state == Status.REACHED
    json.dumps(system.stats())  # stats are plain JSON


def test_the_config_refuses_unknown_keys_and_names_the_noisy_odometry_recipe():
    with pytest.raises(ValueError, match="extra"):
        MetricGridConfig.model_validate({"planning": {"replan_every": 2.0}})
    noisy = MetricGridConfig.for_noisy_odometry()
    assert noisy.odometry.source == "lidar" and MetricGridConfig().odometry.source == "wheel"
    assert noisy.pose_graph.odometry_sigma_yaw_deg < MetricGridConfig().pose_graph.odometry_sigma_yaw_deg
    assert MetricGridConfig.model_validate(noisy.model_dump(mode="json")) == noisy


def _blocked_goal(system, sim, tiny, trial):
    """Start a trial by hand, then remember a ring of obstacle points round the goal (out of the
    lidar's reach: nothing clears them) that shuts it off: a costmap that kept a phantom."""
    map_from_world = se2.inverse(tiny.route_start)
    sim.reset(trial.start)
    system.reset()
    system.set_initial_pose(se2.between(tiny.route_start, trial.start))
    goal = se2.transform_points(map_from_world, trial.goal[None, :])[0]
    system.set_goal(goal)
    angles = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    system.obstacles.memory.mark(goal + 0.8 * np.stack([np.cos(angles), np.sin(angles)], 1))
    assert np.hypot(*(trial.goal - trial.start[:2])) > system.config.planning.new_obstacle_range + 1.0


def test_no_path_for_remembered_obstacles_clears_them_and_plans_again_as_nav2s_recovery_does(tiny, sim, mapped, context):
    _, directory, _ = mapped
    trial = tiny.trials[0]
    strict = MetricGrid.load(directory, MetricGridConfig.model_validate({"planning": {"recoveries": 0}}), context)
    _blocked_goal(strict, sim, tiny, trial)
    strict.step(sim.observe())
    assert strict.status.state == Status.FAILED and strict.status.reason == "no_path"

    system = MetricGrid.load(directory, MetricGridConfig(), context)
    _blocked_goal(system, sim, tiny, trial)
    for _ in range(3):
        sim.step(system.step(sim.observe()))
    assert system.status.state == Status.ACTIVE and system.follower.has_path
    assert system.counters["recoveries"] == 1
    goal = se2.transform_points(se2.inverse(tiny.route_start), trial.goal[None, :])[0]
    remembered = system.obstacles.points
    assert not (np.hypot(*(remembered - goal).T) < 1.0).any()  # the phantom ring is forgotten


def test_the_progress_check_reports_a_stall_once_a_period_and_a_move_resets_it():
    from navkit.follower import ProgressCheck

    check = ProgressCheck(0.5, 10.0)
    assert not check.stalled(0.0, [0.0, 0.0])
    assert not check.stalled(9.9, [0.4, 0.0])  # 0.4 m: not yet progress, and not yet 10 s
    assert check.stalled(10.0, [0.45, 0.0])
    assert not check.stalled(15.0, [0.45, 0.0])  # the next report comes a period later
    assert not check.stalled(19.0, [1.0, 0.0])  # 0.55 m from the checkpoint: a new one
    assert not check.stalled(28.9, [1.2, 0.0]) and check.stalled(29.0, [1.2, 0.0])
