"""The metric baseline's search candidates on a map a run saved (issue 29): Lazy Theta*, 8-connected
A* string-pulled from both ends and refined (``astar_smoothed``), jump point search pulled the same
way (``jps_smoothed``), and a field rooted at the goal (``goal_field``: Dijkstra over the whole mask once per goal; then every
plan to that goal descends it, ``field_path``). Seeded random start-goal pairs among the free cells
of the first level (the robot radius, half a cell and the margin), one process, CPU time, each
mask's line-of-sight raster made once. Prints each candidate's total path length against
Theta*'s, its worst pair, and the median milliseconds per plan (the field: its build apart).

    python benchmarks/bench_metric_search.py RUN_DIR [RUN_DIR ...] [--pairs 40] [--seed 1]

RUN_DIR: a run's results folder with ``maps/metric_grid``.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from baselines.metric_grid.config import PlanningConfig
from baselines.metric_grid.map_folder import load_grid_map
from baselines.metric_grid.planning import GridPlanner
from navkit import grid_search as gs

ROBOT_RADIUS = 0.3


def timed(function: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    t0 = time.process_time()
    out = function(*args)
    return out, (time.process_time() - t0) * 1e3


def measure(run: Path, pairs: int, seed: int) -> None:
    grid = load_grid_map(run / "maps" / "metric_grid")
    planner = GridPlanner(grid, ROBOT_RADIUS, PlanningConfig())
    mask = planner.mask(planner.attempts[0])
    sight = gs.sight_raster(mask)
    free = np.argwhere(mask)
    rng = np.random.default_rng(seed)
    gs.field_path(mask, gs.goal_field(mask, free[1]), free[0], sight)  # compile
    gs.theta_star(mask, free[0], free[1], sight)
    gs.astar_smoothed(mask, free[0], free[1], sight)
    gs.jps_smoothed(mask, free[0], free[1], sight)
    lengths: dict[str, list[float]] = {"theta_star": [], "astar": [], "jps": [], "field": []}
    times: dict[str, list[float]] = {"theta_star": [], "astar": [], "jps": [], "field build": [], "field": []}
    for _ in range(pairs):
        start, goal = free[rng.integers(len(free), size=2)]
        theta, ms_theta = timed(gs.theta_star, mask, start, goal, sight)
        if theta is None:
            continue
        astar, ms_astar = timed(gs.astar_smoothed, mask, start, goal, sight)
        jps, ms_jps = timed(gs.jps_smoothed, mask, start, goal, sight)
        field, ms_build = timed(gs.goal_field, mask, goal)
        descended, ms_field = timed(gs.field_path, mask, field, start, sight)
        for name, path in (("theta_star", theta), ("astar", astar), ("jps", jps), ("field", descended)):
            lengths[name].append(gs.path_length(path, grid.resolution))
        timings = (("theta_star", ms_theta), ("astar", ms_astar), ("jps", ms_jps), ("field build", ms_build), ("field", ms_field))
        for name, ms in timings:
            times[name].append(ms)
    theta_m = np.asarray(lengths["theta_star"])
    print(f"{run}: {len(theta_m)} pairs, mask {mask.shape[0]} x {mask.shape[1]} cells")
    for name, values in lengths.items():
        ratio = np.asarray(values) / theta_m
        print(f"  {name:<11} length / Theta*'s: total {np.sum(values) / theta_m.sum():.5f}, worst pair {ratio.max():.4f}")
    print("  median ms: " + ", ".join(f"{name} {np.median(ms):.2f}" for name, ms in times.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", type=Path, nargs="+")
    parser.add_argument("--pairs", type=int, default=40)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    for run in args.runs:
        measure(run, args.pairs, args.seed)


if __name__ == "__main__":
    main()
