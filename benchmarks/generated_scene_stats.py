"""What the importer makes of generated scenes (``generate_scene.py``): the evidence for its rules.

Per scenario file, loaded as a run would load it (its trials generated):

* trials: how many were generated, the narrowest gap of their shortest paths;
* specks: obstacles of at most 3 pixels standing alone in free space (a SLAM map's speckle and
  chair legs, extruded by the importer), how many lie within the robot radius + 0.1 m of a trial's
  ground-truth shortest path, and the range within which every scan of the scenario's lidar hits
  a speck one pixel wide (its width as wide as the rays' spacing: width / tan(resolution));
* unreached: free space no robot disc covers (the free space the robot's centre reaches, grown
  by its radius, left out), in m² and pieces, and the pieces reaching 1 m or more beyond what a
  robot covers (laser fans, slits; not corners or slivers behind furniture);
* look-alikes (shape worlds): the groups of rooms whose rasters are identical up to a turn or a
  mirror (``scenarios.aliased.look_alike_groups``).

    PYTHONPATH=. .venv/bin/python benchmarks/generated_scene_stats.py SCENARIO.yaml ...
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy import ndimage

from scenarios import load_scenario
from scenarios.aliased import look_alike_groups, room_boxes
from scenarios.scenario import Scenario
from scenarios.schema import read_yaml

EIGHT = np.ones((3, 3), bool)
DEEP_M = 1.0  # an unreached piece this far beyond the robot's reach is a fan or a slit, not a corner


def specks(scenario: Scenario) -> tuple[int, int, int]:
    """(specks, specks by a trial's shortest path, trials passing one)."""
    world, radius = scenario.world, scenario.spec.robot.radius
    blocked, count = ndimage.label(~world.free, structure=EIGHT)
    sizes = np.bincount(blocked.ravel())
    small = np.nonzero(sizes[1:] <= 3)[0] + 1
    if not len(small):
        return 0, 0, 0
    centres = np.array(ndimage.center_of_mass(np.ones_like(blocked), blocked, small))
    xy = world.origin + (centres[:, ::-1] + 0.5) * world.resolution
    near = np.zeros(len(small), bool)
    trials = 0
    for trial in scenario.trials:
        path = trial.shortest_path
        dense = np.vstack([a + np.linspace(0, 1, 40)[:, None] * (b - a) for a, b in zip(path[:-1], path[1:], strict=True)])
        distance = np.min(np.linalg.norm(xy[:, None, :] - dense[None, :, :], axis=2), axis=1)
        close = distance <= radius + 0.1
        near |= close
        trials += bool(close.any())
    return len(small), int(near.sum()), trials


def unreached(scenario: Scenario) -> tuple[float, int, int]:
    """(m², pieces, pieces reaching ``DEEP_M`` beyond what a robot covers) of free space no robot
    disc covers: corners and slivers behind furniture are shallow; fans and slits run deep."""
    world, radius = scenario.world, scenario.spec.robot.radius
    passable, _ = ndimage.label(world.eroded(radius), structure=EIGHT)
    start = tuple(world.to_cell(scenario.route[0]))
    reach = passable == passable[start]
    disc = int(np.ceil(radius / world.resolution))
    yy, xx = np.mgrid[-disc : disc + 1, -disc : disc + 1]
    covered = ndimage.binary_dilation(reach, structure=(yy**2 + xx**2) * world.resolution**2 <= radius**2)
    left = world.free & ~covered
    pieces, count = ndimage.label(left, structure=EIGHT)
    beyond = ndimage.distance_transform_edt(~covered) * world.resolution
    deep = ndimage.maximum(beyond, pieces, np.arange(1, count + 1)) if count else np.zeros(0)
    return float(left.sum()) * world.resolution**2, count, int((np.asarray(deep) >= DEEP_M).sum())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenarios", nargs="+", type=Path)
    args = parser.parse_args()
    for path in args.scenarios:
        scenario = load_scenario(path)
        spec = read_yaml(path)
        gaps = [t.narrowest_gap_m for t in scenario.trials if t.narrowest_gap_m is not None]
        resolvable = scenario.world.resolution / np.tan(np.radians(scenario.spec.sensor.horizontal_resolution))
        count, by_paths, trials = specks(scenario)
        area, pieces, deep = unreached(scenario)
        line = (
            f"{scenario.name:22s} trials {len(scenario.trials):2d} (narrowest gap {min(gaps, default=1.0):.3f} m)  "
            f"specks {count:3d}, {by_paths:2d} by {trials:2d} trials' paths (resolved within {resolvable:.1f} m)  "
            f"unreached {area:5.1f} m² in {pieces:4d} pieces, {deep:3d} reaching {DEEP_M:g} m beyond"
        )
        if spec["world"].get("map") is None:
            line += f"  look-alike rooms {look_alike_groups(scenario.world, room_boxes(spec))}"
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
