"""What the metric baseline's planner pays for obstacles its map lacks, on a map a run saved: its
masks remade only round the obstacles (``GridPlanner.with_blocked``) against a transform of the
whole map per level (as before issue 29), the same plans.

For random start-goal pairs (free cells of the first level at least --min-distance apart, seeded)
a box the map lacks (points on a 0.6 m line across the path, 3 m along it: a box or a person
seen ahead) is put on the shortest path; both ways plan start -> goal round it, alternating, in
one process. Prints the medians of CPU time per plan, and whether every path is the same. CPU times
on a shared machine: compare the two columns, not runs.

    python benchmarks/bench_metric_obstacles.py RUN_DIR [--pairs 30] [--seed 0]

RUN_DIR is a run's results folder with ``maps/metric_grid``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from baselines.metric_grid.config import PlanningConfig
from baselines.metric_grid.map_folder import load_grid_map
from baselines.metric_grid.planning import GridPlanner
from navkit import grid_search
from navkit.geometry import arc_lengths, point_at_arc

ROBOT_RADIUS = 0.3


class WholeMap(GridPlanner):
    """The planner as it was: every level's mask made again from the whole map at each plan."""

    def with_blocked(self, key: tuple[str, float, float | None], blocked: NDArray[np.int64]) -> NDArray[np.bool_]:
        kind, radius, medial = key
        free = self._base(kind)
        free[blocked[:, 0], blocked[:, 1]] = False
        squared = grid_search.clearance_squared(free)
        return grid_search.passable(squared, radius, self.grid_map.resolution, medial)


def arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--pairs", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--min-distance", type=float, default=10.0, help="m between a pair's ends")
    return parser


def box_across(path: NDArray, at_m: float, width_m: float = 0.6) -> NDArray[np.float64]:
    """Points every 5 cm on a line ``width_m`` long across ``path`` (K, 2) ``at_m`` along it."""
    arcs = arc_lengths(path)
    centre = point_at_arc(path, arcs, at_m)
    ahead = point_at_arc(path, arcs, at_m + 0.1) - centre
    normal = np.array([-ahead[1], ahead[0]]) / max(float(np.hypot(*ahead)), 1e-9)
    offsets = np.arange(-width_m / 2, width_m / 2 + 1e-9, 0.05)
    return centre[None] + offsets[:, None] * normal[None]


def main() -> None:
    args = arguments().parse_args()
    grid = load_grid_map(args.run / "maps" / "metric_grid")
    planners = {
        "window": GridPlanner(grid, ROBOT_RADIUS, PlanningConfig(goal_field=False)),
        "whole map": WholeMap(grid, ROBOT_RADIUS, PlanningConfig(goal_field=False)),
    }
    window = planners["window"]
    points = grid.frame.to_world(np.argwhere(window.mask(window.attempts[0])))
    rng = np.random.default_rng(args.seed)
    none = np.zeros((0, 2))
    for planner in planners.values():  # compile the kernels
        planner.plan(points[0], points[-1], none)
    times: dict[str, list[float]] = {name: [] for name in planners}
    same = 0
    done = 0
    while done < args.pairs:
        start, goal = points[rng.integers(len(points), size=2)]
        if np.hypot(*(goal - start)) < args.min_distance:
            continue
        clear = window.plan(start, goal, none)
        if clear is None or clear.length < 6.0:
            continue
        box = box_across(clear.points, 3.0)
        paths = {}
        for name, planner in planners.items():
            t0 = time.process_time()
            planned = planner.plan(start, goal, box)
            times[name].append((time.process_time() - t0) * 1e3)
            paths[name] = None if planned is None else planned.points
        a, b = paths.values()
        same += int((a is None and b is None) or (a is not None and b is not None and np.array_equal(a, b)))
        done += 1
    shape = grid.cells.shape
    print(f"{args.run}: map {shape[1]} x {shape[0]} cells, {done} pairs, a 0.6 m box on each path 3 m from its start")
    for name, values in times.items():
        print(f"  {name:10s} median {statistics.median(values):7.2f} ms CPU per plan, p95 {np.percentile(values, 95):7.2f} ms")
    ratio = statistics.median(times["whole map"]) / statistics.median(times["window"])
    print(f"  whole map / window: {ratio:.1f}x; the same path in {same} of {done} pairs")


if __name__ == "__main__":
    main()
