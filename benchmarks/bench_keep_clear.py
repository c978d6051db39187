"""What easing paths off the walls costs the metric baseline's planner, and what it buys, on a map a
run saved (``planning.keep_clear``; ``navkit.grid_planning.ease_path``).

Plans the same random start-goal pairs (free cells of the saved grid at least --min-distance apart,
seeded) with ``keep_clear`` 0 (the shortest path) and the default, alternating, in one process, and
prints the medians: CPU time per plan, the path's length against the shortest, the least
clearance along it and the metres of it nearer the walls than the first level's clearance plus
0.1 m (clearances to the map's wall cells' centres, as the levels count them: the robot's radius,
half a cell and the 0.1 m margin is the first level). CPU times on a shared machine: compare the two columns, not runs.

    python benchmarks/bench_keep_clear.py RUN_DIR [--pairs 40] [--seed 0]

RUN_DIR is a run's results folder with ``maps/metric_grid``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np

from baselines.metric_grid.config import PlanningConfig
from baselines.metric_grid.map_folder import load_grid_map
from baselines.metric_grid.planning import GridPlanner
from navkit import grid_search
from navkit.grid_planning import densify
from navkit.raster import FREE

ROBOT_RADIUS = 0.3


def arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("--pairs", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--min-distance", type=float, default=10.0, help="m between a pair's ends")
    return parser


def main() -> None:
    args = arguments().parse_args()
    grid = load_grid_map(args.run / "maps" / "metric_grid")
    planners = {
        "shortest": GridPlanner(grid, ROBOT_RADIUS, PlanningConfig(keep_clear=0.0)),
        "eased": GridPlanner(grid, ROBOT_RADIUS, PlanningConfig()),
    }
    first = planners["eased"].mask(planners["eased"].attempts[0])
    cells = np.argwhere(first)
    points = grid.frame.to_world(cells)
    rng = np.random.default_rng(args.seed)
    clearance = np.sqrt(grid_search.clearance_squared(grid.cells == FREE)) * grid.resolution
    none = np.zeros((0, 2))
    for planner in planners.values():  # compile and warm the caches
        planner.plan(points[0], points[-1], none)
    times: dict[str, list[float]] = {name: [] for name in planners}
    least: dict[str, list[float]] = {name: [] for name in planners}
    close: dict[str, list[float]] = {name: [] for name in planners}
    near_m = ROBOT_RADIUS + grid.resolution / 2 + PlanningConfig().inflation_margin + 0.1
    ratio: list[float] = []
    done = 0
    while done < args.pairs:
        a, b = points[rng.integers(len(points), size=2)]
        if np.hypot(*(a - b)) < args.min_distance:
            continue
        lengths = {}
        for name, planner in planners.items():
            t0 = time.process_time()
            planned = planner.plan(a, b, none)
            times[name].append((time.process_time() - t0) * 1e3)
            if planned is None:
                break
            lengths[name] = planned.length
            inner = grid.frame.to_cell(densify(planned.points, grid.resolution / 4)[4:-4])
            along = clearance[inner[:, 0], inner[:, 1]]
            least[name].append(float(along.min()) if len(inner) else np.nan)
            close[name].append(float(np.count_nonzero(along < near_m)) * grid.resolution / 4)
        if len(lengths) == 2:
            ratio.append(lengths["eased"] / lengths["shortest"])
            done += 1
    print(f"{args.run}: {done} pairs, {grid.cells.shape[1]} x {grid.cells.shape[0]} cells of {grid.resolution} m")
    print(
        "| paths | CPU ms per plan, median (p95) | least clearance, median (m) "
        f"| m of path within {near_m:.2f} m of walls, median | length / shortest, median (max) |"
    )
    print("|---|---|---|---|---|")
    for name in planners:
        cpu = f"{statistics.median(times[name]):.2f} ({np.percentile(times[name], 95):.2f})"
        length = "1" if name == "shortest" else f"{statistics.median(ratio):.3f} ({max(ratio):.3f})"
        print(f"| {name} | {cpu} | {np.nanmedian(least[name]):.3f} | {statistics.median(close[name]):.1f} | {length} |")


if __name__ == "__main__":
    main()
