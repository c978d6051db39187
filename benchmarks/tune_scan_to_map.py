"""Tune ``ScanToMapConfig.wall_depth`` (the metric baseline's scan-to-map localizer) on generated
scenes: the bias and error of the fitted pose against the true pose, per wall depth.

For each scene and setting, the map is the metric baseline's own map of that scene (built by
``tune_metric_mapping.py``'s replay of the recorded mapping drive with ``--map-config``, saved
under CACHE/maps). Then, at random poses in the mapped free space (true pose known, any heading),
the simulator takes a scan (with the setting's range noise); its obstacle points are what
``MetricGrid.step`` registers (``voxel_filter_2d(obstacle_points(points, band), voxel)`` within
``max_range``), and ``ScanToMap(grid_map, config).fit(points, predicted)`` runs from

* the true pose (``from truth``): where the fit moves away from the truth is the bias of the
  objective itself (the field's zero not on the walls), with nothing to converge from;
* the true pose perturbed by N(0, ``--perturb-xy``) per axis and N(0, ``--perturb-yaw-deg``)
  (``perturbed``): what tracking sees, a prediction a few cm and a degree off.

Errors are ``between(true, fitted)``: x forward, y left of the robot, and yaw. Reported per wall
depth: the accepted share, translation error median / p90, yaw error median / p90, and the mean
signed error (x, y, yaw) as a bias. Independently of any fit, the signed distance of the scan's
points at the true pose to the mapped occupied cells' boundary (``point_depth``: median over
points within 0.15 m of it) measures where the walls lie inside the occupied cells, which is
what ``wall_depth`` models.

Tuning rule: scenes from ``scenarios.generators`` with seeds disjoint from the benchmark's
(101-103); never a bundled scene.

    .venv/bin/python benchmarks/tune_scan_to_map.py --seeds 101,102,103 --settings precise,noisy \\
        --json data/tuning/scan_to_map.json
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from _tuning import git_state, parse_list, scene_arguments, scenes
from tune_metric_mapping import CANDIDATES, replay

from baselines.metric_grid.config import ScanConfig
from baselines.metric_grid.localization import ScanToMap, ScanToMapConfig
from baselines.metric_grid.occupancy import GridMap
from baselines.metric_grid.scan2d import voxel_filter_2d
from navkit import geometry as se2
from navkit.raster import FREE
from navkit.scan import obstacle_points
from runners.sim import Simulator

TUNING_STREAM = 3  # the simulator's noise stream for these scans (mapping is 1, trials 2)


def sample_poses(scenario, grid_map: GridMap, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count, 3) scene-frame poses: passable for the robot, on a FREE cell of the map, any heading."""
    world = scenario.world
    cells = np.argwhere(scenario.passable)
    poses: list[list[float]] = []
    while len(poses) < count:
        xy = world.to_world(cells[rng.integers(len(cells))][None])[0] + rng.uniform(-0.5, 0.5, 2) * world.resolution
        in_map = se2.transform_points(se2.inverse(scenario.route_start), xy[None])
        row, col = grid_map.cell_of(in_map)[0]
        height, width = grid_map.cells.shape
        if not (0 <= row < height and 0 <= col < width) or grid_map.cells[row, col] != FREE:
            continue
        poses.append([xy[0], xy[1], rng.uniform(-np.pi, np.pi)])
    return np.asarray(poses)


def fit_errors(localizer: ScanToMap, points: np.ndarray, truth: np.ndarray, start: np.ndarray) -> list[float] | None:
    fit = localizer.fit(points, start)
    if fit is None:
        return None
    error = se2.between(truth, fit[0])
    return [float(error[0]), float(error[1]), float(error[2])]


def summarise(errors: list[list[float] | None]) -> dict[str, Any]:
    accepted = [e for e in errors if e is not None]
    out: dict[str, Any] = {"fits": len(errors), "accepted": round(len(accepted) / max(len(errors), 1), 4)}
    if not accepted:
        return out
    e = np.asarray(accepted)
    t = np.hypot(e[:, 0], e[:, 1])
    yaw = np.degrees(np.abs(e[:, 2]))
    out.update(
        translation_cm={
            "median": round(100 * float(np.median(t)), 2),
            "p90": round(100 * float(np.percentile(t, 90)), 2),
            "rms": round(100 * float(np.sqrt(np.mean(t**2))), 2),
        },
        yaw_deg={"median": round(float(np.median(yaw)), 3), "p90": round(float(np.percentile(yaw, 90)), 3)},
        bias={
            "x_cm": round(100 * float(e[:, 0].mean()), 2),
            "y_cm": round(100 * float(e[:, 1].mean()), 2),
            "yaw_deg": round(float(np.degrees(e[:, 2].mean())), 3),
            "x_cm_se": round(100 * float(e[:, 0].std() / np.sqrt(len(e))), 2),
        },
    )
    return out


def run_scene(scenario, key: str, maps: dict[str, GridMap], args) -> list[dict[str, Any]]:
    """Scans at random poses of one scene, fitted in each of its maps (one result per map)."""
    seed = int(scenario.spec.seed)
    rng = np.random.default_rng([seed, TUNING_STREAM])
    poses = sample_poses(scenario, next(iter(maps.values())), args.poses, rng)
    starts = rng.normal(0.0, 1.0, (len(poses), 3)) * [args.perturb_xy, args.perturb_xy, np.radians(args.perturb_yaw_deg)]
    band = ScanConfig()
    base = ScanToMapConfig()
    localizers = {
        name: {d: ScanToMap(grid_map, base.model_copy(update={"wall_depth": d})) for d in args.depths}
        for name, grid_map in maps.items()
    }
    boundary = {name: ScanToMap(grid_map, base.model_copy(update={"wall_depth": 0.0})) for name, grid_map in maps.items()}
    errors: dict[str, dict[str, dict[float, list[list[float] | None]]]] = {
        name: {start: {d: [] for d in args.depths} for start in ("truth", "perturbed")} for name in maps
    }
    depths_seen: dict[str, list[float]] = {name: [] for name in maps}
    to_map = se2.inverse(scenario.route_start)
    with Simulator(scenario, seed=seed) as sim:
        sim.reset(scenario.route_start, stream=(TUNING_STREAM,))
        for pose, noise in zip(poses, starts, strict=True):
            scan = sim.scan(pose)
            points = voxel_filter_2d(obstacle_points(scan, band), base.voxel)
            points = points[np.hypot(points[:, 0], points[:, 1]) <= base.max_range]
            truth = se2.compose(to_map, pose)
            start = se2.compose(truth, noise)
            world = se2.transform_points(truth, points.astype(np.float64))
            for name in maps:
                residual = boundary[name].sample(world)[0]
                near = residual[np.abs(residual) < 0.15]
                if len(near):
                    depths_seen[name].append(-float(np.median(near)))
                for d, localizer in localizers[name].items():
                    errors[name]["truth"][d].append(fit_errors(localizer, points, truth, truth))
                    errors[name]["perturbed"][d].append(fit_errors(localizer, points, truth, start))
    setting = key.rsplit("_", 1)[1]
    return [
        {
            "scene": key,
            "setting": setting,
            "map_config": name,
            "poses": len(poses),
            "point_depth_m": {
                "median": round(float(np.median(depths_seen[name])), 4),
                "mean": round(float(np.mean(depths_seen[name])), 4),
            },
            "by_depth": {
                f"{d:g}": {start: summarise(errors[name][start][d]) for start in ("truth", "perturbed")} for d in args.depths
            },
            "raw": {start: {f"{d:g}": errors[name][start][d] for d in args.depths} for start in ("truth", "perturbed")},
        }
        for name in maps
    ]


def pooled(results: list[dict], setting: str, map_config: str, depth: str, start: str) -> dict[str, Any]:
    errors = [e for r in results if r["setting"] == setting and r["map_config"] == map_config for e in r["raw"][start][depth]]
    return summarise(errors)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    scene_arguments(parser, kind="tree", length=150.0, seeds="101,102,103", settings="precise,noisy")
    parser.add_argument(
        "--map-config",
        default="precise=wheel-noloops+wheel+lidar,noisy=lidar+lidar-s0.1",
        help="per setting, the mapping candidates (tune_metric_mapping.CANDIDATES, joined by +) whose maps "
        "the scans are fitted in; wheel-noloops in the precise setting is the map at the true poses",
    )
    parser.add_argument("--depths", default="0,0.0125,0.025,0.0375,0.05", help="wall_depth values, m")
    parser.add_argument("--poses", type=int, default=300, help="random poses per scene")
    parser.add_argument("--perturb-xy", type=float, default=0.05, help="m, std per axis of the predicted pose's error")
    parser.add_argument("--perturb-yaw-deg", type=float, default=1.0, help="deg, std of the predicted heading's error")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    args.depths = parse_list(args.depths, float)
    map_config = dict(item.split("=", 1) for item in parse_list(args.map_config))
    settings = parse_list(args.settings)

    results = []
    for setting, scenario, rec, key in scenes(args):
        maps = {}
        for name in map_config[setting].split("+"):
            map_yaml = args.cache / "maps" / key / name / "map.yaml"
            if not map_yaml.is_file():
                print(f"building the {name} map of {key} ...", flush=True)
                replay(scenario, rec, key, name, CANDIDATES[name], args.cache, save_maps=True)
            maps[name] = GridMap.load(map_yaml)
        started = time.perf_counter()
        for result in run_scene(scenario, key, maps, args):
            results.append(result)
            depth = result["point_depth_m"]
            print(f"{key} ({result['map_config']} map): point depth median {depth['median']:.4f} m", flush=True)
            for wall_depth, by_start in result["by_depth"].items():
                p = by_start["perturbed"]
                print(
                    f"  wall_depth {wall_depth}: accepted {p['accepted']:.3f}, "
                    f"translation median {p['translation_cm']['median']:.2f} cm, "
                    f"bias x {p['bias']['x_cm']:+.2f} y {p['bias']['y_cm']:+.2f} cm",
                    flush=True,
                )
        print(f"  [{time.perf_counter() - started:.0f} s]", flush=True)

    print(
        "\n| setting | map | wall_depth (m) | start | accepted | translation median / p90 / rms (cm) | yaw median / p90 (°) "
        "| mean error x / y (cm), yaw (°) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    table = []
    for setting in settings:
        for name in map_config[setting].split("+"):
            for depth in (f"{d:g}" for d in args.depths):
                for start in ("truth", "perturbed"):
                    s = pooled(results, setting, name, depth, start)
                    table.append({"setting": setting, "map_config": name, "wall_depth": float(depth), "start": start, **s})
                    if "translation_cm" not in s:
                        print(f"| {setting} | {name} | {depth} | {start} | {s['accepted']:.3f} | – | – | – |")
                        continue
                    t, y, b = s["translation_cm"], s["yaw_deg"], s["bias"]
                    print(
                        f"| {setting} | {name} | {depth} | {start} | {s['accepted']:.3f} "
                        f"| {t['median']:.2f} / {t['p90']:.2f} / {t['rms']:.2f} "
                        f"| {y['median']:.3f} / {y['p90']:.3f} | {b['x_cm']:+.2f} / {b['y_cm']:+.2f}, {b['yaw_deg']:+.3f} |"
                    )
    print("\n| setting | map | scene | point depth median / mean (m) |")
    print("|---|---|---|---|")
    for r in results:
        depth = r["point_depth_m"]
        print(
            f"| {r['setting']} | {r['map_config']} | {r['scene'].split('_r')[0]} | {depth['median']:.4f} / {depth['mean']:.4f} |"
        )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        meta = {"argv": sys.argv[1:], **git_state(), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
        for r in results:
            r.pop("raw")
        args.json.write_text(json.dumps({"meta": meta, "table": table, "results": results}, indent=1) + "\n")


if __name__ == "__main__":
    main()
