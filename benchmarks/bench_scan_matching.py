"""Accuracy, verdict and time of navtopo.scan_matching on simulated lidar scans.

Poses are drawn along the scenario's mapping route (where NavTopo makes its locations): a random
arc length, up to 0.3 m aside (if passable), heading along the route ± 30° or, for half of them,
the other way. Each pose gives a PyBullet lidar scan (runners.sim) and a location grid. Then:

* near pairs (≤ --near m apart): match without a guess, and with an odometry-like guess (the true
  relative pose plus N(0, 0.2 m) per axis and N(0, 3°)); error against the true relative pose
  ``between(A, B)``; accepted share. Reported for all pairs and for those whose grids overlap
  (known-area IoU at the true pose) by at least 0.3, NavTopo's "still inside" level: near poses
  on two sides of a wall see different places.
* far pairs (≥ --far m apart): accepted share without a guess and with the true relative pose
  as the guess (a drift-free odometry hint). An acceptance with a wrong pose (> 0.5 m or > 5°) is
  a false accept; an acceptance with the right pose (far locations can see one corridor stretch)
  is reported apart.
* time per match (median, p95): with both grids unprepared (``ms`` of each pair set: features
  and distance transforms are computed in the call), and with prepared grids as NavTopo would
  hold them (``prepared_match_ms``, after ``prepare_ms_per_grid``); per grid build and per scan.

    python benchmarks/bench_scan_matching.py --scenario corridor_150m --poses 300

A generated scene instead of a scenario file (``scenarios.generators.corridor_tree``, as tuning
asks: seeds disjoint from the benchmark's), optionally with lidar range noise:

    python benchmarks/bench_scan_matching.py --generated 150 --seed 101 --range-noise 0.01
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

from navkit.geometry import between, compose, wrap_angle
from navkit.scan_grid import GridConfig, grid_from_points
from navtopo.scan_matching import MatchingConfig, PreparedGrid, match, verdict
from runners.sim import Simulator
from scenarios import Scenario, generators, load_scenario
from scenarios.scenario import build_scenario
from scenarios.schema import parse_spec


def generated_scenario(length: float, seed: int, range_noise: float = 0.0) -> Scenario:
    """A corridor tree of ``length`` m (``generators.corridor_tree``), its route, no trials."""
    spec = generators.corridor_tree(length, seed, trials=1)
    spec["sensor"] = {**spec.get("sensor", {}), "range_noise": range_noise}
    if range_noise:
        spec["name"] = f"{spec['name']}_range_noise_{range_noise:g}"
    origin = Path(f"<generated {spec['name']}>")
    return build_scenario(parse_spec(spec, origin), origin, with_trials=False)


def scan_grids(scenario: Scenario, poses: np.ndarray, seed: int, grid_config: GridConfig) -> tuple[list, list, list]:
    """A location grid per pose from a simulated scan; (grids, scan ms, grid ms)."""
    scan_ms, grid_ms, grids = [], [], []
    with Simulator(scenario, seed=seed) as sim:
        grid_from_points(sim.scan(poses[0]), grid_config)  # compile / load the numba cache
        for pose in poses:
            start = time.perf_counter()
            points = sim.scan(pose)
            scan_ms.append((time.perf_counter() - start) * 1e3)
            start = time.perf_counter()
            grids.append(grid_from_points(points, grid_config))
            grid_ms.append((time.perf_counter() - start) * 1e3)
    return grids, scan_ms, grid_ms


def route_poses(scenario, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count, 3) poses along the mapping route (see the module docstring)."""
    route = scenario.route
    segments = np.diff(route, axis=0)
    lengths = np.hypot(segments[:, 0], segments[:, 1])
    cumulative = np.concatenate([[0.0], np.cumsum(lengths)])
    passable = scenario.passable
    world = scenario.world
    poses: list[list[float]] = []
    while len(poses) < count:
        s = rng.uniform(0.0, cumulative[-1])
        k = min(int(np.searchsorted(cumulative, s, side="right")) - 1, len(lengths) - 1)
        if lengths[k] < 1e-6:
            continue
        direction = segments[k] / lengths[k]
        xy = route[k] + direction * (s - cumulative[k])
        aside = xy + np.array([-direction[1], direction[0]]) * rng.uniform(-0.3, 0.3)
        cell = world.to_cell(aside)
        if world.inside(cell) and passable[cell[0], cell[1]]:
            xy = aside
        heading = np.arctan2(direction[1], direction[0]) + rng.uniform(-0.52, 0.52)
        if rng.random() < 0.5:
            heading += np.pi
        poses.append([xy[0], xy[1], float(wrap_angle(heading))])
    return np.asarray(poses)


def pair_sample(poses: np.ndarray, low: float, high: float, count: int, rng) -> list:
    pairs = [
        (i, j) for i, j in itertools.combinations(range(len(poses)), 2) if low <= np.hypot(*(poses[i, :2] - poses[j, :2])) <= high
    ]
    if len(pairs) > count:
        pairs = [pairs[k] for k in rng.choice(len(pairs), count, replace=False)]
    return pairs


def run_pairs(grids, poses, pairs, guess_mode: str, config: MatchingConfig, rng) -> list[dict]:
    records = []
    for i, j in pairs:
        truth = between(poses[i], poses[j])
        prepared = PreparedGrid(grids[i], config=config), PreparedGrid(grids[j], config=config)
        _, _, true_overlap, _ = verdict(*prepared, truth, config)
        guess = None
        if guess_mode == "noisy":
            noise = np.array([rng.normal(0, 0.2), rng.normal(0, 0.2), np.radians(rng.normal(0, 3))])
            guess = compose(truth, noise)
        elif guess_mode == "true":
            guess = truth
        cpu = time.process_time()
        result = match(grids[i], grids[j], initial_guess=guess, config=config)
        cpu_ms = (time.process_time() - cpu) * 1e3
        error = result.pose - truth
        records.append(
            {
                "distance_m": float(np.hypot(*(poses[i, :2] - poses[j, :2]))),
                "true_overlap": float(true_overlap),
                "accepted": bool(result.accepted),
                "translation_error_m": float(np.hypot(error[0], error[1])),
                "rotation_error_deg": float(np.degrees(abs(float(wrap_angle(error[2]))))),
                # the matcher's own estimate of its error (one sigma), to check against the errors
                "rotation_sigma_deg": float(np.degrees(np.sqrt(result.covariance[2, 2])))
                if result.covariance is not None
                else None,
                "translation_sigma_m": float(np.sqrt(result.covariance[0, 0] + result.covariance[1, 1]))
                if result.covariance is not None
                else None,
                "score": result.score,
                "wall_agreement": result.wall_agreement,
                "overlap": result.overlap,
                "matched_walls": result.matched_walls,
                "inliers": result.inliers,
                "source": result.source,
                "ms": result.elapsed_ms,
                "cpu_ms": cpu_ms,
            }
        )
    return records


def near_summary(records: list[dict], min_true_overlap: float = 0.0) -> dict:
    records = [r for r in records if r["true_overlap"] >= min_true_overlap]
    t = np.array([r["translation_error_m"] for r in records])
    a = np.array([r["rotation_error_deg"] for r in records])
    accepted = np.array([r["accepted"] for r in records])
    correct = (t < 0.1) & (a < 1.0)
    return {
        "pairs": len(records),
        "translation_error_m": {"median": _r(np.median(t)), "p90": _r(np.percentile(t, 90))},
        "rotation_error_deg": {"median": _r(np.median(a)), "p90": _r(np.percentile(a, 90))},
        "within_0.1m_1deg": _r(correct.mean()),
        "accepted": _r(accepted.mean()),
        "accepted_translation_error_m": {
            "median": _r(np.median(t[accepted])),
            "p90": _r(np.percentile(t[accepted], 90)),
        }
        if accepted.any()
        else None,
        "accepted_rotation_error_deg": {
            "median": _r(np.median(a[accepted])),
            "p90": _r(np.percentile(a[accepted], 90)),
        }
        if accepted.any()
        else None,
        "accepted_wrong": int(np.count_nonzero(accepted & ((t > 0.5) | (a > 5.0)))),
        "accepted_rotation_by_sigma": _by_sigma(
            a[accepted], [r["rotation_sigma_deg"] for r, ok in zip(records, accepted, strict=True) if ok]
        ),
        "ms": _timing(records),
    }


def _by_sigma(errors: np.ndarray, sigmas: list) -> dict | None:
    """The matcher's rotation sigma against its errors: error / sigma (median, p90), and the median
    and largest error in each quartile of sigma (the least certain last)."""
    if len(errors) < 4 or any(s is None for s in sigmas):
        return None
    sigma = np.asarray(sigmas, dtype=np.float64)
    edges = np.quantile(sigma, [0.0, 0.25, 0.5, 0.75, 1.0])
    quartile = np.clip(np.searchsorted(edges, sigma, side="right") - 1, 0, 3)
    return {
        "error_over_sigma": {"median": _r(np.median(errors / sigma)), "p90": _r(np.percentile(errors / sigma, 90))},
        "quartiles": [
            {
                "sigma_deg": [_r(edges[q]), _r(edges[q + 1])],
                "error_deg_median": _r(np.median(errors[quartile == q])),
                "error_deg_max": _r(np.max(errors[quartile == q])),
            }
            for q in range(4)
            if np.any(quartile == q)
        ],
    }


def far_summary(records: list[dict]) -> dict:
    t = np.array([r["translation_error_m"] for r in records])
    a = np.array([r["rotation_error_deg"] for r in records])
    accepted = np.array([r["accepted"] for r in records])
    wrong = accepted & ((t > 0.5) | (a > 5.0))
    return {
        "pairs": len(records),
        "false_accept_rate": _r(wrong.mean()),
        "false_accepts": int(wrong.sum()),
        "accepted_with_right_pose": int((accepted & ~wrong).sum()),
        "ms": _timing(records),
    }


def _timing(records: list[dict]) -> dict:
    ms = np.array([r["ms"] for r in records])
    cpu = np.array([r["cpu_ms"] for r in records])
    return {
        "median": _r(np.median(ms)),
        "p95": _r(np.percentile(ms, 95)),
        "cpu_median": _r(np.median(cpu)),
        "cpu_p95": _r(np.percentile(cpu, 95)),
    }


def _r(value: float) -> float:
    return round(float(value), 4)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="corridor_150m")
    parser.add_argument(
        "--generated",
        type=float,
        metavar="LENGTH",
        help="instead of --scenario: a generated corridor tree of LENGTH m with scene seed --seed",
    )
    parser.add_argument("--range-noise", type=float, default=0.0, help="m; lidar range noise of the generated scene")
    parser.add_argument("--min-wall-agreement", type=float, help="override MatchingConfig.min_wall_agreement")
    parser.add_argument("--min-score", type=float, help="override MatchingConfig.min_score")
    parser.add_argument("--poses", type=int, default=300)
    parser.add_argument("--near", type=float, default=5.0, help="near pairs: at most this far, m")
    parser.add_argument("--far", type=float, default=15.0, help="far pairs: at least this far, m")
    parser.add_argument("--near-pairs", type=int, default=300)
    parser.add_argument("--far-pairs", type=int, default=500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", action="store_true", help="print the summary as JSON only")
    parser.add_argument("--records", help="write every pair's record to this JSON file")
    args = parser.parse_args()

    rng = np.random.default_rng(args.seed)
    if args.generated is not None:
        scenario = generated_scenario(args.generated, args.seed, args.range_noise)
    else:
        if args.range_noise:
            parser.error("--range-noise applies to --generated scenes (a scenario file sets sensor.range_noise)")
        scenario = load_scenario(args.scenario, with_trials=False)
    grid_config = GridConfig()
    overrides = {"min_wall_agreement": args.min_wall_agreement, "min_score": args.min_score}
    config = MatchingConfig(**{key: value for key, value in overrides.items() if value is not None})
    poses = route_poses(scenario, args.poses, rng)
    grids, scan_ms, grid_ms = scan_grids(scenario, poses, args.seed, grid_config)
    match(grids[0], grids[1])  # compile / load the numba cache

    near_pairs = pair_sample(poses, 0.0, args.near, args.near_pairs, rng)
    far_pairs = pair_sample(poses, args.far, np.inf, args.far_pairs, rng)
    records = {
        "near_no_guess": run_pairs(grids, poses, near_pairs, "none", config, rng),
        "near_noisy_guess": run_pairs(grids, poses, near_pairs, "noisy", config, rng),
        "far_no_guess": run_pairs(grids, poses, far_pairs, "none", config, rng),
        "far_true_guess": run_pairs(grids, poses, far_pairs, "true", config, rng),
    }
    # what NavTopo pays when grids are prepared once (the current grid per tick, the vertex
    # grids cached): prepare cost per grid, then the match itself. CPU time beside wall time:
    # on a shared machine the wall clock also counts other processes' turns.
    wall, cpu = time.perf_counter(), time.process_time()
    prepared = [PreparedGrid(grid, grid_config, config) for grid in grids]
    for grid in prepared:
        grid.features  # noqa: B018 - computed on first use
    prepare_ms = {
        "wall": (time.perf_counter() - wall) * 1e3 / len(grids),
        "cpu": (time.process_time() - cpu) * 1e3 / len(grids),
    }
    prepared_ms: dict[str, list[float]] = {"no_guess": [], "noisy_guess": []}
    prepared_cpu_ms: dict[str, list[float]] = {"no_guess": [], "noisy_guess": []}
    for i, j in near_pairs:
        truth = between(poses[i], poses[j])
        noise = np.array([rng.normal(0, 0.2), rng.normal(0, 0.2), np.radians(rng.normal(0, 3))])
        for key, guess in (("no_guess", None), ("noisy_guess", compose(truth, noise))):
            cpu = time.process_time()
            result = match(prepared[i], prepared[j], initial_guess=guess, config=config)
            prepared_cpu_ms[key].append((time.process_time() - cpu) * 1e3)
            prepared_ms[key].append(result.elapsed_ms)

    summary = {
        "scenario": scenario.name,
        "min_wall_agreement": config.min_wall_agreement,
        "min_score": config.min_score,
        "poses": len(poses),
        "seed": args.seed,
        "scan_ms_median": _r(np.median(scan_ms)),
        "grid_ms": {"median": _r(np.median(grid_ms)), "p95": _r(np.percentile(grid_ms, 95))},
        "prepare_ms_per_grid": {key: _r(v) for key, v in prepare_ms.items()},
        "prepared_match_ms": {
            key: {
                "median": _r(np.median(v)),
                "p95": _r(np.percentile(v, 95)),
                "cpu_median": _r(np.median(prepared_cpu_ms[key])),
                "cpu_p95": _r(np.percentile(prepared_cpu_ms[key], 95)),
            }
            for key, v in prepared_ms.items()
        },
        "near_no_guess": near_summary(records["near_no_guess"]),
        "near_no_guess_overlap_0.3": near_summary(records["near_no_guess"], 0.3),
        "near_noisy_guess": near_summary(records["near_noisy_guess"]),
        "near_noisy_guess_overlap_0.3": near_summary(records["near_noisy_guess"], 0.3),
        "far_no_guess": far_summary(records["far_no_guess"]),
        "far_true_guess": far_summary(records["far_true_guess"]),
    }
    if args.records:
        with open(args.records, "w") as f:
            json.dump({"summary": summary, "records": records, "poses": poses.tolist()}, f)
    print(json.dumps(summary, indent=None if args.json else 2))


if __name__ == "__main__":
    main()
