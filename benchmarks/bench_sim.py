"""Simulation cost per tick: one lidar scan (rayTestBatch) and one motion step, on a scenario.

.venv/bin/python benchmarks/bench_sim.py corridor_150m --ticks 200
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from navkit.follower import FollowerConfig, PathFollower
from runners.sim import Simulator
from scenarios import load_scenario


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenario", nargs="?", default="corridor_150m")
    parser.add_argument("--ticks", type=int, default=200)
    args = parser.parse_args()
    scenario = load_scenario(args.scenario, with_trials=False)
    t0 = time.perf_counter()
    sim = Simulator(scenario)
    build_s = time.perf_counter() - t0
    follower = PathFollower(FollowerConfig())
    follower.set_path(scenario.route)
    scan_ms, step_ms, points = [], [], []
    sim.scan()  # warm-up
    for _ in range(args.ticks):
        t0 = time.perf_counter()
        obs = sim.observe()
        scan_ms.append((time.perf_counter() - t0) * 1e3)
        points.append(len(obs.points))
        command = follower.command(sim.true_pose)
        t0 = time.perf_counter()
        sim.step(command)
        step_ms.append((time.perf_counter() - t0) * 1e3)
    sim.close()
    print(
        json.dumps(
            {
                "scenario": scenario.name,
                "rays": scenario.spec.sensor.rays,
                "mesh_triangles": sim.mesh_triangles,
                "world_build_s": round(build_s, 3),
                "ticks": args.ticks,
                "scan_ms": {"median": round(float(np.median(scan_ms)), 2), "p95": round(float(np.percentile(scan_ms, 95)), 2)},
                "step_ms": {"median": round(float(np.median(step_ms)), 3), "p95": round(float(np.percentile(step_ms, 95)), 3)},
                "points_per_scan": int(np.median(points)),
                "substeps_per_tick": round(1.0 / scenario.spec.sensor.rate_hz / 0.05),
            },
            indent=2,
        )
    )


if __name__ == "__main__":
    main()
