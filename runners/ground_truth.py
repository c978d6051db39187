"""The ground truth a report needs, stored in the results folder (``ground_truth/``).

Reports read results folders only (docs/DESIGN.md, "Layout and layers"), so that a report can
be made on another machine from the folder alone. The run therefore stores, once, what its plots
draw against:

* ``raster.png`` + ``raster.yaml``: the GT raster of the scenario as an 8-bit image in the
  ROS map_server layout (top row = largest y; ``origin`` = the lower-left corner of the lower-left
  cell), with the cell values named in ``values``: free in both stages, wall, obstacle, and
  ``change`` (free while mapping, blocked while navigating). ``map_frame`` is the pose
  ``[x, y, yaw]`` of the map frame (the mapping run's first pose) in the scenario frame.
* ``trials.json``: each run trial's start ``[x, y, yaw_deg]``, goal, ``shortest_m``, its GT
  any-angle shortest path (a polyline in the scenario frame, navigation world), its
  ``narrowest_gap_m`` (the room the path leaves the robot beyond its radius on each side in its
  narrowest passage, ``scenarios.gaps``; 1.0: 1 m or more), ``narrowest_gap_at`` ([x, y] of that
  passage, null when wide open) and ``narrow`` (below the margin, run because the file allows
  it); ``margin_m``: the margin the scenario's trials keep.
* ``route.json``: the mapping route's polyline, its length and its start pose.

Written at the start of a run (and on resume when missing); a folder that already holds them is
left alone.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from navkit.raster import write_map_server
from runners.results import write_json
from scenarios import Scenario

FOLDER = "ground_truth"
FORMAT = "navtopo-ground-truth/1"
# cell values of raster.png; with the map_server thresholds below, wall and obstacle read as
# occupied, free as free and a change as unknown
VALUES = {"free": 255, "change": 160, "obstacle": 64, "wall": 0}
FILES = ("raster.png", "raster.yaml", "trials.json", "route.json")


def raster_pixels(scenario: Scenario) -> np.ndarray:
    """(H, W) uint8, row 0 the lowest y (the raster's own order), with the cell values of ``VALUES``."""
    world, navigation = scenario.world, scenario.navigation_world
    image = np.full(world.free.shape, VALUES["wall"], dtype=np.uint8)
    image[world.structure_free] = VALUES["obstacle"]
    image[world.free] = VALUES["change"]
    image[navigation.free] = VALUES["free"]
    return image


def write_raster(scenario: Scenario, folder: Path) -> Path:
    """``raster.png`` + ``raster.yaml`` (map_server, ``navkit.raster``) with this format's keys."""
    world = scenario.world
    extra = {
        "frame": "scenario",
        "map_frame": [round(float(v), 9) for v in scenario.route_start],
        "values": dict(VALUES),
        "wall_height": float(world.wall_height),
        "robot_radius": float(scenario.spec.robot.radius),
    }
    return write_map_server(
        folder / "raster.yaml", raster_pixels(scenario), world.frame, mode=None, header={"format": FORMAT}, extra=extra
    )


def trials_json(scenario: Scenario, trial_count: int | None) -> dict[str, Any]:
    trials = scenario.trials if trial_count is None else scenario.trials[:trial_count]
    return {
        "format": FORMAT,
        "frame": "scenario",
        "margin_m": scenario.trial_margin_m,
        "trials": [
            {
                **trial.to_json(),
                "shortest_m": round(float(trial.shortest_m), 4),
                "narrowest_gap_at": None if trial.gap_at is None else [round(float(v), 4) for v in trial.gap_at],
                "shortest_path": [[round(float(x), 4), round(float(y), 4)] for x, y in trial.shortest_path],
            }
            for trial in trials
        ],
    }


def route_json(scenario: Scenario) -> dict[str, Any]:
    start = scenario.route_start
    return {
        "format": FORMAT,
        "frame": "scenario",
        "start": [round(float(start[0]), 6), round(float(start[1]), 6), round(float(np.degrees(start[2])), 6)],
        "length_m": round(float(scenario.route_length_m), 3),
        "polyline": [[round(float(x), 4), round(float(y), 4)] for x, y in scenario.route],
    }


def write_ground_truth(scenario: Scenario, run_root: Path, trial_count: int | None = None) -> Path:
    """Write ``<run_root>/ground_truth/`` unless all its files are already there; returns the folder."""
    folder = Path(run_root) / FOLDER
    if all((folder / name).is_file() for name in FILES):
        return folder
    folder.mkdir(parents=True, exist_ok=True)
    write_raster(scenario, folder)
    write_json(folder / "trials.json", trials_json(scenario, trial_count))
    write_json(folder / "route.json", route_json(scenario))
    return folder
