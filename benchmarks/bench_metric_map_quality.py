"""Figures of the metric baseline from a results folder: map quality against ground truth, and
the run's own success, efficiency, planning and memory figures, in one JSON object per run.

Map quality is issue 5's definition (``baselines.metric_grid.occupancy.map_quality``): wall recall
is the share of ground-truth wall cells (non-free cells touching free space, 0.05 m raster) with
a mapped occupied cell centre within 0.2 m; occupied precision the share of mapped occupied cells
within 0.2 m of a ground-truth wall cell. The saved map is in the map frame (the mapping run's
first pose), so its cell centres are moved to the scenario frame before comparing. Tracking error
compares each trial's ``trial-<i>.est.tum`` (map frame) with the true ``trial-<i>.tum`` at the same
stamps. A benchmark may read ground truth; no system does.

    .venv/bin/python benchmarks/bench_metric_map_quality.py RUN_DIR [RUN_DIR ...] [--system metric_grid]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from baselines.metric_grid.occupancy import GridMap
from navkit import geometry as se2
from navkit.raster import OCCUPIED
from scenarios import load_scenario


def wall_quality(grid_map: GridMap, scenario, tol: float = 0.2) -> tuple[float, float]:
    mapped = se2.transform_points(scenario.route_start, grid_map.centres(grid_map.cells == OCCUPIED))
    walls = scenario.world.to_world(np.argwhere(scenario.world.wall_mask))
    to_mapped, _ = cKDTree(mapped).query(walls, distance_upper_bound=tol + 1e-9)
    to_walls, _ = cKDTree(walls).query(mapped, distance_upper_bound=tol + 1e-9)
    return float(np.isfinite(to_mapped).mean()), float(np.isfinite(to_walls).mean())


def _yaw(qz: np.ndarray, qw: np.ndarray) -> np.ndarray:
    return 2.0 * np.arctan2(qz, qw)


def tracking_errors(run: Path, system: str, scenario) -> dict | None:
    """Median and max position error of the system's pose estimate over all trials (m)."""
    errors = []
    for estimate_file in sorted((run / "trajectories" / system).glob("trial-*.est.tum")):
        true_file = estimate_file.with_name(estimate_file.name.replace(".est.tum", ".tum"))
        est = np.loadtxt(estimate_file, ndmin=2)
        true = np.loadtxt(true_file, ndmin=2)
        at = np.clip(np.searchsorted(true[:, 0], est[:, 0] - 1e-6), 0, len(true) - 1)
        true_map = se2.transform_points(se2.inverse(scenario.route_start), true[at, 1:3])
        errors.append(np.hypot(*(est[:, 1:3] - true_map).T))
    if not errors:
        return None
    every = np.concatenate(errors)
    per_trial_max = [float(e.max()) for e in errors]
    return {
        "median_m": round(float(np.median(every)), 4),
        "p95_m": round(float(np.percentile(every, 95)), 4),
        "max_m": round(float(every.max()), 4),
        "worst_trial_max_m": round(max(per_trial_max), 4),
    }


def report(run: Path, system: str) -> dict:
    manifest = json.loads((run / "manifest.json").read_text())
    scenario = load_scenario(manifest["scenario"]["file"])
    grid_map = GridMap.load(run / "maps" / system / "map.yaml")
    recall, precision = wall_quality(grid_map, scenario)
    summary = json.loads((run / "summary.json").read_text()).get(system, {})
    mapping = json.loads((run / "mapping" / f"{system}.json").read_text())
    navigation_file = run / "navigation" / f"{system}.json"
    navigation = json.loads(navigation_file.read_text()) if navigation_file.is_file() else {}
    state_keys = ("keyframe_scan_bytes", "kiss_icp_map_bytes", "pose_graph_bytes", "log_odds_grid_bytes", "mapping_state_bytes")
    return {
        "run": str(run),
        "scenario": scenario.name,
        "odometry_noise": None if scenario.spec.odometry.noise is None else scenario.spec.odometry.noise.model_dump(),
        "config_odometry_source": manifest["config"][system]["odometry"]["source"],
        "config_localization": manifest["config"][system]["localization"]["enabled"],
        "map_quality": {"wall_recall": round(recall, 4), "occupied_precision": round(precision, 4), "tolerance_m": 0.2},
        "grid_shape": list(grid_map.cells.shape),
        "success": f"{summary.get('successes')}/{summary.get('trials')}",
        "failure_reasons": summary.get("failure_reasons"),
        "efficiency_mean": summary.get("efficiency_mean"),
        "spl_mean": summary.get("spl_mean"),
        "planning_ms": summary.get("planning_ms"),
        "memory": summary.get("memory"),
        "navigation": navigation,
        "mapping": {
            "scans": mapping.get("scans"),
            "route_length_m": mapping.get("route_length_m"),
            "ms_per_scan": mapping.get("ms_per_scan"),
            "map_bytes": mapping.get("map_bytes"),
            "map_disk_bytes": mapping.get("map_disk_bytes"),
            "keyframes": mapping.get("keyframes"),
            "loop_closures": mapping.get("loop_closures"),
            "loop_attempts": mapping.get("loop_attempts"),
            **{key: mapping.get(key) for key in state_keys},
        },
        "tracking_error": tracking_errors(run, system, scenario),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="results folders of `navtopo-bench run`")
    parser.add_argument("--system", default="metric_grid")
    args = parser.parse_args()
    for run in args.runs:
        print(json.dumps(report(run, args.system), indent=2))


if __name__ == "__main__":
    main()
