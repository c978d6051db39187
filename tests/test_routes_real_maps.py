"""Mapping routes the robot can drive: every bundled scene and a robot-made office map.

The drives use the simulator's kinematics and collision checks and the shared follower on the
true pose, exactly as the mapping stage drives a route, but cast no lidar scans (the scans are
what makes a mapping run slow); ``tools/check_routes.py`` holds the drive. The office map is
generated here (``tools/make_office_map.py``): 58 x 47 m at 0.05 m per pixel, rooms behind
0.8-0.9 m doors (and a few narrower than the robot), desks, chairs, speckles and unknown pixels.
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import yaml
from scipy import ndimage

from scenarios import bundled_names, load_scenario
from scenarios.routes import CLEARANCE_SLACK_M, PASS_MARGIN_M, leg_clearances, route_space
from scenarios.trials import SAMPLE_MARGIN_M

TOOLS = Path(__file__).resolve().parent.parent / "tools"


def tool(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"tools_{name}", TOOLS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


check_routes = tool("check_routes")
office_map = tool("make_office_map")


@pytest.fixture(scope="module")
def office(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return office_map.write_office(tmp_path_factory.mktemp("office"), seed=3)


def densify(route: np.ndarray, step: float = 0.025) -> np.ndarray:
    pieces = []
    for a, b in zip(route[:-1], route[1:], strict=True):
        k = max(2, int(np.linalg.norm(b - a) / step) + 1)
        pieces.append(a + np.linspace(0.0, 1.0, k)[:, None] * (b - a))
    return np.vstack(pieces)


@pytest.mark.parametrize("name", [*bundled_names(), "office"])
def test_the_mapping_route_keeps_its_margin_reaches_every_room_and_is_driven_without_a_collision(name, request):
    path = request.getfixturevalue("office") if name == "office" else name
    scenario = load_scenario(path, with_trials=False)
    world, radius = scenario.world, scenario.spec.robot.radius
    space = route_space(world, radius)
    # every leg keeps the fit margin from walls, measured on the GT clearance raster
    least = leg_clearances(world, scenario.route)
    assert least.min() >= radius + PASS_MARGIN_M - CLEARANCE_SLACK_M - 1e-3, scenario.route[np.argmin(least)]
    # every roomy place of 2 m² or more that the robot can reach (through gaps it fits with the
    # margin) is on the route
    fit_labels, _ = ndimage.label(space.fit, structure=np.ones((3, 3), bool))
    reachable = fit_labels == fit_labels[tuple(world.to_cell(scenario.route[0]))]
    rooms, count = ndimage.label(space.roomy & reachable, structure=np.ones((3, 3), bool))
    area = np.bincount(rooms.ravel(), minlength=count + 1) * world.resolution**2
    cells = world.to_cell(densify(scenario.route))
    visited = np.unique(rooms[cells[:, 0], cells[:, 1]])
    missed = [world.to_world(np.argwhere(rooms == k)[0]) for k in range(1, count + 1) if area[k] >= 2.0 and k not in visited]
    assert not missed, f"roomy places off the route, e.g. at {missed[0]}"
    # and the robot drives it to its end, touching nothing
    result = check_routes.drive_route(scenario)
    assert result.collisions == 0, result.line()
    assert result.completed, result.line()
    assert result.least_margin_m > 0.0, result.line()
    assert result.travelled_m >= 0.9 * result.route_m, result.line()


def corridor_with_rooms(tmp_path: Path) -> Path:
    """A 3 m corridor with a pillar; a room behind a 0.8 m door, one behind a 0.55 m door."""
    spec = {
        "format": "navtopo-scenario/1",
        "name": "doors",
        "seed": 2,
        "world": {
            "corridors": [{"points": [[0, 0], [24, 0]], "width": 3.0}],
            "rooms": [
                {"center": [6, 4.0], "size": [4, 4]},  # y 2..6: 0.5 m of wall below it
                {"center": [6, 1.75], "size": [0.8, 0.6]},  # its door
                {"center": [18, 4.0], "size": [4, 4]},
                {"center": [18, 1.75], "size": [0.55, 0.6]},  # a door narrower than the robot
            ],
            "obstacles": [{"center": [12, 0], "size": [0.4, 0.4], "height": 2.0}],  # a pillar mid-corridor
        },
        "mapping_route": {"auto": {"min_length": 60}},
        "trials": {"generate": {"count": 6, "min_distance": 5}},
    }
    path = tmp_path / "doors.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def test_a_route_enters_a_room_straight_through_its_door_and_skips_one_behind_a_door_too_narrow(tmp_path):
    scenario = load_scenario(corridor_with_rooms(tmp_path))
    route = scenario.route
    dense = densify(route)
    # the room behind the 0.8 m door is toured, the one behind the 0.55 m door is not entered
    assert np.min(np.linalg.norm(dense - [6.0, 4.0], axis=1)) < 1.0
    assert not np.any((dense[:, 1] > 1.6) & (np.abs(dense[:, 0] - 18.0) < 2.5))
    # each crossing of the door (y from 1.45 to 2.05) lies on one straight leg that starts at
    # least 0.6 m before the door and runs on at least 0.15 m after it
    crossings = 0
    for a, b in zip(route[:-1], route[1:], strict=True):
        low, high = sorted((a[1], b[1]))
        if abs(a[0] - 6.0) < 1.0 and low < 1.45 and high > 2.05:
            crossings += 1
            start, end = (a, b) if a[1] < b[1] else (b, a)
            assert start[1] <= 1.45 - 0.6 or end[1] >= 2.05 + 0.6, (a, b)  # the approach side is long
            assert start[1] <= 1.45 - 0.15 and end[1] >= 2.05 + 0.15, (a, b)
    assert crossings >= 2  # in and out
    # no door leg turns inside the door: every route point near the door is outside its opening
    near = (np.abs(route[:, 0] - 6.0) < 0.4) & (route[:, 1] > 1.45) & (route[:, 1] < 2.05)
    assert not near.any(), route[near]
    # the loop round the pillar is opened: the route passes it on one side only
    beside = dense[np.abs(dense[:, 0] - 12.0) < 0.2]
    assert len(beside) and (np.all(beside[:, 1] > 0.2) or np.all(beside[:, 1] < -0.2))
    # generated trials keep a margin and are joined to the route through space the robot fits in
    space = route_space(scenario.world, scenario.spec.robot.radius)
    for trial in scenario.trials:
        for xy in (trial.start[:2], trial.goal):
            assert scenario.world.clearance_at(xy) >= scenario.spec.robot.radius + SAMPLE_MARGIN_M - 0.01
            assert not (abs(xy[0] - 18.0) < 2.5 and xy[1] > 1.5), xy  # never in the room it cannot enter
            assert space.fit[tuple(scenario.world.to_cell(xy))]
    result = check_routes.drive_route(scenario)
    assert result.completed and result.collisions == 0, result.line()


def test_the_office_map_has_what_a_robot_map_has_and_its_trials_are_reachable(office):
    meta = yaml.safe_load((office.parent / "office.yaml").read_text())
    assert meta["resolution"] == 0.05
    scenario = load_scenario(office)
    world = scenario.world
    xmin, ymin, xmax, ymax = world.bounds
    assert xmax - xmin == pytest.approx(58.0, abs=0.1) and ymax - ymin == pytest.approx(47.0, abs=0.1)
    import cv2

    image = cv2.imread(str(office.parent / meta["image"]), cv2.IMREAD_UNCHANGED)
    unknown = (image > 0) & (image < 250)
    inside = image[100:-100, 100:-100]
    assert ((inside > 0) & (inside < 250)).sum() > 500  # grey pixels inside the building too
    assert unknown.sum() > 0 and (image == 0).sum() > 0
    # clutter splits the free space: many holes (desks, chairs, speckles) in the one free piece
    _, holes = ndimage.label(~world.free[1:-1, 1:-1] & ndimage.binary_fill_holes(world.free)[1:-1, 1:-1])
    assert holes > 100
    assert len(scenario.trials) == 12
    radius = scenario.spec.robot.radius
    space = route_space(world, radius)
    labels, _ = ndimage.label(space.fit, structure=np.ones((3, 3), bool))
    route_piece = labels[tuple(world.to_cell(scenario.route[0]))]
    for trial in scenario.trials:
        assert trial.shortest_m >= 15.0
        for xy in (trial.start[:2], trial.goal):
            assert world.clearance_at(xy) >= radius + SAMPLE_MARGIN_M - 0.01
            assert labels[tuple(world.to_cell(xy))] == route_piece


@pytest.mark.slow
@pytest.mark.parametrize("name", bundled_names())
def test_the_mapping_stage_drives_every_bundled_route_to_its_end_with_the_oracle(name, tmp_path):
    """The real mapping stage (scans, the runner's follower and stuck rule), end to end."""
    out = tmp_path / "run"
    command = [sys.executable, "-m", "runners.cli", "run", name, "--systems", "oracle", "--trials", "0", "--out", str(out)]
    done = subprocess.run(command, capture_output=True, text=True, timeout=3600, cwd=TOOLS.parent)
    assert done.returncode == 0, (done.stdout + done.stderr)[-3000:]
    report = json.loads((out / "mapping" / "oracle.json").read_text())
    assert "error" not in report, report.get("error")
    assert report["collisions"] == 0
    # driven to its end: the follower cuts corners by centimetres, it does not skip the route
    assert report["route_length_m"] >= 0.95 * report["route_plan_length_m"]
