"""SLAM-like maps of generated buildings (``scenarios.slam_like``): each artefact where and as many
as asked, doors 0.75-0.9 m on whole pixels, a map that loads as a scenario, the same bytes for the
same seed.

Known answers come from the map itself and from the same building drawn without the artefact: the
walls are drawn first from the same seed, so the pixels an artefact changed are exactly the
difference between the two maps.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import ndimage

from navkit.raster import FREE, OCCUPIED, UNKNOWN, read_map_server
from scenarios import load_scenario
from scenarios.generators import ring_building
from scenarios.map_import import import_map
from scenarios.slam_like import RESOLUTION, Artefacts, SlamMap, slam_map, write_slam_scenario
from scenarios.world import import_rules

EIGHT = np.ones((3, 3), bool)
FOUR = ndimage.generate_binary_structure(2, 1)
SEED = 41
BUILDING = ring_building(80, seed=SEED, rings=1, trials=2, route_factor=1.0)
CLEAN = Artefacts.none()


def only(**amounts: float) -> Artefacts:
    return dataclasses.replace(CLEAN, **amounts)


@pytest.fixture(scope="module")
def clean() -> SlamMap:
    return slam_map(BUILDING, SEED, CLEAN)


def changed(made: SlamMap, clean: SlamMap, before: int, after: int) -> tuple[np.ndarray, int]:
    """Components (8-connected labels, count) of the pixels ``before`` in the clean map and ``after`` in ``made``."""
    assert made.cells.shape == clean.cells.shape
    return ndimage.label((clean.cells == before) & (made.cells == after), structure=EIGHT)


def beside(cells: np.ndarray, value: int) -> np.ndarray:
    """Pixels with a 4-neighbour of ``value``."""
    return ndimage.binary_dilation(cells == value, structure=FOUR)


def door_run(made: SlamMap, centre: tuple[float, float], axis: str) -> int:
    """Free pixels in a row through a door's centre, along its opening."""
    r, c = made.frame.to_cell(np.asarray(centre))
    line = made.cells[r, :] if axis == "x" else made.cells[:, c]
    at = c if axis == "x" else r
    assert line[at] == FREE
    low, high = at, at
    while line[low - 1] == FREE:
        low -= 1
    while line[high + 1] == FREE:
        high += 1
    return high - low + 1


def test_a_map_without_artefacts_has_walls_of_their_thickness_and_every_room_behind_a_door(clean):
    cells = clean.cells
    low, high = CLEAN.wall_px
    # walls separate free space from unknown everywhere: no free pixel beside an unknown one, and
    # every unknown pixel lies more than the thinnest wall from free space; no wall is thicker
    assert not (beside(cells, UNKNOWN) & (cells == FREE)).any()
    distance = ndimage.distance_transform_edt(cells != FREE)
    assert distance[cells == UNKNOWN].min() > low
    assert distance[cells == OCCUPIED].max() <= high
    # free space is one piece; nothing isolated stands in it
    assert ndimage.label(cells == FREE, structure=EIGHT)[1] == 1
    blobs, _ = ndimage.label(cells == OCCUPIED, structure=EIGHT)
    assert np.bincount(blobs.ravel())[1:].min() >= 9  # walls and furniture (0.25 m at least), no speck
    # every room of 2 m or more is behind a door of whole pixels in [0.75, 0.9] m, the width the record says
    rooms = [r for r in clean.source["world"]["rooms"] if min(r["size"]) >= 2.0]
    assert len(clean.record.doors) == len(rooms) >= 10
    for door in clean.record.doors:
        assert 0.75 - 1e-9 <= door.width_m <= 0.9 + 1e-9
        assert door_run(clean, door.centre, door.axis) == round(door.width_m / RESOLUTION)
    assert len({d.width_m for d in clean.record.doors}) >= 3  # drawn per door


def test_broken_walls_are_gaps_of_one_or_two_pixels_from_free_space_to_the_unknown_outside(clean):
    amounts = only(breaks_per_100m=8.0)
    made = slam_map(BUILDING, SEED, amounts)
    expected = int(np.floor(8.0 * clean.record.exterior_wall_m / 100 + 0.5))
    assert expected >= 5 and len(made.record.breaks) == expected
    labels, count = changed(made, clean, OCCUPIED, FREE)
    assert count == expected  # nothing else opened
    outside, inside = beside(made.cells, UNKNOWN), beside(clean.cells, FREE)
    widths = []
    for k in range(1, count + 1):
        gap = labels == k
        assert (gap & outside).any() and (gap & inside).any()  # through the wall, free space to unknown
        rows, cols = np.nonzero(gap)
        widths.append(min(np.ptp(rows), np.ptp(cols)) + 1)
    assert sorted(widths) == sorted(w for *_, w in made.record.breaks)
    assert set(widths) <= {1, 2}
    # an exterior wall only: each gap's inner end is in the building, the outside was unknown
    assert (made.cells[labels > 0] == FREE).all()


def test_laser_fans_are_one_pixel_rays_through_exterior_walls_reaching_the_unknown_outside(clean):
    amounts = only(fans_per_100m=6.0)
    made = slam_map(BUILDING, SEED, amounts)
    expected = int(np.floor(6.0 * clean.record.exterior_wall_m / 100 + 0.5))
    assert expected >= 4 and len(made.record.fans) == expected
    # the rays: free where the clean map had wall or unknown; nothing else changed
    opened = (made.cells == FREE) & (clean.cells != FREE)
    assert ((made.cells != FREE) == (clean.cells != FREE))[~opened].all()
    outside = opened & (clean.cells == UNKNOWN)
    building = ndimage.distance_transform_edt(clean.cells != FREE) * RESOLUTION  # metres from the clean free space
    # one pixel wide: away from the window, hardly a 2 x 2 block of ray pixels (where two rays cross)
    away = outside & (building >= 0.5)
    blocks = away[:-1, :-1] & away[1:, :-1] & away[:-1, 1:] & away[1:, 1:]
    assert blocks.sum() <= 0.005 * away.sum()
    for fan in made.record.fans:
        assert 1 <= len(fan.ray_ends) <= amounts.fan_rays[1]
        ends = made.frame.to_cell(np.asarray(fan.ray_ends))
        assert (made.cells[ends[:, 0], ends[:, 1]] == FREE).all()
        assert (clean.cells[ends[:, 0], ends[:, 1]] == UNKNOWN).all()
        assert building[ends[:, 0], ends[:, 1]].max() >= 1.0  # a metre out beyond the wall
        source = made.frame.to_cell(np.asarray(fan.source))
        assert clean.cells[tuple(source)] == FREE  # from where a robot stood
    assert building[outside].max() >= 2.0


def test_speckle_and_chair_legs_are_isolated_blobs_of_one_to_three_pixels(clean):
    amounts = only(speckle_per_100m2=6.0, chairs_per_100m2=1.0)
    made = slam_map(BUILDING, SEED, amounts)
    area = clean.record.free_area_m2 / 100
    speckle, chairs = int(np.floor(6.0 * area + 0.5)), int(np.floor(1.0 * area + 0.5))
    assert speckle >= 10 and len(made.record.speckle) == speckle
    assert len(made.record.chair_legs) == 4 * chairs
    labels, count = changed(made, clean, FREE, OCCUPIED)
    assert count == speckle + 4 * chairs
    sizes = np.bincount(labels.ravel())[1:]
    assert sizes.min() >= 1 and sizes.max() <= 3
    # each blob stands alone: two pixels of free space all round it
    for k in range(1, count + 1):
        ring = ndimage.binary_dilation(labels == k, structure=EIGHT, iterations=2) & (labels != k)
        assert (made.cells[ring] == FREE).all()
    # and none in a doorway
    for door in made.record.doors:
        assert door_run(made, door.centre, door.axis) == round(door.width_m / RESOLUTION)


def test_unknown_corners_are_patches_of_rooms_never_seen(clean):
    made = slam_map(BUILDING, SEED, only(unknown_corner_share=1.0))
    rooms = [r for r in clean.source["world"]["rooms"] if min(r["size"]) >= 2.0]
    assert len(rooms) // 2 <= len(made.record.unknown_corners) <= len(rooms)
    _, count = changed(made, clean, FREE, UNKNOWN)
    assert count == len(made.record.unknown_corners)
    for x0, y0, x1, y1 in made.record.unknown_corners:
        assert 0.3 - 1e-9 <= x1 - x0 <= 0.8 + 1e-9 and 0.3 - 1e-9 <= y1 - y0 <= 0.8 + 1e-9
        (r0, c0), (r1, c1) = made.frame.to_cell(np.array([[x0 + 0.05, y0 + 0.05], [x1 - 0.05, y1 - 0.05]]))
        assert not (made.cells[r0 : r1 + 1, c0 : c1 + 1] == FREE).any()
    assert ndimage.label(made.cells == FREE, structure=EIGHT)[1] == 1


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, SlamMap]:
    path = tmp_path_factory.mktemp("slam") / "slam_ring41.yaml"
    return path, write_slam_scenario(BUILDING, path, SEED)


def test_a_default_slam_map_loads_as_a_scenario_its_free_space_one_piece_its_doors_kept(written):
    path, made = written
    counts = made.record.counts()
    for artefact in ("breaks", "fans", "speckle", "chair_legs", "unknown_corners", "bumps"):
        assert counts[artefact] > 0, artefact
    ros = read_map_server(path.with_name("slam_ring41_map.yaml"))
    assert (ros.cells == made.cells).all()
    assert ndimage.label(made.cells == FREE, structure=EIGHT)[1] == 1
    scenario = load_scenario(path)
    # the world is what the importer's rules make of the map (docs/DESIGN.md, "Map worlds"): the
    # artefacts are part of the map, the importer cleans them (specks removed, fans made wall)
    spec = scenario.spec
    expected, report = import_map(made.cells, RESOLUTION, import_rules(spec.world, spec.robot, spec.sensor))
    assert (scenario.world.free == expected).all()
    assert report.islands == counts["speckle"] + counts["chair_legs"]  # every speck and chair leg, no more
    assert len(scenario.trials) == 2 and scenario.route_length_m > 80
    for door in made.record.doors:
        assert door_run(made, door.centre, door.axis) == round(door.width_m / RESOLUTION)


def test_the_same_seed_writes_the_same_bytes(written, tmp_path):
    path, _ = written
    again = tmp_path / path.name
    write_slam_scenario(BUILDING, again, SEED)
    for name in (path.name, "slam_ring41_map.yaml", "slam_ring41_map.pgm"):
        assert (path.parent / name).read_bytes() == (tmp_path / name).read_bytes(), name
    other = tmp_path / "other" / path.name
    write_slam_scenario(BUILDING, other, SEED + 1)
    assert (other.parent / "slam_ring41_map.pgm").read_bytes() != (path.parent / "slam_ring41_map.pgm").read_bytes()


def test_amounts_out_of_range_are_refused():
    with pytest.raises(ValueError, match="door_width_m"):
        Artefacts(door_width_m=(0.5, 0.9))
    with pytest.raises(ValueError, match="speckle_per_100m2"):
        Artefacts(speckle_per_100m2=-1.0)


def test_generate_scene_writes_a_slam_map_and_refuses_a_benchmark_seed(tmp_path):
    script = Path(__file__).resolve().parent.parent / "benchmarks" / "generate_scene.py"
    root = str(script.parent.parent)

    def run(*args: str) -> subprocess.CompletedProcess:
        env = {"PYTHONPATH": root, "PATH": "/usr/bin:/bin"}
        return subprocess.run([sys.executable, str(script), *args], capture_output=True, text=True, env=env, timeout=120)

    out = tmp_path / "tree.yaml"
    done = run("slam-tree", "--length", "60", "--seed", "43", "--trials", "1", "-o", str(out))
    assert done.returncode == 0, done.stderr
    assert out.is_file() and (tmp_path / "tree_map.pgm").is_file() and "speckle" in done.stdout
    refused = run("slam-tree", "--seed", "7", "-o", str(tmp_path / "x.yaml"))
    assert refused.returncode == 2 and "benchmark" in refused.stderr and refused.stderr.count("\n") == 1
    refused = run("slam-ring", "--seed", "43", "--artefacts", "fans=2", "-o", str(tmp_path / "x.yaml"))
    assert refused.returncode == 2 and "fans" in refused.stderr
    assert not (tmp_path / "x.yaml").exists() and not (tmp_path / "x_map.pgm").exists()
