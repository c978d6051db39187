"""The map importer's rules (``scenarios.map_import``) on crafted map_server maps with known answers.

Every map here is drawn pixel by pixel at 0.05 m: rooms of free pixels inside two-pixel occupied
walls, unknown space outside, and what a SLAM map adds (specks, laser fans, broken walls). The
scenario's lidar has 1° between columns unless a test says otherwise, so the resolvable size is
2 · 2 · 3 m · sin(0.5°) = 10.5 cm: two pixels are below it, three are not.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from scipy import ndimage
from typer.testing import CliRunner

from navkit.raster import FREE, OCCUPIED, UNKNOWN, GridFrame, trinary_image, write_map_server
from reports.records import ScenarioInfo
from runners.cli import app
from scenarios import ScenarioError, load_scenario
from scenarios.map_import import resolvable_size
from scenarios.schema import RobotSpec, SensorSpec, WorldSpec
from scenarios.world import World, build_world

RES = 0.05
RADIUS = 0.3


def room(rows: int, cols: int, margin: int = 30) -> tuple[np.ndarray, tuple[slice, slice]]:
    """Unknown cells with a room of ``rows`` x ``cols`` free pixels inside a two-pixel occupied
    wall, ``margin`` pixels from the edge; the cells and the room's slices."""
    cells = np.full((rows + 2 * margin, cols + 2 * margin), UNKNOWN, np.uint8)
    cells[margin - 2 : margin + rows + 2, margin - 2 : margin + cols + 2] = OCCUPIED
    inside = (slice(margin, margin + rows), slice(margin, margin + cols))
    cells[inside] = FREE
    return cells, inside


def world_of(tmp_path: Path, cells: np.ndarray, clean: Any = True, horizontal_resolution: float = 1.0) -> World:
    """The world a scenario makes of ``cells`` (written as a PGM map and read back)."""
    write_map_server(tmp_path / "m.yaml", trinary_image(cells), GridFrame(np.zeros(2), RES), image_format="pgm")
    spec = WorldSpec.model_validate({"map": {"yaml": "m.yaml", "clean": clean}})
    robot, sensor = RobotSpec(radius=RADIUS), SensorSpec(horizontal_resolution=horizontal_resolution)
    return build_world(spec, tmp_path / "s.yaml", robot, sensor)


def test_the_resolvable_size_is_what_two_rays_hit_at_the_stated_range():
    assert resolvable_size(3.0, 1.0) == pytest.approx(2 * 3.0 * math.radians(1.0), rel=1e-4)  # 10.5 cm
    assert resolvable_size(3.0, 0.5) == pytest.approx(0.0524, abs=1e-4)
    assert resolvable_size(6.0, 1.0) == pytest.approx(2 * resolvable_size(3.0, 1.0))


# --- rule 1: small obstacles ------------------------------------------------------------------


def speckle_field() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A 10 x 8 m room with specks of one and two pixels (occupied, and a few unknown) and larger
    obstacles: (cells, one-pixel specks, two-pixel specks, large obstacles), masks of the cells."""
    cells, _ = room(160, 200)
    one, two, large = (np.zeros(cells.shape, bool) for _ in range(3))
    for i, r in enumerate(range(50, 180, 20)):
        for j, c in enumerate(range(50, 120, 20)):
            one[r, c] = True
            cells[r, c] = UNKNOWN if (i + j) % 5 == 0 else OCCUPIED
    for r in range(50, 180, 20):
        two[r, 140:142] = True  # side by side
        two[r + 1, 160], two[r, 161] = True, True  # diagonal
    cells[two] = OCCUPIED
    large[60:64, 190:194] = True  # 20 cm square
    large[100:103, 190:193] = True  # 15 cm square: one pixel above the resolvable size
    large[140:141, 185:195] = True  # a thin line 50 cm long
    cells[large] = OCCUPIED
    return cells, one, two, large


def test_specks_below_the_resolvable_size_are_removed_and_larger_obstacles_untouched(tmp_path):
    cells, one, two, large = speckle_field()
    world = world_of(tmp_path, cells)
    expected = (cells == FREE) | one | two
    assert np.array_equal(world.free, expected)
    report = world.map_import
    assert report is not None
    assert report.islands == int(ndimage.label(one | two, structure=np.ones((3, 3)))[1])
    assert report.removed_px == int((one | two).sum())
    assert report.grown_px == report.closed_px == report.fan_px == report.detached_px == 0
    assert report.changed_px == int((one | two).sum())
    assert not world.free[large].any()


def test_grown_specks_become_squares_the_lidar_resolves_and_larger_obstacles_are_untouched(tmp_path):
    cells, one, two, large = speckle_field()
    world = world_of(tmp_path, cells, {"small_obstacles": "grow"})
    grown = ndimage.binary_dilation(one | two, structure=np.ones((3, 3), bool))  # 15 cm >= 10.5 cm
    assert np.array_equal(world.free, (cells == FREE) & ~grown)
    assert world.map_import is not None and world.map_import.grown_px == int((grown & (cells == FREE)).sum())
    # every grown speck is at least the resolvable size across
    labels, count = ndimage.label(~world.free & grown, structure=np.ones((3, 3)))
    for piece in ndimage.find_objects(labels):
        assert min(s.stop - s.start for s in piece) * RES >= resolvable_size(3.0, 1.0)
    assert not world.free[large].any()


def test_the_resolvable_size_follows_the_lidar(tmp_path):
    cells, one, two, large = speckle_field()
    kept = world_of(tmp_path, cells, {"small_obstacles": "keep"})
    assert np.array_equal(kept.free, cells == FREE)
    # at 0.5° the lidar resolves 5.2 cm: one-pixel specks (5 cm) go, two-pixel ones (10 cm) stay
    fine = world_of(tmp_path, cells, horizontal_resolution=0.5)
    assert np.array_equal(fine.free, (cells == FREE) | one)
    # at 2° it resolves 20.9 cm: the 15 and 20 cm squares go too, the 50 cm line stays
    coarse = world_of(tmp_path, cells, horizontal_resolution=2.0)
    line = np.zeros_like(large)
    line[140:141, 185:195] = True
    assert coarse.free[one | two | (large & ~line)].all()
    assert not coarse.free[line].any()


# --- rule 3: laser fans -----------------------------------------------------------------------


def fan_room() -> tuple[np.ndarray, tuple[slice, slice], np.ndarray]:
    """A 5 x 5 m room with a 1 m opening in its right wall, one-pixel free rays fanning from it
    into unknown space, and rays through a one-pixel gap of its top wall: (cells, room, rays)."""
    cells, inside = room(100, 100, margin=80)
    top, right = inside[0].stop, inside[1].stop  # first row above / column right of the room
    cells[120:140, right : right + 2] = FREE  # the opening (rows 120..139)
    rays = np.zeros(cells.shape, np.uint8)
    for angle in range(-40, 41, 5):
        end = (right + 2 + round(70 * math.cos(math.radians(angle))), 130 + round(70 * math.sin(math.radians(angle))))
        cv2.line(rays, (right + 2, 130), end, 1, 1)
    cells[top : top + 2, 110] = FREE  # a one-pixel gap in the top wall
    for dx in (-30, 0, 30):
        cv2.line(rays, (110, top + 2), (110 + dx, top + 60), 1, 1)
    ray_mask = (rays > 0) & (cells == UNKNOWN)
    cells[ray_mask] = FREE
    return cells, inside, ray_mask


def test_one_pixel_rays_into_unknown_space_are_not_free_and_the_room_they_start_from_is_untouched(tmp_path):
    cells, inside, rays = fan_room()
    raw = world_of(tmp_path, cells, False)
    assert raw.free[rays].all()  # the raw map: every ray is free space, joined to the room
    world = world_of(tmp_path, cells)
    assert not world.free[rays].any()
    assert world.free[inside].all()
    # the fan rule alone does the same, and never changes where the robot's centre may be
    fans_only = world_of(tmp_path, cells, {"small_obstacles": "keep", "close_gaps": False})
    assert not fans_only.free[rays].any() and fans_only.free[inside].all()
    assert fans_only.map_import is not None and fans_only.map_import.fan_px >= int(rays.sum())
    assert np.array_equal(fans_only.eroded(RADIUS), raw.eroded(RADIUS))
    assert np.array_equal(world.eroded(RADIUS), raw.eroded(RADIUS))


def channels(widths: tuple[int, ...]) -> tuple[np.ndarray, list[tuple[slice, slice]]]:
    """A 6 x 6 m room with channels of ``widths`` pixels, 40 pixels long, through its right wall
    into unknown space: (cells, each channel's free cells beyond the room)."""
    cells, inside = room(120, 120, margin=60)
    right = inside[1].stop
    found = []
    row = inside[0].start + 15
    for width in widths:
        cells[row - 2 : row + width + 2, right : right + 40] = OCCUPIED
        cells[row : row + width, right : right + 40] = FREE
        found.append((slice(row, row + width), slice(right, right + 40)))
        row += width + 30
    return cells, found


def test_a_channel_into_unknown_exactly_as_wide_as_the_robot_needs_stays_and_one_pixel_narrower_is_wall(tmp_path):
    # the robot's centre fits where the clearance is >= its radius: 13 pixels (0.65 m) across at
    # 0.05 m for a 0.3 m radius, 12 (0.60 m) are one pixel too few
    cells, (wide, narrow) = channels((13, 12))
    raw = world_of(tmp_path, cells, False)
    assert raw.eroded(RADIUS)[wide].any() and not raw.eroded(RADIUS)[narrow].any()
    world = world_of(tmp_path, cells)
    # beyond the reach of a robot body in the room (its radius, 6 pixels), the narrow one is wall;
    # the wide one keeps every pixel but the corners of its open end, and the robot enters it
    assert not world.free[narrow[0], narrow[1].start + 7 :].any()
    assert world.free[wide[0], wide[1].start : wide[1].stop - 7].all()
    assert np.array_equal(world.eroded(RADIUS), raw.eroded(RADIUS))


# --- rule 2: wall gaps ------------------------------------------------------------------------


def two_rooms() -> tuple[np.ndarray, dict[str, tuple[slice, slice]], tuple[slice, slice]]:
    """A room beside a corridor: the wall between them has gaps of 1, 2 and 3 pixels and a 0.8 m
    door; the room's top wall, towards a free yard outside, is broken by gaps of 1 and 2 pixels
    only: (cells, each opening's cells, the yard)."""
    cells, _ = room(200, 300, margin=30)
    wall = slice(130, 132)  # a wall across the building: the room below, the corridor above
    cells[wall, 30:330] = OCCUPIED
    openings = {"gap1": (wall, slice(60, 61)), "gap2": (wall, slice(90, 92)), "gap3": (wall, slice(120, 123))}
    openings["door"] = (wall, slice(200, 216))
    # the yard: free space outside the building, behind its broken bottom wall (rows 28, 29)
    yard = (slice(5, 26), slice(30, 330))
    cells[yard] = FREE
    openings["yard_gap1"] = (slice(26, 30), slice(100, 101))
    openings["yard_gap2"] = (slice(26, 30), slice(200, 202))
    for where in openings.values():
        cells[where] = FREE
    return cells, openings, yard


def test_a_broken_wall_is_closed_beside_a_real_door_which_stays_open(tmp_path):
    cells, openings, yard = two_rooms()
    raw = world_of(tmp_path, cells, False)
    assert all(raw.free[where].all() for where in openings.values()) and raw.free[yard].all()
    world = world_of(tmp_path, cells, {"fans": False, "small_obstacles": "keep"})
    # slits up to two pixels (10 cm < 10.5 cm) are closed, three pixels (15 cm) and the door stay
    for name in ("gap1", "gap2", "yard_gap1", "yard_gap2"):
        assert not world.free[openings[name]].any(), name
    assert world.free[openings["gap3"]].all() and world.free[openings["door"]].all()
    # the yard was joined through the broken wall alone: it is detached
    assert not world.free[yard].any()
    report = world.map_import
    assert report is not None and report.closed_px > 0 and report.detached_px >= 21 * 300
    # and the same with every rule on
    assert np.array_equal(world_of(tmp_path, cells).free, world.free)


def test_at_a_coarser_map_resolution_the_widest_slit_closed_follows_the_resolvable_size(tmp_path):
    cells, _ = room(80, 80)
    cells[28:30, 40:43] = FREE  # three pixels across the bottom wall, towards unknown
    write_map_server(tmp_path / "m.yaml", trinary_image(cells), GridFrame(np.zeros(2), 0.03), image_format="pgm")
    world = build_world(WorldSpec.model_validate({"map": {"yaml": "m.yaml", "clean": {"fans": False}}}), tmp_path / "s.yaml")
    assert world.map_import is not None and world.map_import.rules.resolvable_m / 0.03 == pytest.approx(3.49, abs=0.01)
    assert not world.free[28:30, 40:43].any()  # 9 cm < 10.5 cm


# --- the scenario file, show and manifest ----------------------------------------------------


def scenario_file(tmp_path: Path, clean: Any = None) -> Path:
    cells, _, _, _ = speckle_field()
    write_map_server(tmp_path / "m.yaml", trinary_image(cells), GridFrame(np.zeros(2), RES), image_format="pgm")
    spec: dict[str, Any] = {
        "format": "navtopo-scenario/1",
        "name": "specks",
        "world": {"map": {"yaml": "m.yaml", **({} if clean is None else {"clean": clean})}},
        "mapping_route": {"waypoints": [[3, 3], [9, 3]]},
        "trials": [{"start": [3, 3, 0], "goal": [10.5, 5.5]}],
    }
    path = tmp_path / "s.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.mark.parametrize(
    ("clean", "key", "reason"),
    [
        ("yes", "world.map.clean", "must be true, false or a mapping of rules"),
        ({"small_obstacles": "shrink"}, "world.map.clean.small_obstacles", "Input should be 'remove', 'grow' or 'keep'"),
        ({"resolve_range": 0}, "world.map.clean.resolve_range", "greater than 0"),
        ({"resolve_range": 20.0}, "world.map.clean.resolve_range", "beyond sensor.max_range 15.0 m"),
        ({"fans": 1}, "world.map.clean.fans", "valid boolean"),
        ({"speckle": True}, "world.map.clean.speckle", "unknown key"),
    ],
)
def test_a_bad_clean_option_is_one_line_naming_the_key(tmp_path, clean, key, reason):
    path = scenario_file(tmp_path, clean)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert str(info.value).startswith(f"{path}: {key}: ") and reason in str(info.value), str(info.value)


def test_scenario_show_and_the_manifest_say_what_the_import_changed(tmp_path):
    cells, one, two, _ = speckle_field()
    path = scenario_file(tmp_path)
    result = CliRunner().invoke(app, ["scenario", "show", str(path), "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)["map_import"]
    assert report["removed_px"] == int((one | two).sum()) and report["grown_px"] == 0
    assert report["rules"] == {
        "small_obstacles": "remove",
        "close_gaps": True,
        "fans": True,
        "resolve_range_m": 3.0,
        "resolvable_m": 0.1047,
        "gap_px": 2,
        "robot_radius_m": 0.3,
    }
    text = CliRunner().invoke(app, ["scenario", "show", str(path)]).stdout
    assert f"removed {report['removed_px']} px" in text
    scenario = load_scenario(path)
    info = ScenarioInfo.model_validate({**scenario.summary(), "file": str(path)})
    assert info.map_import is not None and info.map_import.removed_px == report["removed_px"]
    assert info.as_json()["map_import"] == report
    # clean: false keeps the raw map and says so
    raw = load_scenario(scenario_file(tmp_path, False))
    assert np.array_equal(raw.world.free, cells == FREE)
    assert raw.summary()["map_import"]["changed_px"] == 0
    assert "the raw map" in CliRunner().invoke(app, ["scenario", "show", str(tmp_path / "s.yaml")]).stdout


def test_shape_worlds_have_no_map_import():
    assert "map_import" not in load_scenario("tiny").summary()
