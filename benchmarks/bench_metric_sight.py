"""What keeping each static level's line-of-sight raster saves the metric baseline's planner, on a
map a run saved: plans with the raster kept (``GridPlanner``, made on a level's first search)
against the raster made again for every Theta* search (as before issue 29), the same random
start-goal pairs (free cells of the first level, seeded), alternating, in one process, no obstacles.
Prints the medians of CPU time per plan, whether every path is the same, and the planner's bytes.
CPU times on a shared machine: compare the two columns, not runs.

    python benchmarks/bench_metric_sight.py RUN_DIR [--pairs 40] [--seed 0]

RUN_DIR is a run's results folder with ``maps/metric_grid``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

import baselines.metric_grid.planning as metric_planning
from baselines.metric_grid.config import PlanningConfig
from baselines.metric_grid.map_folder import load_grid_map
from baselines.metric_grid.planning import GridPlanner
from navkit.grid_planning import PlannedPath, plan_path

ROBOT_RADIUS = 0.3


def per_search(*args: Any, **kwargs: Any) -> PlannedPath | None:
    """``plan_path`` with no raster kept: each search makes its own."""
    kwargs["sight"] = None
    return plan_path(*args, **kwargs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--pairs", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    grid = load_grid_map(args.run / "maps" / "metric_grid")
    planner = GridPlanner(grid, ROBOT_RADIUS, PlanningConfig(goal_field=False))  # each plan searches
    points = grid.frame.to_world(np.argwhere(planner.mask(planner.attempts[0])))
    rng = np.random.default_rng(args.seed)
    none = np.zeros((0, 2))
    planner.plan(points[0], points[-1], none)  # compile the kernels, make the first level's raster
    ways = {"kept": plan_path, "per search": per_search}
    times: dict[str, list[float]] = {name: [] for name in ways}
    same = 0
    for _ in range(args.pairs):
        start, goal = points[rng.integers(len(points), size=2)]
        found = {}
        for name, function in ways.items():
            metric_planning.plan_path = function  # type: ignore[assignment]
            t0 = time.process_time()
            found[name] = planner.plan(start, goal, none)
            times[name].append((time.process_time() - t0) * 1e3)
        metric_planning.plan_path = plan_path
        a, b = found.values()
        same += int((a is None and b is None) or (a is not None and b is not None and np.array_equal(a.points, b.points)))
    shape = grid.cells.shape
    print(f"{args.run}: map {shape[1]} x {shape[0]} cells, {args.pairs} pairs")
    for name, values in times.items():
        print(f"  {name:10s} median {statistics.median(values):7.2f} ms CPU per plan, p95 {np.percentile(values, 95):7.2f} ms")
    print(f"  the same path in {same} of {args.pairs} pairs; the planner's derived bytes {planner.nbytes}")


if __name__ == "__main__":
    main()
