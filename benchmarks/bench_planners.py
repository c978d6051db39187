"""Both systems' planners timed offline on one run's saved maps: the same start-goal pairs, each
planned cold (the first plan after ``reset``, as a trial's first plan: everything the plan builds
from the map is built in it) and then warm (the same plan again), one process, CPU time.

``--goal-field`` turns on the baseline's ``planning.goal_field`` (its second plan to a goal makes
the field rooted there, later ones descend it): the second plan is reported apart, and warm is the
third.

The pairs: seeded pairs of NavTopo's locations at least ``--min-distance`` apart; the start is
the first location's map-frame position (NavTopo starts there, localized in it), the goal the
second's. Both maps were made from the same drive, their map frames the pose where it began, so
the metric baseline plans between the same points of its own map (a pair whose start or goal is
not free on its grid is snapped like any start, within its ``snap_radius``).

What is timed: NavTopo's ``Navigator._plan`` (Dijkstra over the graph, the union grid of the
location and its neighbours with its distance transform, the local plan: what ``first_plan_ms``
holds); metric_grid's ``MetricGrid.plan`` (Theta* on the eroded masks with its fallbacks, the
easing; the masks are eroded when the map is loaded, timed apart as ``load_ms``). The runner's
figures are measured in the trials, beside the simulator; these isolate the planners, so a
reviewer can reproduce every planning figure of the README on a saved run.

    .venv/bin/python benchmarks/bench_planners.py RUN_DIR [--pairs 40] [--seed 0] [--goal-field] [--json]

RUN_DIR: a run of both systems (``maps/navtopo`` and ``maps/metric_grid``). Run it on two
revisions with ``PYTHONPATH=<clone>`` to compare them on one map.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any, cast

import numpy as np
from bench_navtopo_first_plan import stats as summary

from baselines.metric_grid.system import MetricGrid, MetricGridConfig
from navkit.types import Observation
from navtopo.system import NavTopo, NavTopoConfig


def pairs_of(positions: np.ndarray, count: int, min_distance: float, seed: int) -> list[tuple[int, int]]:
    rng = np.random.default_rng(seed)
    found: list[tuple[int, int]] = []
    for _ in range(100 * count):
        a, b = (int(i) for i in rng.integers(len(positions), size=2))
        if np.hypot(*(positions[a] - positions[b])) >= min_distance:
            found.append((a, b))
            if len(found) == count:
                break
    return found


def time_navtopo(folder: Path, pairs: list[tuple[int, int]]) -> dict[str, Any]:
    NavTopo.warm_up()  # the compiled kernels, as the runner's worker loads them before timing
    system = NavTopo.load(folder, NavTopoConfig())
    navigator = system.navigator
    assert navigator.map_poses is not None
    tick = cast(Observation, SimpleNamespace(stamp=0.0))  # _plan reads only the stamp
    system.set_goal(navigator.map_poses[pairs[0][1], :2])
    navigator._plan(tick, pairs[0][0], np.zeros(3))  # compiles what warm_up does not (a trial's start-up plans would)
    cold, warm, failed = [], [], 0
    for start, goal in pairs:
        system.reset()  # cold: no union grid, no matching grid, no Dijkstra tree
        system.set_goal(navigator.map_poses[goal, :2])
        times = []
        for _ in range(2):
            t0 = time.process_time()
            planned = navigator._plan(tick, start, np.zeros(3))
            times.append((time.process_time() - t0) * 1e3)
        cold.append(times[0])
        warm.append(times[1])
        failed += not planned
    return {"cold_ms": summary(cold), "warm_ms": summary(warm), "failed": failed}


def time_metric(folder: Path, points: np.ndarray, pairs: list[tuple[int, int]], goal_field: bool = False) -> dict[str, Any]:
    MetricGrid.warm_up()
    t0 = time.process_time()
    config = MetricGridConfig()
    config.planning.goal_field = goal_field
    system = MetricGrid.load(folder, config)
    load_ms = (time.process_time() - t0) * 1e3
    cold, second, warm, lengths, failed = [], [], [], [], 0
    for start, goal in pairs:
        system.reset()  # cold: the line-of-sight rasters are made again, no field is kept
        times = []
        for _ in range(3):
            t0 = time.process_time()
            path = system.plan(points[start], points[goal])
            times.append((time.process_time() - t0) * 1e3)
        cold.append(times[0])
        second.append(times[1])
        warm.append(times[2])
        failed += path is None
        if path is not None:
            lengths.append(float(np.hypot(*np.diff(path, axis=0).T).sum()))
    return {
        "cold_ms": summary(cold),
        "second_ms": summary(second),
        "warm_ms": summary(warm),
        "failed": failed,
        "load_ms": round(load_ms, 1),
        "path_m_mean": round(float(np.mean(lengths)), 3) if lengths else None,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a run folder with maps/navtopo and maps/metric_grid")
    parser.add_argument("--pairs", type=int, default=40)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--min-distance", type=float, default=10.0, help="metres between a pair's locations")
    parser.add_argument("--goal-field", action="store_true", help="the baseline with planning.goal_field")
    parser.add_argument("--json", action="store_true", help="print JSON only")
    args = parser.parse_args()
    maps = args.run / "maps"
    for name in ("navtopo", "metric_grid"):
        if not (maps / name).is_dir():
            parser.error(f"{maps / name}: missing (a run of both systems is needed)")
    navtopo = NavTopo.load(maps / "navtopo", NavTopoConfig())
    assert navtopo.navigator.map_poses is not None
    points = navtopo.navigator.map_poses[:, :2].copy()
    pairs = pairs_of(points, args.pairs, args.min_distance, args.seed)
    result: dict[str, Any] = {
        "run": str(args.run),
        "locations": len(points),
        "pairs": len(pairs),
        "navtopo": time_navtopo(maps / "navtopo", pairs),
        "metric_grid": time_metric(maps / "metric_grid", points, pairs, args.goal_field),
    }
    if args.json:
        print(json.dumps(result))
        return
    print(f"{args.run}: {len(pairs)} pairs of {len(points)} locations, CPU ms per plan")
    print(f"{'system':<12} {'cold median':>12} {'cold p95':>9} {'warm median':>12} {'warm p95':>9} {'failed':>7}")
    for name in ("navtopo", "metric_grid"):
        r = result[name]
        print(
            f"{name:<12} {r['cold_ms']['median']:>12.2f} {r['cold_ms']['p95']:>9.2f} "
            f"{r['warm_ms']['median']:>12.2f} {r['warm_ms']['p95']:>9.2f} {r['failed']:>7}"
        )
    metric = result["metric_grid"]
    print(f"metric_grid: second plan median {metric['second_ms']['median']:.2f} ms, p95 {metric['second_ms']['p95']:.2f}")
    print(f"metric_grid: map loaded and masks eroded in {metric['load_ms']} ms")


if __name__ == "__main__":
    main()
