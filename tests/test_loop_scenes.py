"""Scenes with loops (``ring_building``, the bundled loop offices) and navigation-time changes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy import ndimage
from shapely import contains_xy
from shapely.geometry import LineString, MultiPoint, box
from shapely.ops import unary_union

from navkit.types import Command
from runners.metrics import timeout_s
from runners.navigation import mapped_shortest_m
from runners.sim import Simulator
from scenarios import load_scenario
from scenarios.generators import WALL_M, ring_building
from scenarios.scenario import build_scenario
from scenarios.schema import parse_spec
from scenarios.trials import make_trial
from scenarios.world import corridor_polygon, rectangle


def write(tmp_path: Path, spec: dict, name: str = "s.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(spec))
    return path


# ---------------------------------------------------------------------------------------------
# world.changes


def square_ring(changes: list[dict]) -> dict:
    """A 20 x 20 m square ring corridor, 2 m wide; start and goal 12 m apart on its south side."""
    return {
        "format": "navtopo-scenario/1",
        "name": "ring",
        "seed": 1,
        "world": {
            "corridors": [{"points": [[0, 0], [20, 0], [20, 20], [0, 20], [0, 0]], "width": 2.0}],
            "changes": changes,
        },
        "mapping_route": {"waypoints": [[4, 0], [16, 0]]},
        "trials": [{"start": [4, 0, 0], "goal": [16, 0]}, {"start": [4, 20, 0], "goal": [16, 20]}],
    }


CLOSED_SOUTH = [{"center": [10, 0], "size": [0.6, 3.0], "height": 2.0}]


def test_without_changes_the_navigation_world_is_the_mapping_world_itself(tmp_path):
    scenario = load_scenario(write(tmp_path, square_ring([])))
    assert scenario.navigation_world is scenario.world
    assert scenario.navigation_passable is scenario.passable
    assert scenario.summary()["changes"] == 0


def test_the_navigation_world_blocks_the_changes_cells_and_the_mapping_world_does_not(tmp_path):
    scenario = load_scenario(write(tmp_path, square_ring(CLOSED_SOUTH)))
    world, nav = scenario.world, scenario.navigation_world
    assert nav is not world and scenario.summary()["changes"] == 1
    cells = np.argwhere(world.free)
    centres = world.to_world(cells)
    inside = (np.abs(centres[:, 0] - 10.0) < 0.3) & (np.abs(centres[:, 1]) < 1.5)
    assert inside.sum() > 100
    assert not nav.free[cells[inside, 0], cells[inside, 1]].any()
    assert world.free[cells[inside, 0], cells[inside, 1]].all()
    # everything else is the same free space, and the walls are the mapping world's
    assert np.array_equal(nav.free | (world.free & ~nav.free), world.free)
    assert (world.free & ~nav.free).sum() == inside.sum()
    assert nav.wall_segments is world.wall_segments
    # the change stands in the free space: 0.6 x 2 m of the corridor's area is gone
    assert world.free_area_m2 - nav.free_area_m2 == pytest.approx(0.6 * 2.0, rel=1e-6)


def test_a_trial_the_change_cuts_off_takes_the_way_round_the_ring(tmp_path):
    scenario = load_scenario(write(tmp_path, square_ring(CLOSED_SOUTH)))
    radius = scenario.spec.robot.radius
    trial = scenario.trials[0]
    # in the mapping world the way is straight along the south side
    mapping = make_trial(scenario.world, scenario.passable, 0, (4.0, 0.0, 0.0), (16.0, 0.0))
    assert mapping is not None and mapping.shortest_m == pytest.approx(12.0, rel=1e-3)
    # with the south side closed, the exact shortest path wraps the inner block the other way:
    # the convex hull of start, goal and the block grown by the radius, less the side start-goal
    start, goal = np.array([4.0, 0.0]), np.array([16.0, 0.0])
    grown_block = box(1, 1, 19, 19).buffer(radius, quad_segs=128)
    hull = unary_union([grown_block, MultiPoint([start, goal])]).convex_hull
    other_way = hull.length - 12.0
    assert trial.shortest_m == pytest.approx(other_way, rel=0.01)
    assert trial.shortest_m > 4 * mapping.shortest_m
    # the GT path goes round by the north side, never through the change
    assert trial.shortest_path[:, 1].max() > 18.0
    change = rectangle((10, 0), (0.6, 3.0), 0.0)
    assert not LineString(trial.shortest_path).intersects(change)
    # a trial the change does not touch keeps its length
    untouched = make_trial(scenario.world, scenario.passable, 1, (4.0, 20.0, 0.0), (16.0, 20.0))
    assert scenario.trials[1].shortest_m == pytest.approx(untouched.shortest_m, rel=1e-9)


def test_a_changed_world_gives_the_way_the_map_promised_time_too(tmp_path):
    """The runner's time limit in a changed world allows for the way as mapped (12 m along the south
    side, to the shut stretch) besides the way round now; without changes it is the 3x rule."""
    changed = load_scenario(write(tmp_path, square_ring(CLOSED_SOUTH)))
    trial, speed = changed.trials[0], changed.spec.robot.max_linear
    mapped = mapped_shortest_m(changed, trial)
    assert mapped == pytest.approx(12.0, rel=1e-3)
    limit = timeout_s(trial.shortest_m, speed, mapped)
    assert limit == pytest.approx(3 * (trial.shortest_m + 12.0) / speed + 60.0, rel=1e-3)
    assert limit > timeout_s(trial.shortest_m, speed) + 3 * 12.0 / speed - 1e-6
    plain = load_scenario(write(tmp_path, square_ring([]), "plain.yaml"))
    assert mapped_shortest_m(plain, plain.trials[0]) is None


def test_trial_ends_inside_a_change_or_cut_off_by_one_are_refused_naming_the_trial(tmp_path):
    spec = square_ring(CLOSED_SOUTH)
    spec["trials"] = [{"start": [10, 0, 0], "goal": [16, 0]}]
    path = write(tmp_path, spec)
    with pytest.raises(Exception) as info:
        load_scenario(path)
    assert str(info.value).startswith(f"{path}: trials.0.start: ") and "world.changes" in str(info.value)
    # two changes cut the south side off: its trial has no way left
    spec = square_ring([*CLOSED_SOUTH, {"center": [2, 0], "size": [0.6, 3.0], "height": 2.0}])
    spec["trials"] = [{"start": [4, 0, 0], "goal": [8, 0]}, {"start": [4, 0, 0], "goal": [16, 0]}]
    path = write(tmp_path, spec, "b.yaml")
    with pytest.raises(Exception) as info:
        load_scenario(path)
    assert str(info.value).startswith(f"{path}: trials.1: ") and "world.changes" in str(info.value)


def test_generated_trials_keep_out_of_changes(tmp_path):
    spec = square_ring(CLOSED_SOUTH)
    spec["trials"] = {"generate": {"count": 12, "min_distance": 10}}
    scenario = load_scenario(write(tmp_path, spec))
    nav = scenario.navigation_world
    for trial in scenario.trials:
        for xy in (trial.start[:2], trial.goal):
            assert nav.clearance_at(xy) >= scenario.spec.robot.radius + 0.09
            assert not (abs(xy[0] - 10.0) < 0.3 + 0.3 and abs(xy[1]) < 1.5)


def box_room_with_a_change(tmp_path: Path) -> Path:
    spec = {
        "format": "navtopo-scenario/1",
        "name": "room",
        "world": {
            "rooms": [{"center": [0, 0], "size": [8, 6]}],
            "changes": [{"center": [2.0, 0.0], "size": [0.4, 2.0], "height": 1.0}],
        },
        "mapping_route": {"waypoints": [[-3, 0], [3, 0]]},
        "trials": [],
    }
    return write(tmp_path, spec, "room.yaml")


def test_the_simulator_has_the_change_only_with_changes(tmp_path):
    scenario = load_scenario(box_room_with_a_change(tmp_path))
    mount = scenario.spec.sensor.mount_height
    for with_changes, expected_range in ((False, 6.0), (True, 3.8)):
        with Simulator(scenario, with_changes=with_changes) as sim:
            assert sim.with_changes is with_changes
            sim.reset([-2.0, 0.0, 0.0])
            points = sim.scan()
            # the beam straight ahead nearest the horizontal: the far wall, or the change's face
            ahead = points[(np.abs(points[:, 1]) < 1e-3) & (points[:, 0] > 0)]
            beam = ahead[np.argmin(np.abs(ahead[:, 2] - mount))]
            assert abs(beam[2] - mount) < 0.2
            assert beam[0] == pytest.approx(expected_range, abs=2e-3)
            # the change stands 1 m high: beams over it see the far wall
            sim.reset([-1.0, 0.0, 0.0])
            collided = False
            for _ in range(13):  # 2.6 m ahead at 1 m/s: the box's face is 2.5 m away, the wall 4.7 m
                collided = sim.step(Command(1.0, 0.0)).collided or collided
            assert collided is with_changes
            if with_changes:
                assert sim.true_pose[0] == pytest.approx(1.8 - scenario.spec.robot.radius, abs=0.01)


# ---------------------------------------------------------------------------------------------
# ring_building


def resolved(spec: dict):
    origin = Path(f"<generated {spec['name']}>")
    return build_scenario(parse_spec(spec, origin), origin)


def test_ring_building_is_seeded_and_its_corridors_form_loops():
    a, b = ring_building(110, seed=4), ring_building(110, seed=4)
    assert a == b and ring_building(110, seed=5) != a
    for rings in (1, 2):
        spec = ring_building(120, seed=3, rings=rings, trials=4)
        total = sum(
            float(np.linalg.norm(np.diff(np.asarray(c["points"], float), axis=0), axis=1).sum())
            for c in spec["world"]["corridors"]
        )
        assert total == pytest.approx(120, rel=0.02)
        scenario = resolved(spec)
        world = scenario.world
        # loops: the corridors' free space encloses `rings` blocks (holes that are not furniture)
        corridors = unary_union([corridor_polygon(c["points"], c["width"]) for c in spec["world"]["corridors"]])
        assert len(corridors.interiors) == rings
        # every hole of the free space bigger than furniture is a block the corridors go round
        filled = ndimage.binary_fill_holes(world.free)
        holes, count = ndimage.label(filled & ~world.free)
        big = np.bincount(holes.ravel())[1:] * world.resolution**2 > 20.0
        assert big.sum() >= rings
        assert len(scenario.trials) == 4


def test_ring_building_rooms_are_behind_doors_of_a_metre_and_furnished():
    spec = ring_building(120, seed=6, rings=2)
    world_spec = spec["world"]
    rooms = [r for r in world_spec["rooms"] if min(r["size"]) >= 3.5 - 1e-9]  # dress's side rooms are smaller
    doors = [r for r in world_spec["rooms"] if abs(min(r["size"]) - (WALL_M + 0.1)) < 1e-6]
    assert len(rooms) >= 15 and len(doors) == len(rooms)
    for door in doors:
        assert 0.9 <= max(door["size"]) <= 1.0 + 1e-9
    scenario = resolved({**spec, "trials": {"generate": {"count": 2, "min_distance": 10}}})
    world = scenario.world
    # each room is a piece of free space joined to the corridors only through its door: with
    # the doors closed, the rooms fall apart from the corridors
    closed = world.free.copy()
    cells = np.argwhere(world.free)
    xy = world.to_world(cells)
    for door in doors:
        hit = contains_xy(rectangle(door["center"], door["size"], 0.0).buffer(0.06), xy[:, 0], xy[:, 1])
        closed[cells[hit, 0], cells[hit, 1]] = False
    _, pieces = ndimage.label(closed, structure=np.ones((3, 3), bool))
    assert pieces >= len(rooms) + 1
    # furniture of several heights stands in the rooms
    heights = {ob["height"] for ob in world_spec["obstacles"]}
    assert len(heights) >= 4
    furnished = sum(
        any(rectangle(r["center"], r["size"], 0).contains(rectangle(o["center"], o["size"], 0)) for o in world_spec["obstacles"])
        for r in rooms
    )
    assert furnished >= len(rooms) // 2


def test_repeated_rooms_are_identical_side_by_side():
    spec = ring_building(100, seed=2, repeated_rooms=5)
    rooms = [r for r in spec["world"]["rooms"] if min(r["size"]) >= 3.5 - 1e-9]
    south = sorted((r for r in rooms if r["center"][1] < 0), key=lambda r: r["center"][0])[:5]
    assert len(south) == 5
    sizes = {tuple(r["size"]) for r in south}
    assert len(sizes) == 1
    steps = np.diff([r["center"][0] for r in south])
    assert np.allclose(steps, steps[0], atol=2e-3)

    def contents(room: dict) -> list:
        shape = rectangle(room["center"], room["size"], 0)
        out = []
        for kind in ("rooms", "obstacles"):
            for item in spec["world"][kind]:
                if item is room:
                    continue
                centre = np.asarray(item["center"]) - room["center"]
                if shape.buffer(WALL_M + 0.1).contains(rectangle(item["center"], item["size"], 0)):
                    out.append((kind, tuple(np.round(centre, 2)), tuple(item["size"]), item.get("height")))
        return sorted(out)

    first = contents(south[0])
    assert any(kind == "rooms" for kind, *_ in first)  # its door
    for room in south[1:]:
        assert contents(room) == first


# ---------------------------------------------------------------------------------------------
# the bundled loop offices


def windings(route: np.ndarray, centre: tuple[float, float], close_m: float = 1.5) -> set[int]:
    """Signs of the whole turns the route makes round ``centre`` between two moments it is at the
    same place (within ``close_m``): -1 clockwise, +1 counter-clockwise."""
    from test_routes_real_maps import densify  # noqa: PLC0415 - a sibling test module

    points = densify(route, 0.25)
    angle = np.unwrap(np.arctan2(points[:, 1] - centre[1], points[:, 0] - centre[0]))
    found: set[int] = set()
    for i in range(0, len(points), 5):
        near = np.linalg.norm(points[i + 1 :] - points[i], axis=1) < close_m
        turns = (angle[i + 1 :] - angle[i]) / (2 * np.pi)
        for sign in (-1, 1):
            if np.any(near & (np.abs(turns - sign) < 0.1)):
                found.add(sign)
        if found == {-1, 1}:
            break
    return found


def test_loop_office_route_goes_round_both_rings_both_ways():
    scenario = load_scenario("loop_office")
    spec = scenario.spec
    assert spec.odometry.noise is None and len(scenario.trials) == 20
    assert 300 <= scenario.route_length_m <= 1200
    assert 100 <= scenario.summary()["corridor_length_m"] <= 200
    assert min(t.shortest_m for t in scenario.trials) >= 30.0
    ring, cross = spec.world.corridors
    (xc, _), (_, height) = cross.points
    width = ring.points[1][0]
    for centre in ((xc / 2, height / 2), ((xc + width) / 2, height / 2)):
        assert windings(scenario.route, centre) == {-1, 1}, centre


def test_loop_office_door_closes_the_way_most_trials_would_take_and_leaves_one_round():
    office, door = load_scenario("loop_office"), load_scenario("loop_office_door")
    # the same building and route; one change, in the navigation stage only
    assert door.spec.world.model_dump(exclude={"changes"}) == office.spec.world.model_dump(exclude={"changes"})
    assert np.array_equal(door.route, office.route)
    assert len(door.spec.world.changes) == 1 and door.navigation_world is not door.world
    change = door.spec.world.changes[0]
    shut = rectangle(change.center, change.size, change.yaw)
    crossing = 0
    for trial in door.trials:
        mapped = make_trial(door.world, door.passable, trial.index, tuple(np.r_[trial.start[:2], 0.0]), tuple(trial.goal))
        assert mapped is not None
        through = LineString(mapped.shortest_path).intersects(shut)
        crossing += through
        # every trial keeps a way round, which the GT shortest path takes, never through the change
        assert not LineString(trial.shortest_path).intersects(shut)
        if through:
            assert trial.shortest_m > mapped.shortest_m + 5.0
        else:
            assert trial.shortest_m == pytest.approx(mapped.shortest_m, rel=1e-6)
    assert crossing >= 0.75 * len(door.trials)
