"""Scenario files: validation errors, ground-truth rasters, ROS maps, routes and trials."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from scenarios import ScenarioError, bundled_names, load_scenario
from scenarios.schema import WorldSpec, parse_spec
from scenarios.world import build_world, read_ros_map

MAPS = Path(__file__).resolve().parent.parent / "scenarios" / "maps"


def minimal(**overrides) -> dict:
    spec = {
        "format": "navtopo-scenario/1",
        "name": "t",
        "world": {"corridors": [{"points": [[0, 0], [10, 0]], "width": 2.0}]},
        "mapping_route": {"waypoints": [[1, 0], [9, 0]]},
        "trials": [{"start": [1, 0, 0], "goal": [9, 0]}],
    }
    spec.update(overrides)
    return spec


def write(tmp_path: Path, spec: dict, name: str = "s.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.mark.parametrize(
    ("change", "key", "reason"),
    [
        (lambda s: s["world"].update(color="red"), "world.color", "unknown key"),
        (lambda s: s["world"]["corridors"][0].update(width=-1), "world.corridors.0.width", "greater than 0"),
        (lambda s: s["world"]["corridors"][0].update(width="wide"), "world.corridors.0.width", "valid number"),
        (lambda s: s.update(format="navtopo-scenario/9"), "format", "navtopo-scenario/1"),
        (lambda s: s.pop("mapping_route"), "mapping_route", "missing"),
        (lambda s: s["trials"][0].update(start=[5, 1.5, 0]), "trials.0.start", "inside a wall"),
        (lambda s: s["trials"][0].update(start=[5, 5, 0]), "trials.0.start", "outside the map"),
        (lambda s: s["trials"][0].update(goal=[9.0, 0.85]), "trials.0.goal", "from a wall"),
        (lambda s: s["mapping_route"].update(waypoints=[[1, 0], [10.5, 0]]), "mapping_route.waypoints.1", "inside a wall"),
        (lambda s: s["mapping_route"].update(waypoints=[[1, 0], [30, 0]]), "mapping_route.waypoints.1", "outside the map"),
        (lambda s: s["world"].update(map={"yaml": "missing.yaml"}, corridors=[]), "world.map.yaml", "not found"),
        (lambda s: s["world"]["corridors"][0].update(width=True), "world.corridors.0.width", "valid number"),
        (lambda s: s["world"]["corridors"][0].update(width=float("inf")), "world.corridors.0.width", "finite number"),
        (
            lambda s: s["world"]["corridors"][0]["points"][0].__setitem__(0, float("nan")),
            "world.corridors.0.points.0.0",
            "finite",
        ),
        (lambda s: s.update(seed="7"), "seed", "valid integer"),
        (lambda s: s["world"].update(Obstacles=[]), "world.Obstacles", "unknown key"),
        (lambda s: s["world"].update(resolution=1e-5), "world", "too large"),
        (
            lambda s: s["world"].update(changes=[{"center": [5, 0], "size": [1, 1], "height": -1}]),
            "world.changes.0.height",
            "greater than 0",
        ),
        (
            lambda s: s["world"].update(changes=[{"center": [5, 0], "size": [1, 1], "height": 1}, {"center": [5, 0]}]),
            "world.changes.1.size",
            "missing",
        ),
        (
            lambda s: s["world"].update(changes=[{"center": [5, 0], "size": [1, 1], "height": 1, "open": True}]),
            "world.changes.0.open",
            "unknown key",
        ),
        (lambda s: s["world"].update(changes={"center": [5, 0]}), "world.changes", "valid list"),
        (
            lambda s: s["world"].update(changes=[{"center": [1, 0], "size": [1, 3], "height": 1}]),
            "trials.0.start",
            "world.changes",
        ),
        (
            lambda s: s["world"]["corridors"].append({"points": [[30, 30], [50, 30]], "width": 2.0}),
            "world.corridors.1",
            "not connected",
        ),
    ],
)
def test_a_bad_scenario_is_one_line_naming_file_key_and_reason(tmp_path, change, key, reason):
    spec = minimal()
    change(spec)
    path = write(tmp_path, spec)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: {key}: "), message
    assert reason in message


def test_a_map_yaml_with_a_bad_value_is_one_line_naming_the_map_file(tmp_path):
    (tmp_path / "m.yaml").write_text("image: depot.pgm\nresolution: abc\norigin: [0, 0, 0]\n")
    (tmp_path / "depot.pgm").write_bytes((MAPS / "depot.pgm").read_bytes())
    with pytest.raises(ScenarioError, match=r"m\.yaml: resolution: must be a finite number \(got 'abc'\)"):
        read_ros_map(tmp_path / "m.yaml", tmp_path / "s.yaml")


def test_map_image_missing_names_the_map_file(tmp_path):
    (tmp_path / "m.yaml").write_text("image: gone.pgm\nresolution: 0.05\norigin: [0, 0, 0]\n")
    with pytest.raises(ScenarioError, match=r"m\.yaml: image: map image gone\.pgm not found"):
        read_ros_map(tmp_path / "m.yaml", tmp_path / "s.yaml")


@settings(max_examples=40, deadline=None)
@given(
    st.dictionaries(
        st.sampled_from(["format", "name", "world", "robot", "sensor", "trials", "seed", "bogus"]),
        st.one_of(st.none(), st.integers(), st.text(max_size=5), st.lists(st.integers(), max_size=3)),
        max_size=5,
    )
)
def test_the_parser_never_raises_anything_but_a_scenario_error(data):
    try:
        parse_spec(data, "fuzz.yaml")
    except ScenarioError as exc:
        assert str(exc).startswith("fuzz.yaml: ") and "\n" not in str(exc)


def test_raster_areas_of_known_shapes_match_their_geometry():
    world = build_world(
        WorldSpec(
            resolution=0.05,
            corridors=[{"points": [[0, 0], [10, 0]], "width": 2.0}],
            rooms=[{"center": [5, 6], "size": [4, 3], "yaw": 30}],
            obstacles=[{"center": [3, 0], "size": [0.5, 0.4], "height": 1.0}],
        ),
        Path("x.yaml"),
    )
    expected = 10 * 2 + 4 * 3 - 0.5 * 0.4
    assert world.free_area_m2 == pytest.approx(expected, rel=1e-9)
    assert world.free.sum() * 0.05**2 == pytest.approx(expected, rel=0.01)
    # the obstacle blocks the robot but is not a wall: it is free in the structure raster
    cell = world.to_cell(np.array([3.0, 0.0]))
    assert not world.free[tuple(cell)] and world.structure_free[tuple(cell)]


def test_a_ring_corridor_has_no_caps_and_the_right_area():
    ring = [[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]]
    world = build_world(WorldSpec(corridors=[{"points": ring, "width": 2.0}]), Path("x.yaml"))
    # outer 12 x 12 square with corners rounded by r = 1 (round joins), minus the inner 8 x 8 square
    assert world.free_area_m2 == pytest.approx(12 * 12 - (4 - math.pi) - 8 * 8, rel=1e-3)
    assert world.free.sum() * world.resolution**2 == pytest.approx(world.free_area_m2, rel=0.01)
    assert world.free[tuple(world.to_cell(np.array([0.0, 0.0])))]


def test_depot_map_loads_with_origin_at_the_lower_left_and_rows_flipped():
    free, origin, res = read_ros_map(MAPS / "depot.yaml", "x.yaml")
    import cv2

    image = cv2.imread(str(MAPS / "depot.pgm"), cv2.IMREAD_UNCHANGED)
    assert free.shape == image.shape == (307, 604)
    assert res == 0.05 and np.allclose(origin, [0.0, 0.0])
    p = (255.0 - image) / 255.0
    # image row 0 is the top (largest y): it becomes raster row H-1
    assert np.array_equal(free[::-1], p <= 0.25)
    world = load_scenario("depot").world
    top_left_pixel_free = p[0, 0] <= 0.25
    assert world.structure_free[-1, 0] == (top_left_pixel_free and world.structure_free[-1, 0])
    assert world.bounds == pytest.approx((0.0, 0.0, 604 * 0.05, 307 * 0.05))


def test_a_bundled_name_is_not_hidden_by_a_local_folder_and_a_local_file_of_that_name_is_named(tmp_path, monkeypatch):
    from scenarios.scenario import BUNDLED_DIR, resolve_path

    monkeypatch.chdir(tmp_path)
    (tmp_path / "tiny").mkdir()  # a results folder made by `run tiny --out tiny`
    assert resolve_path("tiny") == BUNDLED_DIR / "tiny.yaml"
    (tmp_path / "depot").write_text("a file named like a bundled scenario")
    with pytest.raises(ScenarioError, match="names both a bundled scenario and the file here; write ./depot"):
        resolve_path("depot")
    assert resolve_path("./depot") == Path("./depot") and resolve_path("mine.yaml") == Path("mine.yaml")


def test_tiny_resolves_to_a_short_route_and_three_trials():
    scenario = load_scenario("tiny")
    summary = scenario.summary()
    assert summary["corridor_length_m"] < 30
    assert 40 < summary["route_length_m"] <= 150
    assert summary["trial_count"] == 3
    passable = scenario.passable
    # every route vertex and trial end is where the robot fits
    for xy in [*scenario.route, *[t.start[:2] for t in scenario.trials], *[t.goal for t in scenario.trials]]:
        assert passable[tuple(scenario.world.to_cell(xy))]


def test_corridor_150m_is_the_papers_scene():
    summary = load_scenario("corridor_150m").summary()
    assert summary["corridor_length_m"] == pytest.approx(150, abs=5)
    assert summary["route_length_m"] >= 1000
    assert summary["trial_count"] == 20
    assert summary["trial_distance_mean_m"] == pytest.approx(78, abs=5)


def test_generated_trials_are_seeded_and_respect_min_distance(tmp_path):
    spec = minimal(trials={"generate": {"count": 4, "min_distance": 5.0}}, seed=3)
    spec["world"]["corridors"][0]["points"] = [[0, 0], [20, 0]]
    spec["mapping_route"] = {"waypoints": [[1, 0], [19, 0]]}
    a = load_scenario(write(tmp_path, spec, "a.yaml"))
    b = load_scenario(write(tmp_path, spec, "b.yaml"))
    assert [t.to_json() for t in a.trials] == [t.to_json() for t in b.trials]
    for trial in a.trials:
        assert trial.shortest_m >= 5.0
        assert a.world.clearance_at(trial.start[:2]) >= 0.3


def test_auto_route_visits_every_dead_end():
    scenario = load_scenario("tiny")
    # the skeleton of a flat-capped dead end forks to its corners about half a width before the
    # end wall; with the corner spurs pruned, the route turns within about one corridor width
    dead_ends = [np.array([0.3, 0.0]), np.array([12.0, 7.7]), np.array([6.0, -4.7])]
    for end in dead_ends:
        assert np.min(np.linalg.norm(scenario.route - end, axis=1)) < 2.3, end


def test_the_bundled_scenarios_are_all_there():
    assert {"tiny", "corridor_150m", "depot", "warehouse", "loop_office", "loop_office_door"} <= set(bundled_names())


@pytest.mark.parametrize("name", bundled_names())
def test_bundled_scenarios_validate(name):
    assert load_scenario(name).trials
