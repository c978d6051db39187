"""Scan matching of location grids built from synthetic lidar clouds of known worlds."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from navkit.geometry import between, compose, inverse, wrap_angle
from navkit.raster import OCCUPIED
from navkit.scan_grid import GridConfig, grid_from_points
from navtopo.scan_matching import MatchingConfig, MatchResult, PreparedGrid, match

try:
    from test_local_grid import WALL_HEIGHT, RasterWorld, box_room, lidar_scan
except ImportError:  # tests/ collected as a package
    from tests.test_local_grid import WALL_HEIGHT, RasterWorld, box_room, lidar_scan


def building() -> RasterWorld:
    """A 34 m corridor (2.4 m wide) with irregular door niches, side rooms, a hall, furniture of
    several heights and a pillar: structure every few metres, as the bundled scenes have."""
    world = RasterWorld(-2.0, -9.0, 40.0, 18.0).add_box(-2.0, 38.0, -9.0, 9.0)  # solid rock
    heights = world.heights

    def carve(x0, x1, y0, y1):
        c0, c1 = (int(round((v - world.x0) / world.res)) for v in (x0, x1))
        r0, r1 = (int(round((v - world.y0) / world.res)) for v in (y0, y1))
        heights[r0:r1, c0:c1] = 0.0

    carve(0.0, 34.0, -1.2, 1.2)  # the corridor
    for x, width, depth in ((2.5, 1.0, 0.6), (8.7, 1.4, 0.5), (18.0, 0.9, 0.8), (27.5, 1.2, 0.6)):
        carve(x, x + width, 1.2, 1.2 + depth)  # door niches, north side
    for x, width, depth in ((5.0, 3.0, 4.0), (14.5, 5.0, 3.0), (25.0, 2.5, 5.0)):
        carve(x, x + width, -1.2 - depth, -1.2)  # side rooms, south side
    carve(11.0, 15.0, 1.2, 6.0)  # a hall, north side
    for box in (
        (7.0, 7.4, -1.2, -0.9, 1.0),
        (12.0, 12.8, 4.5, 5.2, 0.8),
        (16.0, 16.5, 0.7, 1.2, 0.5),
        (22.0, 22.3, -1.2, -0.8, 0.3),
        (30.0, 30.4, 0.8, 1.2, WALL_HEIGHT),  # a pillar
        (26.0, 27.0, -5.5, -5.0, 1.2),
    ):
        world.add_box(*box)
    return world


CONFIG = GridConfig()
WORLD = building()


def grid_at(pose, world=WORLD):
    return grid_from_points(lidar_scan(world, np.asarray(pose), ceiling=WALL_HEIGHT), CONFIG)


def pose_error(result: MatchResult, truth) -> tuple[float, float]:
    error = result.pose - truth
    return float(np.hypot(error[0], error[1])), float(np.degrees(abs(wrap_angle(error[2]))))


# reference at A; the query 2 m further along the corridor, 0.4 m aside, turned by 20°
POSE_A = np.array([9.0, 0.3, 0.1])
POSE_B = np.array([11.0, -0.1, 0.1 + np.radians(20.0)])


@pytest.fixture(scope="module")
def grids():
    return grid_at(POSE_A), grid_at(POSE_B)


def test_recovers_a_2m_20deg_offset_without_a_guess(grids):
    reference, query = grids
    result = match(reference, query)
    translation, rotation = pose_error(result, between(POSE_A, POSE_B))
    assert result.accepted and result.source == "features"
    assert translation < 0.1 and rotation < 1.0
    assert result.inliers >= 6 and result.wall_agreement > 0.9 and result.overlap > 0.5
    assert result.pose.shape == (3,) and result.pose.dtype == np.float64


def test_an_odometry_guess_is_refined(grids):
    reference, query = grids
    truth = between(POSE_A, POSE_B)
    guess = compose(truth, np.array([0.35, -0.25, np.radians(6.0)]))
    result = match(reference, query, initial_guess=guess)
    translation, rotation = pose_error(result, truth)
    assert result.accepted and translation < 0.1 and rotation < 1.0


def test_a_wrong_guess_does_not_stop_the_features(grids):
    """A guess 1.5 m and 25° off: ICP from it fails the verdict, the gated features still find
    the pose."""
    reference, query = grids
    truth = between(POSE_A, POSE_B)
    result = match(reference, query, initial_guess=compose(truth, np.array([1.2, 0.9, 0.44])))
    translation, rotation = pose_error(result, truth)
    assert result.accepted and translation < 0.1 and rotation < 1.0


def test_direction_convention_swaps_to_the_inverse(grids):
    """match(reference, query) is the query's pose in the reference frame, between(A, B); with
    the roles swapped it is between(B, A) = inverse(between(A, B))."""
    reference, query = grids
    forward = match(reference, query)
    backward = match(query, reference)
    assert backward.accepted
    translation, rotation = pose_error(backward, between(POSE_B, POSE_A))
    assert translation < 0.1 and rotation < 1.0
    roundtrip = compose(forward.pose, backward.pose)
    assert np.hypot(*roundtrip[:2]) < 0.1 and abs(roundtrip[2]) < np.radians(1.0)
    # the wrong convention (the inverse) is far from the answer
    assert np.hypot(*(inverse(forward.pose) - forward.pose)[:2]) > 1.0


def test_prepared_grids_give_the_same_result(grids):
    reference, query = grids
    plain = match(reference, query)
    prepared = match(PreparedGrid(reference, CONFIG), PreparedGrid(query, CONFIG))
    np.testing.assert_allclose(prepared.pose, plain.pose)
    assert prepared.score == pytest.approx(plain.score)


def test_a_prepared_grid_keeps_its_distance_field_and_nearest_walls_compact_and_exact(grids):
    """The distance field in 16-bit steps is OpenCV's float field to a step (saturated far past any
    cutoff), the nearest-wall lookup (index plus one, 16 bits) names a wall at that distance, and
    the tolerance in steps counts as the float32 field in metres did."""
    import cv2

    prepared = PreparedGrid(grids[0], CONFIG)
    walls = np.zeros_like(prepared.crop, dtype=np.uint8)  # the walls it matches to (closed: wall_closing)
    walls[prepared.occupied_cells[:, 0] - prepared.row0, prepared.occupied_cells[:, 1] - prepared.col0] = 1
    assert walls.sum() >= (prepared.crop == OCCUPIED).sum()
    metres = cv2.distanceTransform(1 - walls, cv2.DIST_L2, cv2.DIST_MASK_5) * np.float32(CONFIG.resolution)
    assert prepared.field.dtype == np.uint16 and prepared.nearest.dtype == np.uint16
    near = metres < 3.0
    assert np.abs(prepared.field[near] * prepared.field_unit - metres[near]).max() <= prepared.field_unit
    assert (prepared.field[~near] * prepared.field_unit >= 3.0 - prepared.field_unit).all()
    rows, cols = np.nonzero(prepared.nearest)
    walls_xy = prepared.occupied_cells[prepared.nearest[rows, cols].astype(np.int64) - 1]
    wall_distance = np.hypot(walls_xy[:, 0] - rows - prepared.row0, walls_xy[:, 1] - cols - prepared.col0) * CONFIG.resolution
    assert np.allclose(wall_distance[metres[rows, cols] < 1.0], metres[rows, cols][metres[rows, cols] < 1.0], atol=0.1)
    for tolerance in (0.1, 0.15, 0.2, 0.3):
        steps = prepared.steps_within(tolerance)
        assert np.array_equal(prepared.field[near] <= steps, metres[near].astype(np.float64) <= tolerance)


def test_different_places_are_rejected(grids):
    reference, _ = grids
    hall = grid_at(np.array([6.0, 5.0, 0.4]), world=box_room())
    far_in_corridor = grid_at(np.array([31.5, -0.2, -2.0]))  # 22 m away, turned
    for other in (hall, far_in_corridor):
        for guess in (None, np.zeros(3)):
            assert not match(reference, other, initial_guess=guess).accepted
            assert not match(other, reference, initial_guess=guess).accepted


def test_empty_grids_are_rejected_without_error(grids):
    reference, _ = grids
    empty = np.zeros_like(reference)
    result = match(reference, empty)
    assert not result.accepted and result.source == "none" and result.score == 0.0
    guess = np.array([1.0, 2.0, 0.3])
    np.testing.assert_allclose(match(empty, empty, initial_guess=guess).pose, guess)


def test_config_rejects_unknown_keys():
    with pytest.raises(ValidationError):
        MatchingConfig(ransac_iters=10)
    assert MatchingConfig().min_wall_agreement > 0.5


def _sigmas(result: MatchResult) -> tuple[float, float, float]:
    """One-sigma x, y (m) and yaw (degrees) of a match, from its covariance."""
    x, y, yaw = np.sqrt(np.diag(result.covariance))
    return float(x), float(y), float(np.degrees(yaw))


def test_a_bare_corridor_leaves_the_slide_along_it_less_certain():
    """Two parallel walls fix the cross-corridor offset, not the position along the corridor (only
    the walls' ends at the lidar's range do): the covariance says so, against the cross direction
    and against the building, whose niches and rooms fix both."""
    world = RasterWorld(-2.0, -5.0, 60.0, 10.0).add_box(-2.0, 58.0, -5.0, 5.0)
    world.heights[int(round(3.8 / world.res)) : int(round(6.2 / world.res)), :] = 0.0  # y in [-1.2, 1.2)
    a, b = np.array([20.0, 0.2, 0.0]), np.array([21.0, -0.1, 0.05])
    bare = match(grid_at(a, world), grid_at(b, world), initial_guess=between(a, b))
    built = match(grid_at(POSE_A), grid_at(POSE_B), initial_guess=between(POSE_A, POSE_B))
    sigma_x, sigma_y, _ = _sigmas(bare)
    assert sigma_x > 1.5 * sigma_y and sigma_x > 1.5 * _sigmas(built)[0]
    assert abs(bare.pose[1] - between(a, b)[1]) < 3.0 * sigma_y + 0.01  # the fixed direction is right


def test_the_covariance_grows_as_the_shared_walls_shrink():
    """A match 0.5 m from the reference shares most walls; one 5 m away shares few and fixes the
    rotation worse. Both poses are within a few of their sigmas of the truth."""
    near, far = np.array([9.5, 0.1, 0.12]), np.array([14.0, -0.2, 0.15])
    reference = grid_at(POSE_A)
    results = {}
    for name, pose in (("near", near), ("far", far)):
        truth = between(POSE_A, pose)
        result = match(reference, grid_at(pose), initial_guess=truth + np.array([0.1, -0.1, 0.02]))
        assert result.accepted
        translation, rotation = pose_error(result, truth)
        sigma_x, sigma_y, sigma_yaw = _sigmas(result)
        assert rotation < 5.0 * sigma_yaw + 0.05 and translation < 5.0 * np.hypot(sigma_x, sigma_y) + 0.02
        results[name] = sigma_yaw
    assert results["far"] > results["near"]


def test_a_hint_off_by_more_than_the_guess_window_still_finds_the_place_within_its_gate():
    """Localizing with an odometry hint that drift has moved 4 m (a loop coming round): the hinted
    match misses (its features are looked for within 2 m of the guess), the unguided one finds the
    true pose, and it is kept because the gate (6 m) allows it — but not with a 3 m gate."""
    from navtopo.graph import TopologicalGraph
    from navtopo.local_grid import CroppedGrid
    from navtopo.localization import LocalizationConfig, Localizer, VertexGrids

    graph = TopologicalGraph(4)
    reference = grid_at(POSE_A)
    graph.add_vertex(CroppedGrid.from_grid(reference), np.ones(4, dtype=np.float32), np.zeros(3), stamp=0.0)
    matching = MatchingConfig()
    localizer = Localizer(graph, VertexGrids(graph, CONFIG, matching, 4), LocalizationConfig(near_k=0), matching, CONFIG)
    truth = between(POSE_A, POSE_B)
    # the robot by odometry, in the hints' frame (the vertex's hint is the origin): 4 m back
    drifted_hint = truth + np.array([-4.0, 0.0, np.radians(4.0)])
    assert np.hypot(*drifted_hint[:2]) < 3.0  # a candidate for both gates below
    query = PreparedGrid(grid_at(POSE_B), CONFIG, matching)
    assert localizer.verify(query, 0, drifted_hint, 6.0, strict=True) is None  # the hinted match alone misses
    found = localizer.localize(query, np.ones(4, dtype=np.float32), robot_hint=drifted_hint, hint_gate={0: 6.0})
    assert len(found) == 1 and pose_error(found[0].result, truth)[0] < 0.1
    # 4 m from the hint is more than a 3 m gate allows
    assert localizer.localize(query, np.ones(4, dtype=np.float32), robot_hint=drifted_hint, hint_gate={0: 3.0}) == []


def _hall_graph(c_x: float):
    """A - B - C: A and C on the corridor (C at ``c_x``, west), B a hall off it; the graph, the
    poses, the vertex ids and a maintainer factory (navigating)."""
    from navtopo.graph import TopologicalGraph
    from navtopo.local_grid import CroppedGrid
    from navtopo.localization import LocalizationConfig
    from navtopo.mapping import GraphMaintainer, MappingConfig

    poses = {"A": np.array([12.5, 0.0, 0.0]), "B": np.array([13.0, 5.0, np.pi / 2]), "C": np.array([c_x, 0.0, np.pi])}
    graph = TopologicalGraph(4)
    ids = {}
    for name, pose in poses.items():
        grid = CroppedGrid.from_grid(grid_at(pose))
        ids[name] = graph.add_vertex(grid, np.ones(4, dtype=np.float32), pose, stamp=float(len(ids)))
    graph.add_edge(ids["A"], ids["B"], between(poses["A"], poses["B"]))
    graph.add_edge(ids["B"], ids["C"], between(poses["B"], poses["C"]))
    describe = lambda points: np.ones(4, dtype=np.float32)  # noqa: E731 - no recognition needed here

    def maintainer() -> GraphMaintainer:
        return GraphMaintainer(graph, describe, CONFIG, MatchingConfig(), MappingConfig(), LocalizationConfig(), mapping=False)

    return poses, ids, maintainer


def test_out_of_reach_the_path_s_next_vertex_is_tried_before_the_nearest_neighbour():
    """Navigating from B (a hall off the corridor) to C (west along the corridor) on a graph whose
    way there is A - B - C: back in the corridor, out of B's reach and nearest to A, the robot moves
    to C, the path's next vertex — not to A, whose path leads back through B (the robot shuttled
    between A and B)."""
    from navtopo.mapping import MappingConfig

    poses, ids, make = _hall_graph(5.5)
    maintainer = make()
    robot = np.array([11.5, 0.0, np.pi])
    to_b, to_c = (np.hypot(*(robot[:2] - poses[name][:2])) for name in "BC")
    assert MappingConfig().max_edge_length < to_b < to_c  # out of B's reach, yet not nearer to C
    maintainer.start_at(ids["B"], between(poses["B"], robot), robot)
    points = lidar_scan(WORLD, robot, ceiling=WALL_HEIGHT)
    happened = maintainer.update(points, robot, stamp=1.0, route=[ids["B"], ids["C"]], force=True)
    assert happened == "route" and maintainer.current == ids["C"]
    assert pose_error_of(maintainer.pose_in_current, between(poses["C"], robot)) < 0.1


def test_the_robot_is_not_moved_into_a_location_farther_than_any_location_holds_it():
    """As above, C 8 m west of the robot: beyond the reach a location holds the robot in (1.5 x the
    5 m of a location's extent), the route's next vertex is not where the robot is, though the match
    from the graph's pose agrees (a mirror building: moved into the goal's location 8.5 m from it,
    the robot stood off that location's union grid, and the plan to the goal had no start)."""
    from navtopo.mapping import MappingConfig

    poses, ids, make = _hall_graph(3.5)
    maintainer = make()
    robot = np.array([11.5, 0.0, np.pi])
    config = MappingConfig()
    assert np.hypot(*(robot[:2] - poses["C"][:2])) > config.stay_factor * config.max_edge_length
    maintainer.start_at(ids["B"], between(poses["B"], robot), robot)
    points = lidar_scan(WORLD, robot, ceiling=WALL_HEIGHT)
    happened = maintainer.update(points, robot, stamp=1.0, route=[ids["B"], ids["C"]], force=True)
    assert maintainer.current != ids["C"], happened


def pose_error_of(pose, truth) -> float:
    return float(np.hypot(*(np.asarray(pose)[:2] - np.asarray(truth)[:2])))


def test_a_path_cut_past_a_location_moves_the_robot_to_the_vertex_it_heads_for():
    """A local path cut straight past a location (A - B - C, B a hall off the corridor) ends at C,
    which no edge joins to A: at C's centre the robot moves to C through the route (``ahead``), where
    with the next vertex alone it stayed in A and planned the same path again (office02, precise)."""
    poses, ids, make = _hall_graph(8.5)
    robot = np.array([8.6, 0.1, np.pi])
    points = lidar_scan(WORLD, robot, ceiling=WALL_HEIGHT)
    route = [ids["A"], ids["B"], ids["C"]]
    outcomes = {}
    for ahead in (1, 2):
        maintainer = make()
        maintainer.start_at(ids["A"], between(poses["A"], robot), robot)
        outcomes[ahead] = (maintainer.update(points, robot, stamp=1.0, route=route, force=True, ahead=ahead), maintainer.current)
        if ahead == 2:
            assert pose_error_of(maintainer.pose_in_current, between(poses["C"], robot)) < 0.1
    assert outcomes[2] == ("route", ids["C"])
    assert outcomes[1][1] != ids["C"]  # by the next vertex alone: not where the robot stands


def test_wall_closing_joins_a_dashed_wall_and_leaves_a_door_open():
    """A wall seen at a grazing angle: one cell in every three is a return. Closed with a 5-cell
    square it is one row of walls; a 0.8 m doorway (8 cells) in it stays open."""
    size = CONFIG.size
    grid = np.full((size, size), 1, dtype=np.uint8)  # free
    row = size // 2 + 15
    dashed = list(range(20, 80, 3)) + list(range(88, 150, 3))  # a doorway between columns 79 and 88
    grid[row, dashed] = OCCUPIED
    raw = PreparedGrid(grid, CONFIG, MatchingConfig(wall_closing=0))
    closed = PreparedGrid(grid, CONFIG, MatchingConfig(wall_closing=5))
    assert len(raw.occupied_cells) == len(dashed)
    columns = set(closed.occupied_cells[:, 1].tolist())
    assert set(closed.occupied_cells[:, 0].tolist()) == {row}  # the row, nothing beside it
    assert set(range(20, 78)) <= columns and set(range(88, 148)) <= columns
    assert not columns & set(range(80, 87))  # the doorway


def test_the_verdict_counts_the_walls_seen_not_the_closed_ones():
    """Two chair legs 0.4 m apart, both seen from one place, one of them hidden from the other
    (which saw free floor there). Closing joins the legs into a bar for the fit; the verdict, counting
    the walls the lidar saw, holds the right match to what it is without closing (one leg agrees
    each way, the hidden one contradicts), not one contradiction per filled cell."""
    from navtopo.scan_matching import verdict

    size = CONFIG.size
    row = size // 2 + 10
    both = np.full((size, size), 1, dtype=np.uint8)
    both[row, [size // 2, size // 2 + 4]] = OCCUPIED
    one = np.full((size, size), 1, dtype=np.uint8)
    one[row, size // 2] = OCCUPIED
    closing, raw = MatchingConfig(wall_closing=5), MatchingConfig(wall_closing=0)
    closed = PreparedGrid(both, CONFIG, closing)
    assert len(closed.occupied_cells) == 5 and len(closed.seen_xy) == 2  # the bar fitted, the legs counted
    _, agreement, _, _ = verdict(PreparedGrid(one, CONFIG, closing), closed, np.zeros(3), closing)
    _, agreement_raw, _, _ = verdict(PreparedGrid(one, CONFIG, raw), PreparedGrid(both, CONFIG, raw), np.zeros(3), raw)
    assert agreement == pytest.approx(agreement_raw) == pytest.approx(2 / 3)


def test_tracking_keeps_odometry_along_a_corridor_the_match_cannot_fix():
    """In a bare corridor (no ends, no doors in sight) the match fixes the cross offset, not the
    position along it: with ``degenerate_ratio`` the maintainer takes the match's correction across
    the corridor and keeps its prediction along it, and in the building, whose niches and rooms fix
    both directions, it takes the match as it is."""
    from navtopo.graph import TopologicalGraph
    from navtopo.local_grid import CroppedGrid
    from navtopo.localization import LocalizationConfig
    from navtopo.mapping import GraphMaintainer, MappingConfig

    bare = RasterWorld(-2.0, -5.0, 60.0, 10.0).add_box(-2.0, 58.0, -5.0, 5.0)
    bare.heights[int(round(3.8 / bare.res)) : int(round(6.2 / bare.res)), :] = 0.0  # y in [-1.2, 1.2)
    describe = lambda points: np.ones(4, dtype=np.float32)  # noqa: E731 - no recognition needed here
    # the prediction 0.12 m off along the way and 0.06 m across it
    predicted_error = np.array([0.12, 0.06, 0.0])
    for world, anchor, robot, remapped in (
        (bare, np.array([20.0, 0.2, 0.0]), np.array([21.5, -0.1, 0.05]), True),
        (WORLD, POSE_A, np.array([10.5, 0.0, 0.15]), False),
    ):
        graph = TopologicalGraph(4)
        vertex = graph.add_vertex(CroppedGrid.from_grid(grid_at(anchor, world)), np.ones(4, np.float32), anchor, stamp=0.0)
        config = MappingConfig(degenerate_ratio=2.0, correction_per_metre=None)
        # closed walls, as the two options are used (the defaults): unclosed, the walls'
        # dashes claim to fix the slide (the covariance's axes within a factor of 2 here)
        matching = MatchingConfig(wall_closing=5)
        maintainer = GraphMaintainer(graph, describe, CONFIG, matching, config, LocalizationConfig(), mapping=False)
        truth = between(anchor, robot)
        maintainer.start_at(vertex, compose(truth, predicted_error), robot)
        happened = maintainer.update(lidar_scan(world, robot, ceiling=WALL_HEIGHT), robot, stamp=1.0, force=True)
        assert happened == "inside"
        # the error in the robot's frame (x: along its heading, the corridor's direction)
        error = between(truth, maintainer.pose_in_current)
        assert abs(error[1]) < 0.03  # across: corrected
        if remapped:
            assert maintainer.counters.remapped == 1
            assert abs(error[0] - predicted_error[0]) < 0.02  # along: the prediction's, kept
        else:
            assert maintainer.counters.remapped == 0
            assert abs(error[0]) < 0.05  # the building fixes it


def test_a_given_pose_is_not_committed_from_a_match_that_cannot_fix_it_along_a_corridor():
    """A start from a given pose 0.4 m off along a bare corridor: the match there fixes the offset
    across it, not the position along it (a rack hall's aisle: it slid 0.56 m and was committed, a
    wrong start-up), so nothing is committed from it at this look; in the building, whose niches and
    rooms fix both directions, the same given error is committed to the true pose."""
    from navkit.types import Observation
    from navtopo.graph import TopologicalGraph
    from navtopo.local_grid import CroppedGrid
    from navtopo.localization import LocalizationConfig
    from navtopo.mapping import GraphMaintainer, MappingConfig
    from navtopo.startup import Startup, StartupConfig

    bare = RasterWorld(-2.0, -5.0, 60.0, 10.0).add_box(-2.0, 58.0, -5.0, 5.0)
    bare.heights[int(round(3.8 / bare.res)) : int(round(6.2 / bare.res)), :] = 0.0  # y in [-1.2, 1.2)
    describe = lambda points: np.ones(4, dtype=np.float32)  # noqa: E731
    for world, anchor, robot, commits in (
        (bare, np.array([20.0, 0.2, 0.0]), np.array([21.5, -0.1, 0.05]), False),
        (WORLD, POSE_A, np.array([10.5, 0.0, 0.15]), True),
    ):
        graph = TopologicalGraph(4)
        graph.add_vertex(CroppedGrid.from_grid(grid_at(anchor, world)), np.ones(4, np.float32), anchor, stamp=0.0)
        maintainer = GraphMaintainer(graph, describe, CONFIG, MatchingConfig(), MappingConfig(), LocalizationConfig(), False)
        startup = Startup(maintainer, describe, StartupConfig())
        startup.map_poses = np.array([anchor])
        startup.set_prior(compose(robot, np.array([0.4, 0.0, 0.0])))  # 0.4 m ahead along the robot's heading
        committed = startup.step(Observation(0.0, lidar_scan(world, robot, ceiling=WALL_HEIGHT), np.zeros(3)))
        if not commits:
            assert committed is None and not startup.from_given_pose
            continue
        assert committed is not None and startup.from_given_pose
        assert float(np.hypot(*(compose(anchor, committed.pose)[:2] - robot[:2]))) < 0.1


def test_a_partial_view_does_not_slide_off_a_good_guess():
    """A route step in a rack hall (the bundled depot map, noisy odometry, replayed): the robot's
    scan against the next location shares 0.62 of the known area, and the guess (odometry and the
    edge) lies 0.028 m from the true pose. ICP's first stage, pairing cells up to a metre apart,
    slid it 0.46 m along the racks to a pose agreeing worse (0.91 against 0.98 at the guess); the
    match keeps the guess's own fit instead."""
    from pathlib import Path

    case = np.load(Path(__file__).parent / "data" / "rack_hall_route_step.npz")
    guess = case["guess"]
    result = match(case["reference"], case["query"], initial_guess=guess)
    assert result.accepted
    assert float(np.hypot(*(result.pose[:2] - guess[:2]))) < 0.05
    assert abs(wrap_angle(result.pose[2] - guess[2])) < np.radians(1.0)
    assert result.wall_agreement > 0.95


def test_each_wall_cell_faces_the_side_its_grid_saw_it_from():
    """A wall between two rooms, 0.2 m thick, seen from each room: the cells of its south face
    (seen from the south room) face south, those of its north face north, whatever way the robot
    heads; with the face test on, a grid matched against the other room's (the truth as the guess)
    pairs no wall cell, as the two faces are different surfaces: the fit has nothing to fix the pose by."""
    from navtopo.scan_matching import FACE_STEPS, covariance, prepare

    world = RasterWorld(-1.0, -6.0, 12.0, 12.0).add_box(-1.0, 11.0, -6.0, 6.0)
    rows = lambda y0, y1: slice(int(round((y0 + 6.0) / world.res)), int(round((y1 + 6.0) / world.res)))  # noqa: E731
    columns = slice(int(round(1.0 / world.res)), int(round(10.0 / world.res)))  # x in [0, 9)
    world.heights[rows(-5.0, -0.1), columns] = 0.0  # the south room
    world.heights[rows(0.1, 5.0), columns] = 0.0  # the north room
    south, north = np.array([4.0, -2.5, 0.7]), np.array([5.0, 2.5, -2.0])
    faces = MatchingConfig(face_angle=120.0)
    grids = {name: prepare(grid_at(pose, world), CONFIG, faces) for name, pose in (("south", south), ("north", north))}
    for name, pose, facing in (("south", south, -np.pi / 2), ("north", north, np.pi / 2)):
        grid = grids[name]
        world_xy = (
            grid.occupied_xy @ np.array([[np.cos(pose[2]), np.sin(pose[2])], [-np.sin(pose[2]), np.cos(pose[2])]]) + pose[:2]
        )
        on_wall = (np.abs(world_xy[:, 1]) < 0.25) & (world_xy[:, 0] > 1.5) & (world_xy[:, 0] < 7.5)  # away from corners
        assert on_wall.sum() > 20
        angles = grid.faces[on_wall].astype(np.float64) * 2 * np.pi / FACE_STEPS + pose[2]  # in the world
        assert np.all(np.abs(wrap_angle(angles - facing)) < np.radians(15.0))  # toward the observer
    truth = between(south, north)
    assert np.allclose(covariance(grids["south"], grids["north"], truth, faces), np.eye(3))
    assert not np.allclose(covariance(grids["south"], grids["north"], truth, MatchingConfig(face_angle=None)), np.eye(3))


def test_a_match_with_a_rival_minimum_as_good_within_its_window_is_found_out():
    """Two grids 6 m apart along a bare corridor (2.4 m wide): the fit is flat along it, and from the
    guess moved 0.35 m along the corridor it settles there at least as well as the match did, the
    rival lying along the corridor, not across it. Two grids of the building (niches, rooms, a
    hall), near and 5 m apart: every start settles on the match, within 2 cm of the truth."""
    from navtopo.scan_matching import rival_minimum

    config = MatchingConfig(guess_translation_tolerance=0.35)
    corridor = RasterWorld(-2.0, -5.0, 60.0, 10.0).add_box(-2.0, 58.0, -5.0, 5.0)
    corridor.heights[int(round(3.8 / corridor.res)) : int(round(6.2 / corridor.res)), :] = 0.0  # y in [-1.2, 1.2)
    for a, b, world, ambiguous in (
        (np.array([20.0, 0.2, 0.0]), np.array([26.0, -0.1, 0.05]), corridor, True),
        (POSE_A, POSE_B, WORLD, False),
        (POSE_A, np.array([14.0, -0.2, 0.15]), WORLD, False),
    ):
        reference, query = (PreparedGrid(grid_at(pose, world), CONFIG, config) for pose in (a, b))
        truth = between(a, b)
        result = match(reference, query, initial_guess=truth, config=config)
        rival = rival_minimum(reference, query, result, truth, 0.35, 0.1, np.radians(1.0), config)
        if ambiguous:
            assert rival is not None
            step = rival - result.pose
            assert abs(step[0]) > 0.1 and abs(step[1]) < 0.05
        else:
            assert rival is None and pose_error(result, truth)[0] < 0.02
