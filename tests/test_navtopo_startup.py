"""NavTopo's start-up commitment rule (``navtopo.startup``) against ground truth: the evidence a
look gives (bookkeeping on hypotheses whose verdicts are given), and a crafted building of two
identical rooms on one corridor, where a commitment from inside a room would be a guess."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from navkit import geometry as se2
from navkit.raster import FREE, OCCUPIED, UNKNOWN, GridFrame
from navkit.scan_grid import GridConfig, grid_from_points
from navkit.types import Observation
from navtopo.graph import TopologicalGraph
from navtopo.local_grid import CroppedGrid
from navtopo.localization import LocalizationConfig
from navtopo.mapping import GraphMaintainer, MappingConfig
from navtopo.planning import UnionGrid
from navtopo.scan_matching import MatchingConfig
from navtopo.startup import Hypothesis, Startup, StartupConfig, beam_contradictions, scan_beams
from runners.sim import Simulator
from scenarios.scenario import build_scenario
from scenarios.schema import parse_spec

GRID = GridConfig()


# -- the evidence of a look, on hypotheses whose verdicts the test gives -----------------------------


def _bookkeeping(count: int, **config) -> tuple[Startup, list[Hypothesis]]:
    """A start-up holding ``count`` hypotheses (vertex k each) whose trackers' verdicts are set by hand."""
    startup = Startup(SimpleNamespace(), None, StartupConfig(**config))  # type: ignore[arg-type]
    hypotheses = [
        Hypothesis(
            tracker=SimpleNamespace(current=k, pose_in_current=np.zeros(3), last_verified=False),  # type: ignore[arg-type]
            odometer_start=0.0,
            places={k},
        )
        for k in range(count)
    ]
    startup.hypotheses = list(hypotheses)
    return startup, hypotheses


def _look(
    startup: Startup, hypotheses: list[Hypothesis], verdicts: list[bool], moved: float = 0.25, heading: float = 0.0
) -> None:
    """A look after ``moved`` metres (toward ``heading``, rad) that verifies ``hypotheses[k]`` iff
    ``verdicts[k]`` (dropped ones are not asked)."""
    if not startup._odom.started:
        startup._odom.update(np.zeros(3))
    startup._odom.update(startup._odom.last + moved * np.array([np.cos(heading), np.sin(heading), 0.0]))
    for h, ok in zip(hypotheses, verdicts, strict=True):
        h.tracker.last_verified = ok
    startup._weigh()


def test_a_look_that_verifies_no_hypothesis_drops_none():
    """Turning on the spot, the matcher may verify nobody for looks on end: no place lost ground."""
    startup, both = _bookkeeping(2)
    for _ in range(5):
        _look(startup, both, [False, False])
    assert startup.hypotheses == both
    for _ in range(5):  # ... but a place never verified again is dropped in the end
        _look(startup, both, [False, False])
    assert startup.hypotheses == []


def test_an_exact_look_alike_is_never_left_alone_by_chance_and_a_contradicted_place_falls():
    """The right place and its look-alike, each missed at one look in four (not the same ones):
    both stay, so nothing is committed; a third place the scan contradicts falls in drop_after looks."""
    startup, three = _bookkeeping(3)
    right, alike, contradicted = three
    for k in range(40):
        _look(startup, three, [k % 4 != 0, k % 4 != 2, False])
        assert startup._committed() is None
        if k >= startup.config.drop_after - 1:
            assert contradicted not in startup.hypotheses
    assert startup.hypotheses == [right, alike]


# -- the far evidence: beams against a hypothesis's map --------------------------------------------


def _corridor_map(east_end: float = 10.0) -> UnionGrid:
    """A corridor 2.4 m wide along x from -15 m to ``east_end``, walls of one cell, unknown beyond."""
    res = 0.1
    frame = GridFrame(np.array([-16.0, -3.0]), res)
    cells = np.full((60, 300), UNKNOWN, np.uint8)
    centres = frame.to_world(np.argwhere(cells == UNKNOWN)).reshape(60, 300, 2)
    x, y = centres[..., 0], centres[..., 1]
    inside = (np.abs(y) < 1.2) & (x > -15.0) & (x < east_end)
    cells[inside] = FREE
    wall = ~inside & (np.abs(y) < 1.3) & (x > -15.1) & (x < east_end + 0.1)
    cells[wall] = OCCUPIED
    return UnionGrid(0, cells, frame)


def _corridor_scan(x_robot: float, east_end: float = 10.0) -> np.ndarray:
    """A lidar's returns (robot frame, z 0.6 m, 1° apart) from x_robot on the corridor's axis, facing east."""
    angles = np.radians(np.arange(-180.0, 180.0, 1.0))
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        to_side = np.where(np.abs(s) > 1e-9, 1.2 / np.abs(s), np.inf)
        to_end = np.where(c > 1e-9, (east_end - x_robot) / c, np.where(c < -1e-9, (-15.0 - x_robot) / c, np.inf))
    ranges = np.minimum(to_side, to_end)
    keep = ranges <= 15.0
    return np.stack([ranges * c, ranges * s, np.full_like(ranges, 0.6)], axis=1)[keep]


def test_beams_contradict_a_look_alike_along_a_corridor_and_not_the_right_place():
    """The robot 6 m short of a corridor's end: its right place in the map contradicts no beam; a
    place 4 m further along or back (a room's width on a wing of identical rooms: the same walls
    within a few metres) is contradicted by the beams that reach the end, through the map's end
    wall (4 m east) or as returns where the map has open floor (4 m west)."""
    union = _corridor_map()
    angles, ranges = scan_beams(_corridor_scan(4.0), GRID)
    assert 340 <= len(ranges) <= 360  # one beam per degree (none where the corridor runs beyond the range)
    right = beam_contradictions(union, np.array([4.0, 0.0, 0.0]), angles, ranges, 0.5)
    east = beam_contradictions(union, np.array([8.0, 0.0, 0.0]), angles, ranges, 0.5)
    west = beam_contradictions(union, np.array([0.0, 0.0, 0.0]), angles, ranges, 0.5)
    assert right == 0
    assert east >= 12 and west >= 12
    # and 2 m either way (half a room) too
    assert beam_contradictions(union, np.array([6.0, 0.0, 0.0]), angles, ranges, 0.5) >= 12
    assert beam_contradictions(union, np.array([2.0, 0.0, 0.0]), angles, ranges, 0.5) >= 12


def test_a_place_found_late_must_explain_the_earlier_looks_carried_back_by_odometry():
    """The robot saw the corridor's end from 4-6 m before it (three looks kept), then drove back to
    x = -6 m: there a look-alike 4 m along matches the last scan about as well as the right place, but
    the earlier looks, carried back by odometry, contradict it and not the right place."""
    startup = Startup(SimpleNamespace(grid_config=GRID), None, StartupConfig())  # type: ignore[arg-type]
    startup._unions = {0: _corridor_map()}
    for x in (4.0, 5.0, 6.0):
        startup._history.append((np.array([x, 0.0, 0.0]), *scan_beams(_corridor_scan(x), GRID, 2.0)))
    now = SimpleNamespace(odom=np.array([-6.0, 0.0, 0.0]))
    right, shifted, back = startup._replayed(
        now, [(0, np.array([-6.0, 0.0, 0.0])), (0, np.array([-2.0, 0.0, 0.0])), (0, np.array([-10.0, 0.0, 0.0]))]
    )  # type: ignore[arg-type]
    assert right == 0
    assert shifted >= 2 * startup.config.far_margin and back >= 2 * startup.config.far_margin


def test_a_place_verified_in_one_location_only_is_never_committed_however_far_the_robot_drives():
    """Driving about a room does not tell it from a look-alike room elsewhere (the right one may be a
    room the map never entered): a commitment needs a second location, the corridor beyond the door."""
    startup, (room,) = _bookkeeping(1)
    room.alone_since = 0.0
    for _ in range(40):  # 10 m of looks, every one verifying it, all in location 0
        _look(startup, [room], [True])
        assert startup._committed() is None
    room.places.add(1)  # verified beyond the door
    _look(startup, [room], [True])
    assert startup._committed() is room


def test_two_locations_verified_without_leaving_a_room_commit_nothing():
    """A location's grid reaches into the rooms round it: a look-alike room's tracker may change
    location while the robot drives about the room. Two locations are not enough until the places
    the hypothesis was verified at lie ``confirm_span`` apart."""
    startup, (room,) = _bookkeeping(1)
    room.alone_since = 0.0
    room.places.add(1)
    for k in range(60):  # 15 m of driving back and forth across a 2.5 m room
        _look(startup, [room], [True], heading=0.0 if (k // 10) % 2 == 0 else np.pi)
        assert startup._committed() is None
    assert room.span < startup.config.confirm_span
    for _ in range(20):  # out of the door and 5 m along the corridor beyond
        _look(startup, [room], [True], heading=np.pi / 2)
    assert room.span >= startup.config.confirm_span and startup._committed() is room


def test_the_far_evidence_counts_against_the_contradicted_hypothesis_only():
    startup, (right, shifted) = _bookkeeping(2)
    for _ in range(2):
        _look(startup, [right, shifted], [True, True])
    for _ in range(3):  # both verified by the matcher, one contradicted by the far beams
        startup._odom.metres += 0.25
        startup._weigh([False, True])
    assert startup.hypotheses == [right]


def test_the_survivor_is_committed_only_after_it_has_been_verified_alone_for_a_while():
    startup, both = _bookkeeping(2, confirm_places=1, confirm_span=0.0)
    right, _ = both
    config = startup.config
    for _ in range(4):
        _look(startup, both, [True, True])
    for _ in range(config.drop_after):  # the corridor outside the door tells them apart
        _look(startup, both, [True, False])
    assert startup.hypotheses == [right] and right.alone_since is not None
    assert startup._committed() is None  # just alone: a rival dropped at one look may come back
    looks = 0
    while startup._committed() is None:
        _look(startup, [right], [True])
        looks += 1
    assert looks == max(config.confirm_alone_looks, int(np.ceil(config.confirm_alone_distance / 0.25)))
    _look(startup, [right], [False])
    assert startup._committed() is None  # the committing look must verify it


# -- a crafted building: two identical rooms on one corridor -----------------------------------------

ROOM_A, ROOM_B = 4.0, 12.0  # the rooms' centres (x); the corridor runs along y = 0 from x = 0 to 20
# the places and the drive lie this far off the world's 0.05 m raster, as a drive's poses do: with
# both at its multiples, every wall face falls on a 0.1 m cell's edge and lands in the cell beyond
# it (binning by floor), half a cell the same way in each grid's own axes, which between views 90°
# apart is one cell: the start-up's match was 0.097 m off (0.105 m with closed walls), 0.005 m off
# the raster (raw or closed walls alike; 0.02-0.07 m over other offsets and turns)
OFF_RASTER = np.array([0.013, 0.027, 0.0])


def _twin_rooms() -> dict:
    """Two rooms identical to the raster cell (door, box, a bench across the corridor), 8 m apart on
    the south of a closed corridor: from inside either room the scan is the same; the corridor's ends
    and its other benches tell them apart."""
    rooms = [{"center": [10.0, 0.0], "size": [20.0, 2.0]}]  # the corridor, y in [-1, 1]
    bench = {"size": [1.2, 0.4], "height": 0.8}
    obstacles = [{"center": [x, 0.75], **bench} for x in (2.0, 9.1, 17.5)]
    for x in (ROOM_A, ROOM_B):
        rooms += [{"center": [x, -3.1], "size": [3.0, 4.0]}, {"center": [x + 0.5, -1.05], "size": [1.0, 0.3]}]
        obstacles += [{"center": [x + 0.8, -4.3], "size": [0.6, 0.6], "height": 0.8}, {"center": [x + 2.2, 0.75], **bench}]
    return {
        "format": "navtopo-scenario/1",
        "name": "twin_rooms",
        "seed": 5,
        "world": {"resolution": 0.05, "wall_height": 2.6, "rooms": rooms, "obstacles": obstacles},
        "mapping_route": {"waypoints": [[1.0, 0.0], [19.0, 0.0]]},
        "trials": [{"start": [ROOM_A, -3.5, 1.57], "goal": [18.0, 0.0]}],
    }


def _drive() -> list[np.ndarray]:
    """From inside room A out of its door, a turn east, and along the corridor (true poses)."""
    poses = [np.array([ROOM_A + 0.5, y, np.pi / 2]) for y in np.arange(-3.6, 0.0, 0.1)]
    poses += [np.array([ROOM_A + 0.5, 0.0, yaw]) for yaw in np.radians(np.arange(80.0, -1.0, -10.0))]
    poses += [np.array([x, 0.0, 0.0]) for x in np.arange(ROOM_A + 0.6, ROOM_A + 6.0, 0.1)]
    return [pose + OFF_RASTER for pose in poses]


@pytest.fixture(scope="module")
def twin_rooms(tmp_path_factory):
    origin = Path(tmp_path_factory.mktemp("twin")) / "twin_rooms.yaml"
    scenario = build_scenario(parse_spec(_twin_rooms(), origin), origin)
    places = [[x, -3.1, 0.0] for x in (ROOM_A, ROOM_B)] + [[x, 0.0, 0.0] for x in (1.5, 4.5, 8.5, 12.5, 16.5, 19.0)]
    places = [list(np.asarray(place) + OFF_RASTER) for place in places]
    with Simulator(scenario, seed=0) as sim:
        grids = [grid_from_points(sim.scan(np.asarray(p, float)), GRID) for p in places]
        poses = _drive()
        scans = [sim.scan(p) for p in poses]
    graph = TopologicalGraph(4)
    for k, (pose, grid) in enumerate(zip(places, grids, strict=True)):
        graph.add_vertex(CroppedGrid.from_grid(grid), np.ones(4, np.float32), pose, float(k))
    for u, v in [(0, 3), (1, 5), (2, 3), (3, 4), (4, 5), (5, 6), (6, 7)]:
        graph.add_edge(u, v, se2.between(np.asarray(places[u], float), np.asarray(places[v], float)))
    return graph, np.array(places), poses, scans


def test_identical_rooms_are_told_apart_in_the_corridor_never_guessed_from_inside(twin_rooms):
    """Inside room A, room B verifies as well (the map is aliased there): no commitment. Out in the
    corridor its ends tell the rooms apart: the start-up commits, to the right place."""
    graph, places, poses, scans = twin_rooms
    assert not np.array_equal(graph.vertices[0].grid.cells, np.full_like(graph.vertices[0].grid.cells, FREE))
    describe = lambda points: np.ones(4, np.float32)  # noqa: E731 - place recognition tells nothing apart
    maintainer = GraphMaintainer(graph, describe, GRID, MatchingConfig(), MappingConfig(), LocalizationConfig(), False)
    startup = Startup(maintainer, describe, StartupConfig())
    most_alive, committed_at = 0, None
    for k, (pose, scan) in enumerate(zip(poses, scans, strict=True)):
        committed = startup.step(Observation(0.2 * k, scan, se2.between(poses[0], pose)))
        most_alive = max(most_alive, len(startup.hypotheses))
        in_room = pose[1] < -1.0
        if committed is not None:
            where = se2.compose(places[committed.vertex], committed.pose)
            assert np.hypot(*(where[:2] - pose[:2])) < 0.3, f"committed {np.hypot(*(where[:2] - pose[:2])):.1f} m off"
            assert not in_room, "committed from inside a room that has a twin"
            committed_at = k
            break
    assert most_alive >= 2, "the twin room verified too: the crafted map is aliased"
    assert committed_at is not None, "the corridor tells the rooms apart"


def _given_a_pose(graph: TopologicalGraph, places: np.ndarray) -> Startup:
    """A start-up on the twin rooms' map with the locations' map poses, where place recognition tells
    nothing apart; the test gives the pose (``set_prior``)."""
    describe = lambda points: np.ones(4, np.float32)  # noqa: E731
    maintainer = GraphMaintainer(graph, describe, GRID, MatchingConfig(), MappingConfig(), LocalizationConfig(), False)
    startup = Startup(maintainer, describe, StartupConfig())
    startup.map_poses = places
    return startup


@pytest.mark.parametrize("error", [(0.4, -0.3, 8.0), (-0.5, 0.5, -10.0)])
def test_a_given_start_pose_commits_at_the_first_look_to_the_right_one_of_twin_rooms(twin_rooms, error):
    """The protocol's ``perturbed`` start: the true pose off by up to 0.5 m and 10°. Inside room A,
    whose twin verifies as well without a pose, the given pose settles it at once: committed at the
    first look, to room A, within 0.1 m of the truth (the match's, not the given error)."""
    graph, places, poses, scans = twin_rooms
    startup = _given_a_pose(graph, places)
    dx, dy, dyaw = error
    startup.set_prior(poses[0] + np.array([dx, dy, np.radians(dyaw)]))
    committed = startup.step(Observation(0.0, scans[0], np.zeros(3)))
    assert committed is not None and startup.from_given_pose and startup.looks == 1
    where = se2.compose(places[committed.vertex], committed.pose)
    assert np.hypot(*(where[:2] - poses[0][:2])) < 0.1
    assert abs(np.degrees(se2.wrap_angle(where[2] - poses[0][2]))) < 2.0


def test_a_given_pose_farther_off_than_the_search_commits_nothing_from_it(twin_rooms):
    """A given pose 2.5 m off (beyond ``prior_search``): no match near it puts the robot there, so
    the start-up goes on as without one (no commitment from inside a room with a twin)."""
    graph, places, poses, scans = twin_rooms
    startup = _given_a_pose(graph, places)
    startup.set_prior(poses[0] + np.array([0.0, 2.5, 0.0]))
    for k in range(8):  # the first looks, still inside room A
        assert startup.step(Observation(0.2 * k, scans[k], se2.between(poses[0], poses[k]))) is None
    assert not startup.from_given_pose


def test_a_given_pose_keeps_look_alikes_far_from_it_from_becoming_rivals(twin_rooms):
    """A given pose 1.8 m off (beyond ``prior_search``: not committed from it at once) still rules out
    room B, 8 m away (``prior_gate``): its finds are refused, room A is the only hypothesis from the
    first look on, and the start-up commits to it once the robot is out in the corridor."""
    graph, places, poses, scans = twin_rooms
    startup = _given_a_pose(graph, places)
    startup.set_prior(poses[0] + np.array([1.8, 0.0, 0.0]))
    committed = None
    for k, (pose, scan) in enumerate(zip(poses, scans, strict=True)):
        committed = startup.step(Observation(0.2 * k, scan, se2.between(poses[0], pose)))
        assert len(startup.hypotheses) <= 1, "a look-alike 8 m from the given pose became a rival"
        if committed is not None:
            break
    assert committed is not None and not startup.from_given_pose and startup.prior_refused > 0
    where = se2.compose(places[committed.vertex], committed.pose)
    assert np.hypot(*(where[:2] - poses[k][:2])) < 0.3
