"""NavTopo graph maintenance on simulated scans, against the simulator's true poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from crafted_poses import poses_along

from navkit import geometry as se2
from navkit.follower import FollowerConfig, PathFollower
from navkit.scan_grid import grid_from_points
from navkit.types import Command
from navtopo.graph import TopologicalGraph
from navtopo.scan_matching import prepare
from navtopo.system import NavTopo, NavTopoConfig
from runners.sim import Simulator
from scenarios import load_scenario


def two_rooms(tmp_path: Path) -> Path:
    """Two furnished 6 x 5 m rooms joined by a 14 m corridor with niches."""
    spec = {
        "format": "navtopo-scenario/1",
        "name": "two_rooms",
        "world": {
            "rooms": [
                {"center": [0, 0], "size": [6, 5]},
                {"center": [20, 0], "size": [6, 5]},
                {"center": [7, 1.3], "size": [1.2, 0.6]},
                {"center": [13, -1.3], "size": [1.6, 0.6]},
            ],
            "corridors": [{"points": [[2.5, 0], [17.5, 0]], "width": 2.0}],
            "obstacles": [
                {"center": [-2.0, 1.8], "size": [1.0, 0.6], "height": 0.8},
                {"center": [1.5, -1.9], "size": [0.6, 0.6], "height": 1.6},
                {"center": [21.5, 1.5], "size": [0.8, 0.8], "height": 0.5},
                {"center": [18.5, -1.8], "size": [1.2, 0.5], "height": 2.0},
            ],
        },
        "mapping_route": {"waypoints": [[0, 0], [20, 0]]},
        "trials": [],
    }
    path = tmp_path / "two_rooms.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    return load_scenario(two_rooms(tmp_path_factory.mktemp("s")))


def config() -> NavTopoConfig:
    return NavTopoConfig(descriptor="scan_context")


def drive(system: NavTopo, sim: Simulator, waypoints, true_at: dict) -> list[int]:
    """Follow the waypoints on the true pose, feeding every scan to the system; records the true
    pose at each stamp and returns the graph's size after each scan."""
    follower = PathFollower(FollowerConfig())
    follower.set_path(np.array(waypoints, dtype=float))
    sizes = []
    while not follower.reached:
        obs = sim.observe()
        true_at[obs.stamp] = sim.true_pose
        system.observe(obs)
        sizes.append(len(system.graph))
        sim.step(follower.command(sim.true_pose))
    return sizes


def test_turning_in_place_keeps_one_location_and_leaving_the_room_adds_more(scenario):
    system = NavTopo.create(config())
    with Simulator(scenario) as sim:
        sim.reset([0.0, 0.0, 0.0])
        true_at = {}
        for _ in range(25):  # a full turn and more, in place
            obs = sim.observe()
            true_at[obs.stamp] = sim.true_pose
            system.observe(obs)
            sim.step(Command(0.0, 1.5))
        assert len(system.graph) == 1
        assert system.maintainer.counters.inside > 5

        drive(system, sim, [[0.0, 0.0], [20.0, 0.0]], true_at)
        assert sim.collisions == 0
    # 20 m with locations at most 5 m from their centre: several, but not one per scan
    assert 3 <= len(system.graph) <= 8
    # the robot is in the last location, where its tracked pose matches the truth
    current = system.maintainer.current
    vertex_true = true_at[system.graph.vertices[current].stamp]
    estimated = se2.compose(vertex_true, system.maintainer.pose_in_current)
    assert se2.distance(estimated, sim.true_pose) < 0.25
    # every edge is the true relative pose of its vertices' observation points
    assert system.graph.edge_count >= len(system.graph) - 1
    for u, v, pose_uv in system.graph.edges():
        truth = se2.between(true_at[system.graph.vertices[u].stamp], true_at[system.graph.vertices[v].stamp])
        error = se2.between(truth, pose_uv)
        assert np.hypot(error[0], error[1]) < 0.3 and abs(np.degrees(error[2])) < 3.0


def test_driving_back_reuses_the_locations(scenario):
    system = NavTopo.create(config())
    with Simulator(scenario) as sim:
        sim.reset([0.0, 0.0, 0.0])
        counts = drive(system, sim, [[0.0, 0.0], [20.0, 0.0], [0.5, 0.0]], {})
    outward = max(counts[: len(counts) // 2])
    assert len(system.graph) <= outward + 1  # the way back adds (almost) nothing


def test_saved_graph_loads_for_navigation_with_the_same_bytes(scenario, tmp_path):
    system = NavTopo.create(config())
    with Simulator(scenario) as sim:
        sim.reset([0.0, 0.0, 0.0])
        for _ in range(30):
            system.observe(sim.observe())
            sim.step(Command(1.0, 0.0))
    system.save(tmp_path / "map")
    loaded = NavTopo.load(tmp_path / "map", config())
    assert loaded.graph.nbytes == system.graph.nbytes and len(loaded.graph) == len(system.graph)
    assert not loaded.maintainer.mapping
    assert TopologicalGraph.load(tmp_path / "map")[1]["navtopo_config"]["descriptor"] == "scan_context"


def test_global_localization_finds_the_location_and_the_pose_without_a_prior(scenario):
    """Map the corridor, then drop the robot anywhere along it facing anywhere: top-k place
    recognition plus scan matching puts it in a location, at its true pose."""
    system = NavTopo.create(config())
    true_at = {}
    with Simulator(scenario) as sim:
        sim.reset([0.0, 0.0, 0.0])
        drive(system, sim, [[0.0, 0.0], [20.0, 0.0]], true_at)
        vertex_truth = [true_at[v.stamp] for v in system.graph.vertices]
        localizer = system.maintainer.localizer
        located = 0
        for truth in ([1.0, 0.5, 2.5], [9.0, -0.3, -1.0], [15.5, 0.2, 3.0], [20.5, -0.5, 0.4]):
            points = sim.scan(np.array(truth))
            query = prepare(grid_from_points(points, system.config.grid), system.config.grid, system.config.matching)
            found = localizer.localize(query, system.descriptor.embed(points))
            if not found:
                continue
            estimate = se2.compose(vertex_truth[found[0].vertex], found[0].pose)
            assert se2.distance(estimate, truth) < 0.2  # never a wrong place
            assert abs(se2.wrap_angle(estimate[2] - truth[2])) < np.radians(3)
            located += 1
    assert located >= 3


def bare_maintainer(config, graph: TopologicalGraph | None = None):
    """A mapping maintainer of ``config`` on ``graph`` (an empty one): one descriptor for every scan,
    the default grids, matcher and localization."""
    from navkit.scan_grid import GridConfig
    from navtopo.localization import LocalizationConfig
    from navtopo.mapping import GraphMaintainer
    from navtopo.scan_matching import MatchingConfig

    graph = TopologicalGraph(4) if graph is None else graph
    return GraphMaintainer(
        graph, lambda points: np.ones(4, np.float32), GridConfig(), MatchingConfig(), config, LocalizationConfig()
    )


def test_gated_corrections_allow_what_the_odometry_travelled_since_the_last_verified_pose_explains():
    """``mapping.correction_per_metre``: a correction may move the pose by at most base + k x the
    odometry travelled since the pose was last verified (never more than max_correction)."""
    from navtopo.mapping import MappingConfig

    def limits(config: MappingConfig, travelled: list[float]) -> list[float]:
        maintainer = bare_maintainer(config)
        maintainer.current = 0
        seen = []
        maintainer.localizer.verify = lambda query, vertex, guess, max_jump: seen.append(max_jump)  # never verifies
        odom = np.zeros(3)
        maintainer.integrate(odom)
        for step in travelled:
            odom = odom + np.array([step, 0.0, 0.0])
            maintainer.integrate(odom)
            maintainer._correct(None)
        return seen

    assert limits(MappingConfig(correction_per_metre=None), [0.25, 0.25]) == [0.5, 0.5]  # off: max_correction alone
    gated = MappingConfig(correction_per_metre=0.2, correction_base=0.05)  # the defaults
    assert limits(gated, [0.25, 0.25, 5.0]) == pytest.approx([0.1, 0.15, 0.5])  # 0.05 + 0.2 x 0.25, x 0.5; capped


def test_a_correction_turning_the_pose_more_than_the_odometry_since_explains_is_refused():
    """``mapping.correction_turn_deg`` (the default): a correction that turns the
    tracked pose, together with the corrections taken in the last ``correction_turn_window`` metre,
    by more than 2° + 2°/m of the odometry travelled since the last verified pose is no correction
    (the pose keeps odometry's heading, the refusal counted); within it, the match's pose is taken.
    Steps of under 2° at a location's rim add up (a held-out aliased ring's pose turned 4.4° so), a
    match turning the pose back is taken, and a correction a metre on is judged afresh."""
    from types import SimpleNamespace

    from navtopo.mapping import MappingConfig

    def maintainer_with(config: MappingConfig):
        maintainer = bare_maintainer(config)
        maintainer.current, maintainer.pose_in_current = 0, np.array([1.0, 0.5, 0.3])
        maintainer.integrate(np.zeros(3))
        return maintainer

    def correct(maintainer, turn_deg: float, travelled: float = 0.0, overlap: float = 1.0) -> tuple[bool, float, int]:
        maintainer.integrate(maintainer._odom.last + np.array([travelled, 0.0, 0.0]))
        matched = maintainer.pose_in_current + np.array([0.02, 0.0, np.radians(turn_deg)])
        maintainer.localizer.verify = lambda query, vertex, guess, max_jump: SimpleNamespace(
            vertex=vertex, pose=matched.copy(), result=SimpleNamespace(covariance=None, overlap=overlap)
        )
        taken = maintainer._correct(None)
        return taken, float(np.degrees(maintainer.pose_in_current[2] - 0.3)), maintainer.counters.refused_turns

    # the defaults, the agreement with the fit alone (a test of its own) apart
    gated = MappingConfig(correction_turn_deg=2.0, correction_turn_per_metre_deg=2.0, correction_agreement=False)
    assert correct(maintainer_with(gated), 1.5) == (True, pytest.approx(1.5), 0)
    assert correct(maintainer_with(gated), 4.8, 0.9) == (False, pytest.approx(0.0), 1)  # over 2 + 2 x 0.9 = 3.8
    assert correct(maintainer_with(gated), 4.8, 1.5) == (True, pytest.approx(4.8), 0)  # 5° allowed after 1.5 m
    off = MappingConfig(correction_turn_deg=None, correction_agreement=False)
    assert correct(maintainer_with(off), 4.8, 0.9) == (True, pytest.approx(4.8), 0)

    rim = maintainer_with(gated)  # matches at a location's rim, each verified: 0.1 m of odometry since
    assert correct(rim, 1.5, 0.1) == (True, pytest.approx(1.5), 0)
    assert correct(rim, 1.5, 0.1) == (False, pytest.approx(1.5), 1)  # 3° in 0.2 m, over 2 + 2 x 0.1
    assert correct(rim, -1.5, 0.1) == (True, pytest.approx(0.0), 1)  # back: 0° in all
    assert correct(rim, 1.5, 0.1) == (True, pytest.approx(1.5), 1)  # 1.5 - 1.5 + 1.5 within the metre
    assert correct(rim, 1.5, 1.2) == (True, pytest.approx(3.0), 1)  # a metre on, the window empty: 1.5° alone
    alone = maintainer_with(gated.model_copy(update={"correction_turn_window": 0.0}))
    assert [correct(alone, 1.5, 0.1)[0] for _ in range(3)] == [True, True, True]  # each correction alone: 4.5° in all


def corridor_with_side_room(tmp_path: Path) -> Path:
    """A 14 m corridor and, through a 1 m door at x = 4.5, a 5 x 4 m room whose far corner the
    corridor cannot see."""
    spec = {
        "format": "navtopo-scenario/1",
        "name": "side_room",
        "world": {
            "rooms": [
                {"center": [6.5, 4.5], "size": [5.0, 4.0]},  # x 4-9, y 2.5-6.5
                {"center": [4.5, 1.75], "size": [1.0, 1.5]},  # the door through the wall
            ],
            "corridors": [{"points": [[-1, 0], [15, 0]], "width": 2.0}],
            "obstacles": [{"center": [8.0, 1.8], "size": [0.4, 0.4], "height": 1.0}],
        },
        "mapping_route": {"waypoints": [[0.5, 0], [13, 0]]},
        "trials": [],
    }
    path = tmp_path / "side_room.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.mark.parametrize("seen_only", [True, False])
def test_a_room_entered_through_a_door_gets_a_location_of_its_own(tmp_path, seen_only):
    # from the corridor the room is seen only through its door: with seen_only (the default) the
    # robot in the room's far part is outside the corridor's location and maps the room as a place
    scenario = load_scenario(corridor_with_side_room(tmp_path))
    system = NavTopo.create(NavTopoConfig(descriptor="scan_context", mapping={"seen_only": seen_only}))
    true_at: dict = {}
    with Simulator(scenario) as sim:
        sim.reset([0.5, 0.0, 0.0])
        drive(system, sim, [[0.5, 0.0], [4.5, 0.0], [4.5, 3.2], [8.0, 5.7], [4.5, 3.2], [4.5, 0.0], [13.0, 0.0]], true_at)
        assert sim.collisions == 0
    in_room = [v for v in system.graph.vertices if true_at[v.stamp][1] > 2.6]
    assert bool(in_room) == seen_only
    for u, v, pose_uv in system.graph.edges():
        truth = se2.between(true_at[system.graph.vertices[u].stamp], true_at[system.graph.vertices[v].stamp])
        error = se2.between(truth, pose_uv)
        assert np.hypot(error[0], error[1]) < 0.3 and abs(np.degrees(error[2])) < 3.0


def test_an_edge_weighs_its_measurements_by_their_covariance():
    """A sure measurement (0.05°) and an unsure one (1°, a degree away): the edge stays within a
    hundredth of a degree of the sure one — the information-weighted mean, (1/0.05²·0 + 1/1²·1) /
    (1/0.05² + 1/1²) = 0.0025°; a plain mean would be 0.5°."""
    from navtopo.mapping import EdgeEstimate

    sure = np.diag([0.01**2, 0.01**2, np.radians(0.05) ** 2])
    unsure = np.diag([0.01**2, 0.01**2, np.radians(1.0) ** 2])
    edge = EdgeEstimate.first(np.array([5.0, 0.0, 0.0]), sure)
    edge.fuse(np.array([5.0, 0.0, np.radians(1.0)]), unsure)
    assert abs(np.degrees(edge.pose[2]) - 0.0025) < 1e-3 and edge.count == 2
    assert np.allclose(edge.pose[:2], [5.0, 0.0])


def small_ring(tmp_path: Path) -> Path:
    """A 16 x 8 m ring of 2 m corridors with niches and two boxes."""
    spec = {
        "format": "navtopo-scenario/1",
        "name": "small_ring",
        "world": {
            "corridors": [{"points": [[0, 0], [16, 0], [16, 8], [0, 8], [0, 0]], "width": 2.0}],
            "rooms": [
                {"center": [4, -1.4], "size": [1.2, 0.8]},
                {"center": [7, -1.4], "size": [0.8, 0.8]},
                {"center": [11, 1.4], "size": [1.6, 0.8]},
                {"center": [16, 3], "size": [2.8, 1.2]},
                {"center": [9, 8], "size": [1.4, 2.8]},
                {"center": [0, 5], "size": [2.6, 1.0]},
            ],
            "obstacles": [
                {"center": [1.5, -0.7], "size": [0.4, 0.4], "height": 1.0},
                {"center": [13, 0.7], "size": [0.5, 0.3], "height": 1.0},
            ],
        },
        "mapping_route": {"waypoints": [[2, 0], [16, 0]]},
        "trials": [],
    }
    path = tmp_path / "small_ring.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def ring_unjoined(system: NavTopo, scenario, true_at: dict) -> list[tuple[int, int]]:
    """Asserts every edge of the graph within 0.3 m and 3 degrees of the truth; returns the pairs of
    locations the runner's measure finds unjoined (``unjoined_neighbours``, within 8 m)."""
    from runners.metrics import unjoined_neighbours

    for u, v, pose_uv in system.graph.edges():
        truth = se2.between(true_at[system.graph.vertices[u].stamp], true_at[system.graph.vertices[v].stamp])
        error = se2.between(truth, pose_uv)
        assert np.hypot(error[0], error[1]) < 0.3 and abs(np.degrees(error[2])) < 3.0
    positions = [true_at[v.stamp][:2] for v in system.graph.vertices]
    pairs = [(u, v) for u, v, _ in system.graph.edges()]
    return unjoined_neighbours(positions, pairs, scenario.world.clearances_at, scenario.spec.robot.radius, radius=8.0)


@pytest.mark.parametrize("closure_radius", [2.5, None])
def test_a_loop_closes_where_the_robot_passes_a_location_without_leaving_its_own(tmp_path, closure_radius):
    # round the ring from (3, 0), then back along the bottom to 2.3 m short of the first location
    # and away again: the last location (about 10 m along) holds the robot all that time, so it
    # never moves along an edge or localizes; only the closure from inside joins the two
    scenario = load_scenario(small_ring(tmp_path))
    system = NavTopo.create(NavTopoConfig(descriptor="scan_context", mapping={"closure_radius": closure_radius}))
    true_at: dict = {}
    with Simulator(scenario) as sim:
        sim.reset([3.0, 0.0, np.pi])
        drive(system, sim, [[3, 0], [0, 0], [0, 8], [16, 8], [16, 0], [5.3, 0], [12, 0]], true_at)
        assert sim.collisions == 0
    first, last = 0, len(system.graph) - 1
    assert np.hypot(*(true_at[system.graph.vertices[last].stamp][:2] - [3.0, 0.0])) < 8.0  # passed within 2.5 m
    assert system.graph.has_edge(first, last) == (closure_radius is not None)
    # every edge true, and the runner's measure of the gap (with a radius that takes in these 7 m)
    assert ring_unjoined(system, scenario, true_at) == ([] if closure_radius else [(first, last)])
    assert system.maintainer.counters.closures_from_inside == (1 if closure_radius else 0)


@pytest.mark.parametrize("shortcut_radius", [8.0, None])
def test_mapping_ends_by_joining_locations_the_graph_joins_only_the_long_way_round(tmp_path, shortcut_radius):
    """The drive above without the closure from inside: the first and the last location, 7 m apart
    along the bottom corridor, are joined only round the ring. The shortcut pass at mapping's end
    joins them (their grids matched, a way between them through both grids' free space, the
    loop-closure check passed), at the true relative pose; with it off they stay apart. (The two
    grids, 7 m apart round the ring's boxes, agree on 85 % of their walls at the true pose: the
    shortcut pass's own verdict, ``shortcut_wall_agreement``, takes them; the matcher's 90 % would not.)"""
    scenario = load_scenario(small_ring(tmp_path))
    mapping = {"closure_radius": None, "shortcut_radius": shortcut_radius}
    config = NavTopoConfig(descriptor="scan_context", mapping=mapping)
    system = NavTopo.create(config)
    true_at: dict = {}
    with Simulator(scenario) as sim:
        sim.reset([3.0, 0.0, np.pi])
        drive(system, sim, [[3, 0], [0, 0], [0, 8], [16, 8], [16, 0], [5.3, 0], [12, 0]], true_at)
    first, last = 0, len(system.graph) - 1
    assert not system.graph.has_edge(first, last)
    system.finish_mapping()
    assert system.graph.has_edge(first, last) == (shortcut_radius is not None)
    assert system.maintainer.counters.shortcuts == (1 if shortcut_radius else 0)
    assert ring_unjoined(system, scenario, true_at) == ([] if shortcut_radius else [(first, last)])
    # every edge's length measured on the two grids: the way the robot drives between the two
    # observation points, no shorter than the true shortest way in the world (less a cell's
    # rounding) and at most a little longer
    from scenarios.route_space import polyline_length, shortest_path

    assert system.maintainer.counters.edges_measured == system.graph.edge_count
    for u, v, pose_uv in system.graph.edges():
        a, b = true_at[system.graph.vertices[u].stamp][:2], true_at[system.graph.vertices[v].stamp][:2]
        truth = polyline_length(shortest_path(scenario.world, scenario.passable, a, b))
        measured = system.graph.edge_length(u, v)
        assert system.graph.measured_edge(u, v) and measured >= np.hypot(pose_uv[0], pose_uv[1])
        assert truth - 0.15 <= measured <= 1.1 * truth + 0.3, (u, v, measured, truth)


@pytest.mark.parametrize("turn_agreement", [None, 1.0])
def test_a_shortcut_match_turned_from_its_seed_keeps_the_seed(tmp_path, monkeypatch, turn_agreement):
    """Two grids that share a fifth of their known area fix the turn between them to a few degrees,
    the locations' relaxed poses to a few tenths (BENCHMARKS.md, "Design choices: shortcuts seeded by
    the relaxed poses"). The small ring's shortcut, its match turned by 3 degrees as such a pair of
    grids can turn it: with ``shortcut_turn_agreement`` the edge keeps the seed, within 0.1 m and 0.5
    degrees of the truth; without it, the edge is the turned match."""
    from navtopo.localization import Localized

    scenario = load_scenario(small_ring(tmp_path))
    mapping = {"closure_radius": None, "shortcut_guess": "relaxed", "shortcut_turn_agreement": turn_agreement}
    system = NavTopo.create(NavTopoConfig(descriptor="scan_context", mapping=mapping))
    true_at: dict = {}
    with Simulator(scenario) as sim:
        sim.reset([3.0, 0.0, np.pi])
        drive(system, sim, [[3, 0], [0, 0], [0, 8], [16, 8], [16, 0], [5.3, 0], [12, 0]], true_at)
    localizer = system.maintainer.localizer
    verify = localizer.verify

    def turned(query, vertex, guess=None, *args, **kwargs):
        located = verify(query, vertex, guess, *args, **kwargs)
        if located is None:
            return None
        return Localized(located.vertex, located.pose + np.array([0.0, 0.0, np.radians(3.0)]), located.result)

    monkeypatch.setattr(localizer, "verify", turned)
    system.finish_mapping()
    first, last = 0, len(system.graph) - 1
    assert system.graph.has_edge(first, last)
    vertices = system.graph.vertices
    truth = se2.between(true_at[vertices[first].stamp], true_at[vertices[last].stamp])
    error = se2.between(truth, system.graph.edge(first, last))
    turn = abs(np.degrees(se2.wrap_angle(error[2])))
    if turn_agreement is None:
        assert 2.0 < turn < 4.0
    else:
        assert turn < 0.5 and np.hypot(error[0], error[1]) < 0.1


def test_a_place_far_from_the_robot_by_the_current_locations_hint_is_no_loop_closure_candidate():
    """Hints drift apart by what odometry travelled between their making: after a long route the
    gate around the robot's odometry is wide (3 m + 5 % of 1.3 km), but the robot's pose in the
    current location is scan-matched, and through that location's hint only the drift between the
    two locations' making counts. A location 26 m away that looks alike is left out; one 2 m away
    stays, with the gate it had."""
    from navkit.scan_grid import GridConfig
    from navtopo.local_grid import CroppedGrid
    from navtopo.localization import LocalizationConfig
    from navtopo.mapping import GraphMaintainer, MappingConfig
    from navtopo.scan_matching import MatchingConfig

    graph = TopologicalGraph(4)
    grid = CroppedGrid.from_grid(np.zeros((GridConfig().size, GridConfig().size), np.uint8))
    maintainer = GraphMaintainer(
        graph, lambda points: np.ones(4, np.float32), GridConfig(), MatchingConfig(), MappingConfig(), LocalizationConfig()
    )
    # made at these odometers: the robot is back in location 2, made early on; 0 was made 360 m later
    hints = {0: ([24.3, 17.2, -1.6], 390.0), 1: ([5.0, 2.0, 0.0], 40.0), 2: ([3.0, -1.0, 0.0], 30.0)}
    for vertex, (hint, travelled) in hints.items():
        graph.add_vertex(grid, np.ones(4), np.array(hint), float(vertex), travelled)
        maintainer._odometer_at_vertex[vertex] = travelled
    maintainer.current, maintainer.pose_in_current = 2, np.array([0.3, 3.8, 0.0])  # the robot at (3.3, 2.8)
    maintainer._odom.metres = maintainer._odometer_verified = 1310.0
    robot, gates = maintainer._hint_gates(np.array([3.3, 2.8, 1.6]), base=3.0)
    assert np.allclose(robot[:2], [3.3, 2.8])
    # 26 m off: the odometry gate alone (3 + 0.05 x 920 m = 49 m) let it in; through location 2's hint
    # the gate is 3 + 0.05 x (360 + 10) m = 21.5 m
    assert 0 not in gates
    assert gates[1] == pytest.approx(3.0 + 0.05 * 1270.0)


def test_with_drifting_odometry_the_lidar_hints_place_the_locations_in_the_map_frame(tmp_path):
    """Mapping two_rooms there and back (40 m) on odometry whose heading drifts 2°/√m: every
    location keeps a lidar-odometry pose beside its odometry pose, the map frame is placed by the
    lidar hints (the odometry is the odd one out) and every location lies within 0.15 m of the truth
    there, where the odometry hints are off by more; the hints survive saving and loading."""
    from navtopo.graph_poses import relaxed_poses

    spec = yaml.safe_load(two_rooms(tmp_path).read_text())
    spec["odometry"] = {"noise": {"translation": 0.02, "rotation_deg_per_m": 2.0}}
    path = tmp_path / "drifting.yaml"
    path.write_text(yaml.safe_dump(spec))
    system = NavTopo.create(config())
    true_at: dict[float, np.ndarray] = {}
    with Simulator(load_scenario(path), seed=3) as sim:
        sim.reset([0.0, 0.0, 0.0])
        drive(system, sim, [[0.0, 0.0], [20.0, 0.0], [0.5, 0.0]], true_at)
    graph = system.graph
    assert len(graph) >= 3 and all(v.lidar_hint is not None for v in graph.vertices)
    origin = true_at[graph.vertices[0].stamp]
    truth = np.array([se2.between(origin, true_at[v.stamp]) for v in graph.vertices])
    odometry = np.array([se2.between(graph.vertices[0].pose_hint, v.pose_hint) for v in graph.vertices])
    assert system.mapping_stats()["map_frame_hints"] == "lidar"
    placed = np.hypot(*(relaxed_poses(graph)[:, :2] - truth[:, :2]).T)
    assert placed.max() < 0.15
    assert np.hypot(*(odometry[:, :2] - truth[:, :2]).T).max() > 2 * placed.max()
    system.save(tmp_path / "map")
    loaded = NavTopo.load(tmp_path / "map", config())
    np.testing.assert_allclose(loaded.navigator.map_poses, relaxed_poses(graph), atol=1e-9)


def _ring_maintainer(heading_noise_deg: float = 0.1, seed: int = 0, mapping=None, edge_sigma: float = 0.02):
    """A mapped ring corridor 24 x 12 m, locations every 3 m made in order (edges measured with
    small errors, their matches claiming ``edge_sigma``), the robot back in the last location, 1.5 m
    short of the first: its true poses."""
    from navkit.scan_grid import GridConfig
    from navtopo.local_grid import CroppedGrid
    from navtopo.localization import LocalizationConfig
    from navtopo.mapping import GraphMaintainer, MappingConfig
    from navtopo.scan_matching import MatchingConfig

    corners = [(0.0, 0.0), (24.0, 0.0), (24.0, 12.0), (0.0, 12.0), (0.0, 1.5)]
    truth = poses_along(corners, 3.0)
    truth.append(np.array([0.0, 1.5, -np.pi / 2]))
    graph = TopologicalGraph(4)
    grid = CroppedGrid.from_grid(np.zeros((GridConfig().size, GridConfig().size), np.uint8))
    maintainer = GraphMaintainer(
        graph,
        lambda points: np.ones(4, np.float32),
        GridConfig(),
        MatchingConfig(),
        mapping or MappingConfig(),
        LocalizationConfig(),
    )
    rng = np.random.default_rng(seed)
    covariance = np.diag([edge_sigma**2, edge_sigma**2, np.radians(0.1) ** 2])  # what the matcher reports
    for k, pose in enumerate(truth):
        graph.add_vertex(grid, np.ones(4), pose, float(k), 3.0 * k)
        if k:
            measured = se2.between(truth[k - 1], pose) + rng.normal(0, [0.02, 0.02, np.radians(heading_noise_deg)])
            maintainer._new_edge(k - 1, k, measured, covariance)
    maintainer.current = len(truth) - 1
    return maintainer, truth, covariance


def test_a_loop_closure_to_a_look_alike_place_is_refused_and_the_right_one_accepted():
    """Ground truth: the robot, back at the ring's start, matches a location. The right one (the
    first, 1.5 m ahead) agrees with the pose composed round the ring and closes the loop; a
    look-alike 3 m further along the same corridor (a row of identical rooms: the match says
    "1.5 m ahead" there too) and the mirror-image place across the ring (the same view turned half
    round) disagree with it and are refused, and counted."""
    maintainer, truth, covariance = _ring_maintainer()
    current = maintainer.current
    right = se2.between(truth[current], truth[0])
    assert maintainer._edge_acceptable(current, 0, right, covariance)
    assert maintainer.counters.loop_closures == 1 and maintainer.counters.rejected_closures == 0
    # the look-alike one location on: the same relative pose, but the graph puts it 3 m further
    assert not maintainer._edge_acceptable(current, 1, right, covariance)
    # the mirror place: location 12 (at (24, 12), facing the other way) seen as the first one
    assert not maintainer._edge_acceptable(current, 12, right, covariance)
    assert maintainer.counters.rejected_closures == 2 and maintainer.counters.loop_closures == 1
    assert [accepted for *_, accepted in maintainer.closure_checks] == [True, False, False]
    # each check kept for the audit: the way round composed from edges 2 cm off each, the right
    # closure on it within a few decimetres, the look-alike a corridor's 3 m further, refused by the gate
    checks = maintainer.edge_checks
    assert [(c.u, c.v, c.way, c.verdict) for c in checks] == [
        (current, 0, "loop", "accepted"),
        (current, 1, "loop", "gate"),
        (current, 12, "loop", "gate"),
    ]
    assert np.hypot(*(np.asarray(checks[0].composed[:2]) - right[:2])) < 0.4
    truth_1 = se2.between(truth[current], truth[1])
    assert np.hypot(*(np.asarray(checks[1].composed[:2]) - truth_1[:2])) < 0.4
    assert checks[0].distance < 16.27 < checks[1].distance


def test_the_closure_check_admits_the_drift_of_a_long_way_round():
    """The pose composed round the ring carries every edge's error: with headings 0.3° off per edge
    (the edges' usual worst) the right closure is accepted for every draw, and a look-alike 3 m on
    still refused."""
    for seed in range(10):
        maintainer, truth, covariance = _ring_maintainer(heading_noise_deg=0.3, seed=seed)
        current = maintainer.current
        right = se2.between(truth[current], truth[0])
        assert maintainer._edge_acceptable(current, 0, right, covariance), seed
        assert not maintainer._edge_acceptable(current, 1, right, covariance), seed


def test_a_look_alike_closure_the_edges_cannot_tell_apart_is_refused_by_the_lidar_hints():
    """Ground truth: a ring mapped along corridors whose matches fix little (each edge claims 1.2 m,
    as along a rack hall's aisles), the lidar odometry's hints 0.1 m from the truth. The chain round
    the ring admits the look-alike one location (3 m) on, and the closure check alone accepts it;
    with ``closure_hint_gate`` it is refused, as 3 m from where the hints put that location, and
    counted, while the right closure is still accepted."""
    from navtopo.mapping import MappingConfig

    for gate, look_alike_accepted in ((None, True), (1.0, False)):
        maintainer, truth, covariance = _ring_maintainer(mapping=MappingConfig(closure_hint_gate=gate), edge_sigma=1.2)
        rng = np.random.default_rng(1)
        for vertex, pose in zip(maintainer.graph.vertices, truth, strict=True):
            vertex.lidar_hint = pose + rng.normal(0.0, [0.1, 0.1, np.radians(0.2)])
        current = maintainer.current
        right = se2.between(truth[current], truth[0])
        assert maintainer._edge_acceptable(current, 1, right, covariance) is look_alike_accepted
        assert maintainer.counters.hint_rejected_closures == (0 if look_alike_accepted else 1)
        assert maintainer._edge_acceptable(current, 0, right, covariance)


def test_a_look_alike_closure_in_the_map_is_undone_when_the_right_place_contradicts_it():
    """Ground truth: a closure joined the ring's last location to the second one (a look-alike 3 m
    along: its edge says "1.5 m ahead"). The robot then matches the first location, truly 1.5 m
    ahead: that disagrees with the way round over the wrong closure but agrees with the chain made
    driving, and the wrong closure disagrees with that chain: it is undone and the right one made."""
    maintainer, truth, covariance = _ring_maintainer()
    last = maintainer.current
    right = se2.between(truth[last], truth[0])
    maintainer._new_edge(last, 1, right, covariance)  # the look-alike closure, already in the map
    maintainer._closure_edges.add((1, last))
    assert maintainer._edge_acceptable(last, 0, right, covariance)
    assert not maintainer.graph.has_edge(last, 1)
    assert maintainer.counters.undone_closures == 1 and maintainer.counters.loop_closures == 1
    # a closure no earlier one contradicts: nothing undone
    maintainer.graph.add_edge(last, 0, right)
    assert not maintainer._edge_acceptable(last, 1, right, covariance)
    assert maintainer.counters.undone_closures == 1


def _agreeing_maintainer(positions: list[tuple[float, float]], edges: list[tuple[int, int]]):
    """A navigating maintainer on locations at ``positions`` joined by ``edges``, every match verified."""
    from types import SimpleNamespace

    from navkit.scan_grid import GridConfig, grid_from_points
    from navtopo.graph import TopologicalGraph
    from navtopo.local_grid import CroppedGrid
    from navtopo.localization import LocalizationConfig
    from navtopo.mapping import GraphMaintainer, MappingConfig
    from navtopo.scan_matching import MatchingConfig

    grid_config = GridConfig()
    graph = TopologicalGraph(4)
    grid = CroppedGrid.from_grid(grid_from_points(np.array([[3.0, 2.0, 0.5], [3.0, -2.0, 0.5]], np.float32), grid_config))
    poses = [np.array([x, y, 0.0]) for x, y in positions]
    for k, pose in enumerate(poses):
        graph.add_vertex(grid, np.ones(4, np.float32), pose, float(k))
    for u, v in edges:
        graph.add_edge(u, v, poses[v] - poses[u])
    describe = lambda points: np.ones(4, np.float32)  # noqa: E731
    maintainer = GraphMaintainer(graph, describe, grid_config, MatchingConfig(), MappingConfig(), LocalizationConfig(), False)
    maintainer.localizer.verify = lambda query, vertex, guess, jump: SimpleNamespace(  # every match verifies
        pose=np.asarray(guess, float), result=SimpleNamespace(covariance=None, overlap=1.0)
    )
    return maintainer


def test_a_robot_that_just_moved_into_a_location_is_not_moved_straight_back():
    """Navigating, between two locations that both verify the robot (here every match does): once
    moved from location 0 into 1, no move along the edge back into 0 before the robot has driven
    ``shuttle_guard`` metres (moved back and forth at every update, each move a plan in another
    frame, a robot turned on the spot until it was stuck); after that, as before."""
    maintainer = _agreeing_maintainer([(0.0, 0.0), (3.0, 0.0)], [(0, 1)])
    config = maintainer.config
    maintainer.start_at(0, np.array([1.6, 0.0, 0.0]), np.zeros(3))  # nearer to 1's position than to 0's
    assert maintainer._move_along_edge(None) and maintainer.current == 1
    assert not maintainer._move_along_edge(None) and maintainer.current == 1  # not straight back
    maintainer.integrate(np.array([config.shuttle_guard + 0.1, 0.0, 0.0]))  # driven on
    maintainer.pose_in_current = np.array([-1.6, 0.0, 0.0])
    assert maintainer._move_along_edge(None) and maintainer.current == 0


def test_no_location_left_is_moved_back_into_along_an_edge_not_only_the_last():
    """Three locations at one junction, each verifying the robot: 0 -> 1 -> 2, then not on to 0, left
    a moment before (the last one left is 1); the robot went round 4 -> 5 -> 6 -> 4 at every update
    (slam-ring 904, noisy, a `timeout` standing at the junction)."""
    maintainer = _agreeing_maintainer([(0.0, 0.0), (3.0, 0.0), (1.5, 1.0)], [(0, 1), (1, 2), (0, 2)])
    maintainer.start_at(0, np.array([2.0, 0.0, 0.0]), np.zeros(3))
    assert maintainer._move_along_edge(None) and maintainer.current == 1  # the nearest neighbour
    assert maintainer._move_along_edge(None) and maintainer.current == 2  # 0 just left: the other one
    assert not maintainer._move_along_edge(None) and maintainer.current == 2  # both left a moment ago


@pytest.mark.parametrize("turned_deg", [0.0, 2.0])
def test_an_edge_measurement_from_a_match_away_from_the_walls_nearest_its_guess_is_left_out(turned_deg):
    """Two locations 2.5 m apart along a corridor with rooms; the robot in the first, as near the
    second. The scan matched against the second measures their edge when the match lands at the
    walls nearest its guess (the truth here); a match turned 2° from there (one that fell into a
    neighbouring minimum, its covariance as sure as ever) is left out and counted, the edge as it was."""
    import dataclasses

    from navkit.scan_grid import GridConfig
    from navtopo.local_grid import CroppedGrid
    from navtopo.mapping import MappingConfig
    from navtopo.scan_matching import MatchingConfig

    try:
        from test_scan_matching import grid_at
    except ImportError:  # tests/ collected as a package
        from tests.test_scan_matching import grid_at

    first, second, robot = np.array([9.0, 0.0, 0.0]), np.array([11.5, 0.2, 0.1]), np.array([10.3, -0.1, 0.05])
    graph = TopologicalGraph(4)
    for k, pose in enumerate((first, second)):
        graph.add_vertex(CroppedGrid.from_grid(grid_at(pose)), np.ones(4, np.float32), pose, float(k))
    maintainer = bare_maintainer(MappingConfig(measure_agreement=0.1, measure_agreement_deg=1.0), graph)  # the defaults
    edge = se2.between(first, second)
    maintainer._new_edge(0, 1, edge, np.diag([0.02**2, 0.02**2, np.radians(0.5) ** 2]))
    maintainer.current, maintainer.pose_in_current = 0, se2.between(first, robot)
    maintainer.pose_covariance = np.diag([0.01**2, 0.01**2, np.radians(0.2) ** 2])
    verify = maintainer.localizer.verify

    def turned(query, vertex, guess, jump):
        located = verify(query, vertex, guess, jump)
        pose = located.result.pose + np.array([0.0, 0.0, np.radians(turned_deg)])
        return dataclasses.replace(located, pose=pose, result=dataclasses.replace(located.result, pose=pose))

    maintainer.localizer.verify = turned
    maintainer._measure_neighbour(prepare(grid_at(robot), GridConfig(), MatchingConfig()))
    estimate = maintainer._edges[(0, 1)]
    if turned_deg:
        assert (estimate.count, maintainer.counters.ambiguous_measurements) == (1, 1)
        assert np.array_equal(graph.edge(0, 1), edge)
    else:
        assert (estimate.count, maintainer.counters.ambiguous_measurements) == (2, 0)
        error = se2.between(edge, graph.edge(0, 1))
        assert np.hypot(error[0], error[1]) < 0.05 and abs(error[2]) < np.radians(0.5)


def test_navigating_a_re_localization_into_the_look_alike_room_next_door_is_refused():
    """Ground truth: a row of identical rooms 4 m apart, one location in each, joined along the
    corridor; the robot, tracked in room 2 at 0.5 m from its centre, loses it (no match in room 2)
    and localizes globally. The twin room 1 matches as well ("0.5 m from the centre") but lies 4 m
    from where tracking puts the robot: refused and counted (a generated wing's robot re-localized so
    into the room next door, then room after room). Room 3, matched where the robot truly stands, is
    taken. After 40 m without a verified pose, tracking says little and the twin is taken; with
    ``relocalize_gate`` off, as before."""
    from types import SimpleNamespace

    from navtopo.localization import Localized
    from navtopo.mapping import MappingConfig

    def relocalized(found_in: list[tuple[int, list[float]]], travelled: float = 0.0, gate: float | None = 1.0):
        maintainer = _agreeing_maintainer([(0.0, 0.0), (4.0, 0.0), (8.0, 0.0), (12.0, 0.0)], [(0, 1), (1, 2), (2, 3)])
        maintainer.config = MappingConfig(relocalize_gate=gate)
        maintainer.start_at(2, np.array([0.5, 0.0, 0.0]), np.zeros(3))  # truly at x = 8.5
        maintainer.integrate(np.array([travelled, 0.0, 0.0]))
        maintainer.pose_in_current = np.array([0.5, 0.0, 0.0])  # odometry kept it (the drive was a turn)
        match = SimpleNamespace(covariance=None, overlap=1.0)
        maintainer.localizer.localize = lambda *args, **kwargs: [
            Localized(vertex, np.array(pose), match) for vertex, pose in found_in
        ]
        taken = maintainer._localize(None, np.zeros((0, 3), np.float32), np.zeros(3))
        return taken, maintainer.current, maintainer.counters.refused_relocalizations

    twin = (1, [0.5, 0.0, 0.0])  # the same view in the room 4 m west
    truth = (3, [-3.5, 0.0, 0.0])  # room 3's frame: 8.5 - 12
    assert relocalized([twin]) == (False, 2, 1)
    assert relocalized([twin, truth]) == (True, 3, 1)
    assert relocalized([(3, [-3.0, 0.3, 0.0])]) == (True, 3, 0)  # 0.58 m off: within 1 m + 0.05 x 4 m of path
    assert relocalized([twin], travelled=40.0) == (True, 1, 0)  # 1 + 0.1 x 40 + 0.05 x 4 = 5.2 m: lost long ago
    assert relocalized([twin], gate=None) == (True, 1, 0)


def test_a_turning_correction_whose_match_leaves_the_nearest_fit_is_refused_with_correction_agreement(monkeypatch):
    """``mapping.correction_agreement``: a correction turning the pose more than
    ``measure_agreement_deg`` is taken only where the distance-field fit alone from the same guess
    lands with the match (a match at a location's rim turned a generated noisy mirror building's pose
    4.4° the wrong way, the fit alone 4.36° from it); one that turns less is taken unchecked."""
    from types import SimpleNamespace

    from navtopo import mapping as mapping_module
    from navtopo.mapping import MappingConfig

    def correct(turn_deg: float, fit_follows: bool, agreement: bool = True) -> tuple[bool, int, int]:
        maintainer = bare_maintainer(MappingConfig(correction_agreement=agreement, correction_turn_deg=None))
        maintainer.current, maintainer.pose_in_current = 0, np.array([1.0, 0.5, 0.3])
        maintainer.integrate(np.zeros(3))
        matched = maintainer.pose_in_current + np.array([0.02, 0.0, np.radians(turn_deg)])
        result = SimpleNamespace(covariance=None, overlap=1.0, pose=matched.copy())
        maintainer.localizer.verify = lambda query, vertex, guess, max_jump: SimpleNamespace(
            vertex=vertex, pose=matched.copy(), result=result
        )
        maintainer.localizer.grids.get = lambda vertex: None
        calls = []

        def fit(prepared, query, guess, matching, icp=True):
            calls.append(guess)
            return matched.copy() if fit_follows else np.asarray(guess, float).copy()

        monkeypatch.setattr(mapping_module, "refine", fit)
        taken = maintainer._correct(None)
        return taken, maintainer.counters.ambiguous_corrections, len(calls)

    assert correct(4.4, fit_follows=False) == (False, 1, 1)  # the fit stayed: the match is another minimum
    assert correct(4.4, fit_follows=True) == (True, 0, 1)  # the fit lands with the match: taken
    assert correct(0.5, fit_follows=False) == (True, 0, 0)  # a small turn: not checked
    assert correct(4.4, fit_follows=False, agreement=False) == (True, 0, 0)  # off (the default)


def test_a_shortcut_seed_nothing_corroborates_is_refused_and_one_the_way_confirms_kept():
    """Ground truth: locations 0, 1, 2 at (0, 0), (3, 4), (6, 0), the edges 0-1 and 1-2 exact. A
    shortcut 0-2 whose match shares too little known area to fix the pose keeps its seed (the
    relaxed poses); with ``shortcut_seed_agreement`` 0.2 m, a seed 0.34 m off is refused (the way
    0-1-2, 10 m for a 6 m pair, composes the truth), and counted; a seed 5 cm off is kept (the way
    agrees); a match that shares enough is not asked; without a short way the seed is kept, unless
    the weak match is asked too (``shortcut_seed_by: match_or_way``) and lands 0.35 m from it."""
    from navkit.scan_grid import GridConfig
    from navtopo.local_grid import CroppedGrid
    from navtopo.localization import LocalizationConfig, Localized
    from navtopo.mapping import GraphMaintainer, MappingConfig
    from navtopo.scan_matching import MatchingConfig, MatchResult

    truth = [np.array([0.0, 0.0, 0.0]), np.array([3.0, 4.0, 0.0]), np.array([6.0, 0.0, 0.0])]
    graph = TopologicalGraph(4)
    grid = CroppedGrid.from_grid(np.zeros((GridConfig().size, GridConfig().size), np.uint8))
    for k, pose in enumerate(truth):
        graph.add_vertex(grid, np.ones(4), pose, float(k), 5.0 * k)
    maintainer = GraphMaintainer(
        graph,
        lambda points: np.ones(4, np.float32),
        GridConfig(),
        MatchingConfig(),
        MappingConfig(shortcut_seed_agreement=0.2),
        LocalizationConfig(),
    )
    covariance = np.diag([0.02**2, 0.02**2, np.radians(0.2) ** 2])
    maintainer._new_edge(0, 1, se2.between(truth[0], truth[1]), covariance)
    maintainer._new_edge(1, 2, se2.between(truth[1], truth[2]), covariance)
    right = se2.between(truth[0], truth[2])
    path, length = graph.shortest_path(0, 2)
    assert path == [0, 1, 2] and length == pytest.approx(10.0)

    def located(seed, match, overlap):
        result = MatchResult(match, 0.1, True, 0, 0.9, overlap, 100, "guess", 1.0, covariance)
        return Localized(0, seed.copy(), result)

    off_seed, off_match = right + [0.34, 0.0, 0.0], right + [-0.3, 0.0, 0.0]
    assert not maintainer._seed_corroborated(located(off_seed, off_match, 0.15), off_seed, path, length, 6.34)
    assert maintainer.counters.uncorroborated_shortcuts == 1
    near_seed = right + [0.05, 0.0, 0.0]
    assert maintainer._seed_corroborated(located(near_seed, off_match, 0.15), near_seed, path, length, 6.05)
    # the match shares enough known area: its own pose is the edge, checked by the pass's other rules
    assert maintainer._seed_corroborated(located(off_match, off_match, 0.5), off_seed, path, length, 6.34)
    # without a short way (the graph joins them only the long way round) the seed is kept: a match
    # too weak to fix the pose is too weak to speak against it ...
    assert maintainer._seed_corroborated(located(near_seed, off_match, 0.15), near_seed, None, 0.0, 6.05)
    assert maintainer.counters.uncorroborated_shortcuts == 1
    # ... unless the weak match is asked too (shortcut_seed_by: match_or_way)
    maintainer.config = MappingConfig(shortcut_seed_agreement=0.2, shortcut_seed_by="match_or_way")
    assert not maintainer._seed_corroborated(located(near_seed, off_match, 0.15), near_seed, None, 0.0, 6.05)
    assert maintainer._seed_corroborated(located(off_seed, off_seed + [0.1, 0, 0], 0.15), off_seed, None, 0.0, 6.34)
    assert maintainer.counters.uncorroborated_shortcuts == 2
