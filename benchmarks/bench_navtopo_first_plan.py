"""NavTopo's first plan of a trial, offline on a saved map: every location in turn as the start
(the robot at its origin), the goal a map-frame point beside the location farthest from it, all
caches cold (no union grid, no Dijkstra tree) as at a trial's first plan. Times the whole plan
(global search, union grid, target, local plan: what ``first_plan_ms`` holds) and, apart, the union
grid alone.

The runner's ``first_plan_ms`` is measured in the trial, with the simulator beside it in the same
worker; this isolates NavTopo's part, so that a change to the planner can be measured without a run.
Run it on two revisions with ``PYTHONPATH=<clone>`` to compare them on one map.

    .venv/bin/python benchmarks/bench_navtopo_first_plan.py RUN_DIR/maps/navtopo [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from types import SimpleNamespace
from typing import cast

import numpy as np

from navkit.types import Observation
from navtopo.planning import build_union_grid
from navtopo.system import NavTopo, NavTopoConfig


def stats(samples: list[float]) -> dict[str, float]:
    values = np.asarray(samples, dtype=np.float64)
    return {
        "median": round(float(np.median(values)), 3),
        "p95": round(float(np.percentile(values, 95)), 3),
        "max": round(float(values.max()), 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("map", type=Path, help="a saved NavTopo map (RUN_DIR/maps/navtopo)")
    parser.add_argument("--repeats", type=int, default=5, help="passes over every start location")
    args = parser.parse_args()
    NavTopo.warm_up()  # the compiled kernels, as the runner's worker loads them before timing
    system = NavTopo.load(args.map, NavTopoConfig())
    navigator, graph = system.navigator, system.graph
    assert navigator.map_poses is not None, "a loaded map has its locations' map-frame poses"
    positions = navigator.map_poses[:, :2]
    plans, unions, failed = [], [], 0
    for _ in range(args.repeats):
        for start in range(len(graph)):
            far = int(np.argmax(np.hypot(*(positions - positions[start]).T)))
            system.set_goal(positions[far] + 0.3)
            system.unions.clear()
            navigator.global_planner.reset()
            started = time.perf_counter()
            planned = navigator._plan(cast(Observation, SimpleNamespace(stamp=0.0)), start, np.zeros(3))  # only its stamp is read
            plans.append((time.perf_counter() - started) * 1e3)
            failed += not planned
            started = time.perf_counter()
            build_union_grid(graph, start, system.config.grid, system.config.planning.union_radius)
            unions.append((time.perf_counter() - started) * 1e3)
    print(
        json.dumps(
            {
                "map": str(args.map),
                "locations": len(graph),
                "plans": len(plans),
                "failed": failed,
                "first_plan_ms": stats(plans),
                "union_grid_ms": stats(unions),
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
