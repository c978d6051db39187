"""Global localization in a saved NavTopo graph: place recognition + scan-matching verification.

The robot is put at random poses in the scenario's free space (any heading, seeded), scans once
and localizes with no prior (as at the start of a navigation trial). Success: a verified vertex,
and the robot's estimated position — the vertex's pose composed with the estimate — within
``--tolerance`` of the truth. Vertex poses come from the graph's odometry hints, which equal the
true poses relative to the route start only when the mapping run had precise odometry; so this
benchmark takes such runs only.

    .venv/bin/python benchmarks/bench_navtopo_localization.py results/corridor_150m/latest --queries 200
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from navkit import geometry as se2
from navkit.scan_grid import grid_from_points
from navtopo.scan_matching import prepare
from navtopo.system import NavTopo, NavTopoConfig
from runners.results import read_json
from runners.sim import Simulator
from scenarios import load_scenario


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--queries", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tolerance", type=float, default=0.5)
    parser.add_argument("--descriptor", default=None, help="default: the one the graph was built with")
    args = parser.parse_args()
    manifest = read_json(args.run_dir / "manifest.json")
    scenario = load_scenario(manifest["scenario"]["file"], with_trials=False)
    if scenario.spec.odometry.noise is not None:
        raise SystemExit("this benchmark needs a mapping run with precise odometry (vertex hints = true poses)")
    config = NavTopoConfig.model_validate(manifest["config"]["navtopo"])
    if args.descriptor:
        config = config.model_copy(update={"descriptor": args.descriptor})
    system = NavTopo.load(args.run_dir / "maps" / "navtopo", config)
    graph, localizer = system.graph, system.maintainer.localizer
    start = scenario.route_start
    vertex_truth = np.array([se2.compose(start, v.pose_hint) for v in graph.vertices])
    rng = np.random.default_rng(args.seed)
    cells = np.argwhere(scenario.passable)
    outcomes, errors, times = [], [], []
    with Simulator(scenario) as sim:
        for _ in range(args.queries):
            r, c = cells[rng.integers(len(cells))]
            xy = scenario.world.to_world(np.array([r, c]))
            truth = np.array([xy[0], xy[1], rng.uniform(-np.pi, np.pi)])
            points = sim.scan(truth)
            t0 = time.perf_counter()
            query = prepare(grid_from_points(points, config.grid), config.grid, config.matching)
            found = localizer.localize(query, system.descriptor.embed(points))
            times.append((time.perf_counter() - t0) * 1e3)
            if not found:
                outcomes.append("not_localized")
                continue
            best = found[0]
            estimate = se2.compose(vertex_truth[best.vertex], best.pose)
            error = float(se2.distance(estimate, truth))
            errors.append(error)
            outcomes.append("ok" if error <= args.tolerance else "wrong_place")
    counts = {k: outcomes.count(k) for k in ("ok", "wrong_place", "not_localized")}
    ok_errors = [e for e in errors if e <= args.tolerance]
    print(
        json.dumps(
            {
                "run": str(args.run_dir),
                "descriptor": config.descriptor,
                "vertices": len(graph),
                "queries": args.queries,
                "success_rate": round(counts["ok"] / args.queries, 4),
                "wrong_place_rate": round(counts["wrong_place"] / args.queries, 4),
                "not_localized_rate": round(counts["not_localized"] / args.queries, 4),
                "position_error_m_median": round(float(np.median(ok_errors)), 4) if ok_errors else None,
                "ms_per_localization": {
                    "median": round(float(np.median(times)), 2),
                    "p95": round(float(np.percentile(times, 95)), 2),
                },
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
