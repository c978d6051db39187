"""Aliased buildings (``scenarios.aliased``): look-alike places whose rasters are identical up to a
translation, a turn or a mirror, as many as asked; seeded; each loads as a scenario."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scenarios.aliased import aliased_ring, aliased_wing, look_alike_groups, mirror_floor, room_boxes, room_raster
from scenarios.generators import ring_building
from scenarios.scenario import build_scenario
from scenarios.schema import parse_spec
from scenarios.world import World, shape_world


def world_of(spec: dict) -> World:
    return shape_world(parse_spec(spec, f"<generated {spec['name']}>").world)


def centred_crop(world: World) -> np.ndarray:
    """The free cells of the largest rectangle of the raster centred on the origin (a cell corner)."""
    x0, y0, x1, y1 = world.bounds
    half_x, half_y = min(-x0, x1), min(-y0, y1)
    (r0, c0), (r1, c1) = world.to_cell(np.array([[-half_x + 1e-6, -half_y + 1e-6], [half_x - 1e-6, half_y - 1e-6]]))
    crop = world.free[r0 : r1 + 1, c0 : c1 + 1]
    assert crop.shape == (round(2 * half_y / world.resolution), round(2 * half_x / world.resolution))
    assert not crop[[0, -1], :].any() and not crop[:, [0, -1]].any()  # the whole building
    return crop


@pytest.mark.parametrize("corridors", [1, 2])
def test_a_wing_repeats_one_room_along_its_corridors_and_mirrors_it_across_them(corridors):
    rooms = 5
    spec = aliased_wing(rooms, seed=61, corridors=corridors, trials=2)
    world = world_of(spec)
    boxes = room_boxes(spec)
    wing = [b for b in boxes if b[0] > 0]  # the lobby lies west of x = 0
    assert len(wing) == 2 * corridors * rooms + 1  # and the stair room
    rows: dict[float, list] = {}
    for b in wing:
        rows.setdefault(b[1], []).append(b)
    full_rows = [sorted(r) for r in rows.values() if len(r) == rooms]
    assert len(full_rows) == 2 * corridors
    first = room_raster(world, full_rows[0][0])
    facing = None
    for row in full_rows:
        rasters = [room_raster(world, b) for b in row]
        for raster in rasters[1:]:
            assert np.array_equal(raster, rasters[0])  # along a row: the same room, moved
        # across a corridor: the mirror image (doors facing each other)
        assert np.array_equal(rasters[0], first) or np.array_equal(rasters[0], first[::-1])
        facing = facing or not np.array_equal(rasters[0], first)
    assert facing and not np.array_equal(first, first[::-1])  # a mirror image, not the same picture
    assert look_alike_groups(world, boxes) == [2 * corridors * rooms]
    assert "identical rooms" in spec["description"]


def test_a_square_ring_looks_the_same_turned_by_a_quarter_and_a_rectangle_by_a_half():
    square = aliased_ring(3, seed=62, sides=4, trials=2)
    world = world_of(square)
    crop = centred_crop(world)
    assert np.array_equal(crop, np.rot90(crop)) and not np.array_equal(crop, crop[::-1])
    groups = look_alike_groups(world, room_boxes(square))
    assert groups and set(groups) == {4} and sum(groups) == len(room_boxes(square))
    rectangle = aliased_ring(3, seed=63, sides=2, trials=2)
    world = world_of(rectangle)
    crop = centred_crop(world)
    assert np.array_equal(crop, np.rot90(crop, 2)) and not np.array_equal(crop, np.rot90(crop))
    groups = look_alike_groups(world, room_boxes(rectangle))
    assert groups and set(groups) == {2} and sum(groups) == len(room_boxes(rectangle))


def test_a_mirror_floor_is_its_own_mirror_image_about_the_cross_corridor():
    spec = mirror_floor(110, seed=64, trials=2)
    corridors = spec["world"]["corridors"]
    assert len(corridors) == 2
    axis = corridors[1]["points"][0][0]
    world = world_of(spec)
    col = int(round((axis - world.origin[0]) / world.resolution))
    assert abs(world.origin[0] + col * world.resolution - axis) < 1e-9  # the axis on a cell edge
    reach = min(col, world.free.shape[1] - col)
    band = world.free[:, col - reach : col + reach]
    assert np.array_equal(band, band[:, ::-1])
    boxes = room_boxes(spec)
    groups = look_alike_groups(world, boxes)
    assert set(groups) == {2} and sum(groups) == len(boxes) >= 12


def test_a_building_without_look_alikes_has_none():
    spec = ring_building(100, seed=65, rings=1, trials=2)
    assert look_alike_groups(world_of(spec), room_boxes(spec)) == []


def test_aliased_buildings_are_seeded():
    assert aliased_wing(4, seed=66) == aliased_wing(4, seed=66) != aliased_wing(4, seed=67)
    assert aliased_ring(2, seed=66) == aliased_ring(2, seed=66) != aliased_ring(2, seed=67)
    assert mirror_floor(100, seed=66) == mirror_floor(100, seed=66) != mirror_floor(100, seed=67)


@pytest.mark.parametrize(
    "make",
    [
        lambda: aliased_wing(4, seed=68, corridors=2, trials=3),
        lambda: aliased_ring(2, seed=68, trials=3),
        lambda: mirror_floor(100, seed=68, trials=3),
    ],
    ids=["wing", "ring", "mirror"],
)
def test_aliased_buildings_load_as_scenarios_whose_route_enters_every_look_alike_room(make):
    spec = make()
    path = Path(f"<generated {spec['name']}>")
    scenario = build_scenario(parse_spec(spec, path), path)  # free space one piece, a route, trials
    assert len(scenario.trials) == 3
    route = scenario.route
    dense = np.vstack([a + np.linspace(0, 1, 50)[:, None] * (b - a) for a, b in zip(route[:-1], route[1:], strict=True)])
    for x0, y0, x1, y1 in room_boxes(spec):
        inside = (dense[:, 0] > x0) & (dense[:, 0] < x1) & (dense[:, 1] > y0) & (dense[:, 1] < y1)
        assert inside.any(), (x0, y0, x1, y1)
