"""Tune the metric baseline's mapping config (odometry source, odometry-factor sigmas, loop
closures) on generated scenes, in both benchmark settings, by replaying recorded mapping drives.

What it measures, per (scene, setting, candidate config):

* map quality as ``bench_metric_map_quality.py`` defines it (issue 5): wall recall (GT wall cells
  with a mapped occupied cell within 0.2 m) and occupied precision (mapped occupied cells within
  0.2 m of a GT wall), the map in the map frame moved to the scene frame by the route's start;
* keyframe ATE: the optimised keyframe poses against the true poses, in the map frame (RMSE and
  max), and after a rigid 2D alignment (RMSE and the alignment's rotation: a consistent map whose
  frame turned about the first pose has a small aligned RMSE and a large rotation);
* the odometry's keyframe-to-keyframe error (RMS, translation and yaw) and its ratio to the
  factor sigmas the config gives (``z``: about 1 when the sigmas are the measured error; far
  below 1 when the factors are looser than the odometry);
* verified loop closures, and those whose measurement is off the truth by > 0.1 m or > 1°.

Method: each (scene, setting) mapping drive is simulated once (``_tuning.record_drive``, as
``runners.mapping`` drives it) and cached under ``--cache``; each candidate replays it through
``MetricGrid.create(config, context).observe(obs)`` ... ``finish_mapping()``. kiss-icp's poses
depend only on the odometry config, so they are computed once per drive and replayed into the
pose graph (``ReplayedOdometry``); the online grid is off (the saved map is traced from the
keyframes at their optimised poses in ``finish_mapping`` either way).

Tuning rule: scenes come from ``scenarios.generators`` with seeds disjoint from the benchmark's
(101-103, never 1/7/11/150); no bundled scene (corridor_150m, tiny, ...) is used.

    .venv/bin/python benchmarks/tune_metric_mapping.py --seeds 101,102,103 --length 150 \\
        --settings precise,noisy --json data/tuning/metric_mapping.json
"""

from __future__ import annotations

import argparse
import copy
import hashlib
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from _tuning import Recording, git_state, parse_list, scene_arguments, scenes
from bench_metric_map_quality import wall_quality

from baselines.metric_grid.system import NOISY_ODOMETRY, PRECISE_ODOMETRY, MetricGrid, MetricGridConfig
from navkit import geometry as se2
from navkit.odometry import LidarOdometry
from runners.systems import SystemContext


def _sigmas(xy: float, xy_per_m: float, yaw: float, yaw_per_m: float) -> dict[str, float]:
    return {
        "odometry_sigma_xy": xy,
        "odometry_sigma_xy_per_m": xy_per_m,
        "odometry_sigma_yaw_deg": yaw,
        "odometry_sigma_yaw_deg_per_m": yaw_per_m,
    }


NO_LOOPS = {"pose_graph": {"loop": {"enabled": False}}}
LIDAR = {"odometry": {"source": "lidar"}}

#: name -> overrides of MetricGridConfig (on top of its defaults)
CANDIDATES: dict[str, dict[str, Any]] = {
    "wheel": {},  # the default config (precise recipe)
    "wheel-noloops": NO_LOOPS,
    "wheel-s0.1": {"pose_graph": _sigmas(0.01, 0.01, 0.1, 0.1)},
    "wheel-precise": PRECISE_ODOMETRY,  # today's precise recipe: factors as tight as exact odometry
    "lidar": LIDAR,  # kiss-icp seeded by the wheels, pose-graph default sigmas
    "lidar-s0.05": {**LIDAR, "pose_graph": _sigmas(0.01, 0.01, 0.05, 0.05)},
    "lidar-s0.1": NOISY_ODOMETRY,  # today's noisy recipe
    "lidar-s0.25": {**LIDAR, "pose_graph": _sigmas(0.01, 0.01, 0.25, 0.25)},
    "lidar-s0.1-xy0.02": {**LIDAR, "pose_graph": _sigmas(0.02, 0.02, 0.1, 0.1)},
    "lidar-s0.1-noloops": {**NOISY_ODOMETRY, "pose_graph": {**NOISY_ODOMETRY["pose_graph"], "loop": {"enabled": False}}},
    # kiss-icp's own keyframe-to-keyframe error, measured by this script in both settings (RMS per
    # axis 0.8-0.9 cm, yaw 0.05° at the 0.75 m keyframe step): sigmas equal to it (z about 1)
    "lidar-measured": {**LIDAR, "pose_graph": _sigmas(0.005, 0.005, 0.03, 0.03)},
    "lidar-xy0.01-yaw0.5": {**LIDAR, "pose_graph": _sigmas(0.01, 0.01, 0.5, 0.5)},
    "lidar-xy0.05": {**LIDAR, "pose_graph": _sigmas(0.05, 0.05, 0.5, 0.5)},
    "lidar-yaw0.25": {**LIDAR, "pose_graph": _sigmas(0.02, 0.02, 0.25, 0.25)},
    "lidar-yaw1": {**LIDAR, "pose_graph": _sigmas(0.02, 0.02, 1.0, 1.0)},
}
#: what ``--configs default`` replays
DEFAULT_SET = (
    "wheel",
    "wheel-noloops",
    "wheel-s0.1",
    "wheel-precise",
    "lidar",
    "lidar-measured",
    "lidar-s0.1",
    "lidar-s0.1-xy0.02",
    "lidar-s0.1-noloops",
)


def merge(base: dict[str, Any], extra: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for key, value in extra.items():
        out[key] = merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def make_config(overrides: dict[str, Any]) -> MetricGridConfig:
    # the online grid does not change the saved map (finish_mapping traces it anew): off for speed
    return MetricGridConfig.model_validate(merge(overrides, {"online_grid": False}))


class ReplayedOdometry:
    """Stands in for ``LidarOdometry`` in a replay: the poses an earlier run of it produced."""

    def __init__(self, poses: np.ndarray) -> None:
        self.poses = poses
        self.scans = 0
        self.nbytes = 0

    def update(self, points: np.ndarray, wheel_odom: np.ndarray) -> np.ndarray:
        pose = self.poses[self.scans]
        self.scans += 1
        return pose.copy()


def lidar_odometry(rec: Recording, key: str, system: MetricGrid, cache: Path) -> np.ndarray:
    """(T, 3) kiss-icp poses of a drive for the system's odometry config, cached per config."""
    odometry_config = system.config.odometry
    digest = hashlib.sha1(json.dumps(odometry_config.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()[:10]
    path = cache / "odometry" / f"{key}_{digest}.npz"
    if path.is_file():
        with np.load(path) as data:
            return data["poses"]
    started = time.perf_counter()
    odometry = LidarOdometry(odometry_config)
    poses = np.array([odometry.update(rec.observation(k).points, rec.odom[k]) for k in range(len(rec))])
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, poses=poses, seconds=time.perf_counter() - started)
    print(f"  kiss-icp over {len(rec)} scans: {time.perf_counter() - started:.0f} s", flush=True)
    return poses


def rigid_alignment(estimate: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(RMSE after the best rigid 2D alignment of estimate onto truth, its rotation in degrees)."""
    a, b = estimate - estimate.mean(axis=0), truth - truth.mean(axis=0)
    angle = np.arctan2(np.sum(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]), np.sum(a * b))
    c, s = np.cos(angle), np.sin(angle)
    turned = a @ np.array([[c, s], [-s, c]])
    return float(np.sqrt(np.mean(np.sum((turned - b) ** 2, axis=1)))), float(np.degrees(angle))


def replay(scenario, rec: Recording, key: str, name: str, overrides: dict, cache: Path, save_maps: bool) -> dict[str, Any]:
    config = make_config(overrides)
    context = SystemContext(robot=scenario.spec.robot, sensor=scenario.spec.sensor)
    system = MetricGrid.create(config, context)
    if system.config.odometry.source == "lidar":
        system.odometry = ReplayedOdometry(lidar_odometry(rec, key, system, cache))  # type: ignore[assignment]
    graph = system.pose_graph
    assert graph is not None
    started = time.perf_counter()
    keyframe_scans = []
    for k in range(len(rec)):
        before = len(graph.keyframes)
        system.observe(rec.observation(k))
        if len(graph.keyframes) > before:
            keyframe_scans.append(k)
    system.finish_mapping()
    seconds = time.perf_counter() - started
    assert system.grid_map is not None
    recall, precision = wall_quality(system.grid_map, scenario)
    if save_maps:
        system.grid_map.save(cache / "maps" / key / name / "map.yaml")

    truth = rec.true_in_map(scenario.route_start)[keyframe_scans]
    estimate = graph.poses()
    errors = np.hypot(*(estimate[:, :2] - truth[:, :2]).T)
    aligned_rmse, align_deg = rigid_alignment(estimate[:, :2], truth[:, :2])
    # odometry between consecutive keyframes against the truth, and against the factor sigmas
    odom = np.array([kf.odom_pose for kf in graph.keyframes])
    measured = se2.between(odom[:-1], odom[1:])
    true_delta = se2.between(truth[:-1], truth[1:])
    error = se2.between(true_delta, measured)
    step = np.hypot(measured[:, 0], measured[:, 1])
    pg = system.config.pose_graph
    sigma_xy = pg.odometry_sigma_xy + pg.odometry_sigma_xy_per_m * step
    sigma_yaw = np.deg2rad(pg.odometry_sigma_yaw_deg + pg.odometry_sigma_yaw_deg_per_m * step)
    err_xy = np.hypot(error[:, 0], error[:, 1]) / np.sqrt(2.0)  # per axis, as the factor's sigma is
    err_yaw = np.abs(error[:, 2])
    # loop measurements against the truth
    bad_loops = 0
    for loop in graph.loops:
        off = se2.between(se2.between(truth[loop.old], truth[loop.new]), loop.pose)
        bad_loops += int(np.hypot(off[0], off[1]) > 0.1 or abs(off[2]) > np.deg2rad(1.0))
    return {
        "scene": key,
        "setting": key.rsplit("_", 1)[1],
        "config": name,
        "overrides": overrides,
        "wall_recall": round(recall, 4),
        "occupied_precision": round(precision, 4),
        "ate_rmse_m": round(float(np.sqrt(np.mean(errors**2))), 4),
        "ate_max_m": round(float(errors.max()), 4),
        "aligned_rmse_m": round(aligned_rmse, 4),
        "alignment_yaw_deg": round(align_deg, 4),
        "keyframes": len(graph.keyframes),
        "loop_closures": len(graph.loops),
        "bad_loops": bad_loops,
        "odometry_keyframe_error": {
            "step_m_median": round(float(np.median(step)), 3),
            "xy_rms_m": round(float(np.sqrt(np.mean(err_xy**2))), 5),
            "yaw_rms_deg": round(float(np.degrees(np.sqrt(np.mean(err_yaw**2)))), 4),
            "yaw_p99_deg": round(float(np.degrees(np.percentile(err_yaw, 99))), 4),
            "z_xy_rms": round(float(np.sqrt(np.mean((err_xy / sigma_xy) ** 2))), 3),
            "z_yaw_rms": round(float(np.sqrt(np.mean((err_yaw / sigma_yaw) ** 2))), 3),
        },
        "replay_s": round(seconds, 1),
    }


def summarise(results: list[dict]) -> list[dict]:
    rows = []
    keys = sorted(
        {(r["setting"], r["config"]) for r in results},
        key=lambda k: (k[0], list(CANDIDATES).index(k[1]) if k[1] in CANDIDATES else 99),
    )
    for setting, name in keys:
        rs = [r for r in results if r["setting"] == setting and r["config"] == name]
        rows.append(
            {
                "setting": setting,
                "config": name,
                "scenes": len(rs),
                "wall_recall_mean": round(float(np.mean([r["wall_recall"] for r in rs])), 4),
                "wall_recall_min": round(float(np.min([r["wall_recall"] for r in rs])), 4),
                "occupied_precision_mean": round(float(np.mean([r["occupied_precision"] for r in rs])), 4),
                "occupied_precision_min": round(float(np.min([r["occupied_precision"] for r in rs])), 4),
                "ate_rmse_m_mean": round(float(np.mean([r["ate_rmse_m"] for r in rs])), 4),
                "ate_rmse_m_max": round(float(np.max([r["ate_rmse_m"] for r in rs])), 4),
                "bad_loops": int(sum(r["bad_loops"] for r in rs)),
            }
        )
    return rows


def print_tables(results: list[dict], rows: list[dict]) -> None:
    print(
        "\n| setting | config | scene | wall recall | occupied precision | ATE rmse / max (m) | aligned rmse (m), rotation (°) "
        "| odom err per kf xy (cm) / yaw (°) | z xy / yaw | loops (bad) | replay s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in sorted(results, key=lambda r: (r["setting"], r["config"], r["scene"])):
        e = r["odometry_keyframe_error"]
        scene = r["scene"].split("_r")[0]
        print(
            f"| {r['setting']} | {r['config']} | {scene} | {r['wall_recall']:.3f} | {r['occupied_precision']:.3f} "
            f"| {r['ate_rmse_m']:.3f} / {r['ate_max_m']:.3f} | {r['aligned_rmse_m']:.3f}, {r['alignment_yaw_deg']:+.3f} "
            f"| {100 * e['xy_rms_m']:.2f} / {e['yaw_rms_deg']:.3f} | {e['z_xy_rms']:.2f} / {e['z_yaw_rms']:.2f} "
            f"| {r['loop_closures']} ({r['bad_loops']}) | {r['replay_s']:.0f} |"
        )
    print(
        "\n| setting | config | scenes | wall recall mean (min) | occupied precision mean (min) "
        "| ATE rmse mean (max), m | bad loops |"
    )
    print("|---|---|---|---|---|---|---|")
    for row in rows:
        print(
            f"| {row['setting']} | {row['config']} | {row['scenes']} "
            f"| {row['wall_recall_mean']:.3f} ({row['wall_recall_min']:.3f}) "
            f"| {row['occupied_precision_mean']:.3f} ({row['occupied_precision_min']:.3f}) "
            f"| {row['ate_rmse_m_mean']:.3f} ({row['ate_rmse_m_max']:.3f}) | {row['bad_loops']} |"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    scene_arguments(parser, kind="tree", length=150.0, seeds="101,102,103", settings="precise,noisy")
    parser.add_argument(
        "--configs",
        default="default",
        help=f"comma-separated candidates, default ({', '.join(DEFAULT_SET)}) or all: {', '.join(CANDIDATES)}",
    )
    parser.add_argument(
        "--extra",
        action="append",
        default=[],
        metavar="NAME=YAML",
        help="an ad hoc candidate: overrides of MetricGridConfig as YAML",
    )
    parser.add_argument("--save-maps", action="store_true", help="save each map under CACHE/maps (for tune_scan_to_map.py)")
    parser.add_argument("--json", type=Path, help="write every result and the summary here")
    parser.add_argument("--fresh", action="store_true", help="replay again even if CACHE/results holds this result")
    args = parser.parse_args()

    candidates = dict(CANDIDATES) if args.configs == "all" else {}
    if args.configs != "all":
        for name in DEFAULT_SET if args.configs == "default" else parse_list(args.configs):
            if name not in CANDIDATES:
                parser.error(f"unknown candidate {name!r}; known: {', '.join(CANDIDATES)}")
            candidates[name] = CANDIDATES[name]
    for extra in args.extra:
        name, _, text = extra.partition("=")
        candidates[name] = yaml.safe_load(text) or {}
    for overrides in candidates.values():
        make_config(overrides)  # fail early on a bad candidate

    results = []
    for _, scenario, rec, key in scenes(args):
        for name, overrides in candidates.items():
            r = cached_replay(scenario, rec, key, name, overrides, args)
            results.append(r)
            print(
                f"{key} {name}: recall {r['wall_recall']:.3f} precision {r['occupied_precision']:.3f} "
                f"ATE {r['ate_rmse_m']:.3f} m (aligned {r['aligned_rmse_m']:.3f} m, {r['alignment_yaw_deg']:+.3f}°) "
                f"loops {r['loop_closures']} bad {r['bad_loops']} [{r['replay_s']:.0f} s]",
                flush=True,
            )
            write_json(args, results)
    print_tables(results, summarise(results))
    write_json(args, results)


def cached_replay(scenario, rec: Recording, key: str, name: str, overrides: dict, args) -> dict[str, Any]:
    """A replay's result, reused from CACHE/results when the same code replayed the same candidate."""
    state = git_state()
    identity = json.dumps({"overrides": overrides, "revision": state["git_revision"]}, sort_keys=True)
    digest = hashlib.sha1(identity.encode()).hexdigest()[:10]
    path = args.cache / "results" / key / f"{name}_{digest}.json"
    usable = state["git_revision"] is not None and not state["git_dirty"] and not args.fresh
    if usable and path.is_file() and not (args.save_maps and not (args.cache / "maps" / key / name / "map.yaml").is_file()):
        return json.loads(path.read_text())
    result = replay(scenario, rec, key, name, overrides, args.cache, args.save_maps)
    result.update(state)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1) + "\n")
    return result


def write_json(args, results: list[dict]) -> None:
    if not args.json:
        return
    args.json.parent.mkdir(parents=True, exist_ok=True)
    meta = {"argv": sys.argv[1:], **vars(args), **git_state(), "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
    meta = {k: (str(v) if isinstance(v, Path) else v) for k, v in meta.items()}
    args.json.write_text(json.dumps({"meta": meta, "summary": summarise(results), "results": results}, indent=1) + "\n")


if __name__ == "__main__":
    main()
