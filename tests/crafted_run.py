"""A results folder written by hand, with figures chosen so that a report's numbers can be checked
against values computed on paper (tests/test_reports.py, tests/test_report_html.py).

The folder follows the contract (docs/DESIGN.md, "Contracts: the command line and the results
folder"): two systems, ``navtopo`` (a graph map of two locations) and ``metric_grid`` (a 10 x 10
map_server grid), six trials each, a ground_truth/ folder and TUM trajectories.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import yaml

# navtopo: (success, reason, efficiency, first_plan_ms, planning samples)
NAVTOPO_TRIALS = [
    (True, "", 0.9, 4.0, [1.0, 2.0, 3.0]),
    (True, "", 0.8, 6.0, [4.0, 5.0]),
    (False, "timeout", None, 8.0, [6.0, 7.0, 8.0, 9.0]),
    (True, "", 0.7, 2.0, [10.0]),
    (True, "", 1.0, 10.0, [11.0, 12.0]),
    (True, "", 0.6, 12.0, [13.0, 14.0, 15.0, 16.0, 17.0, 18.0, 19.0, 20.0]),
]
METRIC_TRIALS = [
    (True, "", 0.95, 500.0, [100.0, 300.0]),
    (False, "collision", None, 500.0, [100.0, 300.0]),
    (True, "", 0.95, 500.0, [100.0, 300.0]),
    (False, "collision", None, 500.0, [100.0, 300.0]),
    (True, "", 0.95, 500.0, [100.0, 300.0]),
    (True, "", 0.95, 500.0, [100.0, 300.0]),
]
MEMORY = {
    "navtopo": {"map": 1_000_000, "localization": 500_000, "derived": 250_000, "model": 1_250_000, "total": 3_000_000},
    "metric_grid": {"map": 8_000_000, "localization": 1_000_000, "derived": 1_000_000, "model": 0, "total": 10_000_000},
}
DISK = {"navtopo": 800_000, "metric_grid": 2_000_000}
RSS = {"navtopo": (40_000_000, 400_000_000), "metric_grid": (20_000_000, 300_000_000)}
MS_PER_SCAN = {"navtopo": (25.0, 40.0), "metric_grid": (50.0, 90.0)}
MAP_FRAME = [0.5, 0.0, math.pi / 2]  # the mapping run's first pose in the scenario frame
# NavTopo's two locations: made at stamps 1.0 and 2.0, truly at these poses (scenario frame)
ANCHORS = [[1.0, 1.0, 0.5, math.pi / 2], [2.0, 3.0, 0.5, 0.0]]
HINTS = [[0.5, -0.5, 0.0], [0.5, -2.5, -math.pi / 2]]  # odometry poses (map frame): exactly the anchors (precise)


def _trial(system: str, index: int, spec: tuple, seed: int, planning_scale: float = 1.0) -> dict:
    success, reason, efficiency, first, samples = spec
    first, samples = first * planning_scale, [v * planning_scale for v in samples]
    shortest = 2.0 + index
    return {
        "system": system,
        "trial": index,
        "success": success,
        "reason": reason,
        "start": [0.5, 0.0, 0.0],
        "goal": [3.5, 0.5],
        "shortest_m": shortest,
        "travelled_m": shortest / efficiency if efficiency else shortest * 2,
        "efficiency": efficiency,
        "spl": efficiency if success else 0.0,
        "collisions": 1 if reason == "collision" else 0,
        "sim_time_s": 10.0,
        "compute_s": 1.0,
        "planning_ms": {"median": float(np.median(samples)), "count": len(samples)},
        "planning_ms_samples": samples,
        "first_plan_ms": first,
        "tracking_error_m": None,
        "memory": None,
        "final_distance_m": 0.2,
        "seed": seed,
    }


def write_crafted_run(
    root: Path,
    seed: int = 7,
    memory_scale: float = 1.0,
    scenario: str = "crafted",
    planning_scale: float = 1.0,
    corridor_length_m: float = 4.0,
    setting: str = "precise",
) -> Path:
    """Write the crafted folder at ``root``; returns it. ``memory_scale`` multiplies every memory
    figure, ``planning_scale`` every planning time."""
    root.mkdir(parents=True, exist_ok=True)
    systems = ["navtopo", "metric_grid"]
    dump = lambda path, data: (path.parent.mkdir(parents=True, exist_ok=True), path.write_text(json.dumps(data, indent=1)))  # noqa: E731
    dump(
        root / "manifest.json",
        {
            "scenario": {
                "name": scenario,
                "file": f"scenarios/bundled/{scenario}.yaml",
                "bounds_m": [-1.0, -2.0, 5.0, 2.0],
                "corridor_length_m": corridor_length_m,
            },
            "systems": systems,
            "seed": seed,
            "setting": setting,
            "setting_override": setting,
            "odometry_noise": None,
            "range_noise": 0.0,
            "protocol": {"initial_pose_error_xy": 0.5, "initial_pose_error_yaw_deg": 10.0, "stop_tolerance": 0.35},
            "trial_count": 6,
            "config": {"navtopo": {"grid": {"resolution": 0.1, "radius": 2.0}}, "metric_grid": {"resolution": 0.1}},
            "versions": {"python": "3.11.0", "numpy": "1.26.0"},
            "git_revision": "0123456789abcdef",
            "machine": {"cpu": "crafted", "cores": 2},
            "created": "2026-01-01T00:00:00+00:00",
        },
    )
    records = [_trial("navtopo", i, t, seed, planning_scale) for i, t in enumerate(NAVTOPO_TRIALS)]
    records += [_trial("metric_grid", i, t, seed, planning_scale) for i, t in enumerate(METRIC_TRIALS)]
    duplicate = dict(records[0], success=False, reason="written twice: the first record counts")
    lines = [json.dumps(r) for r in records] + [json.dumps(duplicate)]
    (root / "trials.jsonl").write_text("\n".join(lines) + "\n" + '{"system": "navtopo", "tri')  # torn last line
    summary = {}
    for system, trials in (("navtopo", NAVTOPO_TRIALS), ("metric_grid", METRIC_TRIALS)):
        memory = {k: int(v * memory_scale) for k, v in MEMORY[system].items()}
        summary[system] = {
            "trials": len(trials),
            "successes": sum(t[0] for t in trials),
            "success_rate": sum(t[0] for t in trials) / len(trials),
            "planning_ms": {"median": 0.0},
            "first_plan_ms": {"median": 0.0},
            "map_load_ms": 12.0,
            "memory": {
                **memory,
                "map_bytes": memory["map"],
                "disk_bytes": int(DISK[system] * memory_scale),
                "rss_bytes": int(RSS[system][0] * memory_scale),
                "rss_process_bytes": int(RSS[system][1] * memory_scale),
            },
            "mapping_ms_per_scan": {"median": MS_PER_SCAN[system][0], "p95": MS_PER_SCAN[system][1]},
        }
        dump(
            root / "mapping" / f"{system}.json",
            {
                "scans": 100,
                "route_length_m": 8.0,
                "ms_per_scan": {"median": MS_PER_SCAN[system][0], "p95": MS_PER_SCAN[system][1]},
                "map_bytes": memory["map"],
                "growth": [[0.0, 0], [4.0, memory["map"] // 2], [8.0, memory["map"]]],
                "memory": memory,
                **({"anchors": ANCHORS, "vertices": 2, "edges": 1} if system == "navtopo" else {}),
                **(
                    {"keyframes": 11, "raw_cloud_bytes": 2_400_000, "rtabmap_style_bytes": 2_650_000}
                    if system == "metric_grid"
                    else {}
                ),
            },
        )
        dump(root / "navigation" / f"{system}.json", {"map_load_ms": 12.0, "memory": memory})
        for i in range(len(trials)):
            path = root / "trajectories" / system / f"trial-{i}.tum"
            path.parent.mkdir(parents=True, exist_ok=True)
            xs = np.linspace(0.5, 3.5, 7)
            path.write_text("".join(f"{0.2 * k:.3f} {x:.4f} {0.1 * i:.4f} 0 0 0 0 1\n" for k, x in enumerate(xs)))
    dump(root / "summary.json", summary)
    _write_ground_truth(root / "ground_truth")
    _write_graph(root / "maps" / "navtopo")
    _write_grid(root / "maps" / "metric_grid")
    return root


def _write_ground_truth(folder: Path) -> None:
    """A 4 m x 6 m raster of 0.1 m at origin (-1, -2): free for |y| < 1, x in [0, 4], walls elsewhere."""
    folder.mkdir(parents=True, exist_ok=True)
    image = np.zeros((40, 60), dtype=np.uint8)
    ys = -2.0 + (39 - np.arange(40) + 0.5) * 0.1  # image row -> cell-centre y
    xs = -1.0 + (np.arange(60) + 0.5) * 0.1
    image[np.ix_(np.abs(ys) < 1.0, (xs > 0.0) & (xs < 4.0))] = 255
    image[18:22, 40:42] = 64  # an obstacle
    cv2.imwrite(str(folder / "raster.png"), image)
    (folder / "raster.yaml").write_text(
        yaml.safe_dump(
            {
                "format": "navtopo-ground-truth/1",
                "image": "raster.png",
                "resolution": 0.1,
                "origin": [-1.0, -2.0, 0.0],
                "map_frame": MAP_FRAME,
                "values": {"free": 255, "change": 160, "obstacle": 64, "wall": 0},
                "robot_radius": 0.3,
            }
        )
    )
    trials = [
        {
            "trial": i,
            "start": [0.5, 0.0, 0.0],
            "goal": [3.5, 0.5],
            "shortest_m": 2.0 + i,
            "shortest_path": [[0.5, 0.0], [3.5, 0.5]],
        }
        for i in range(6)
    ]
    (folder / "trials.json").write_text(json.dumps({"format": "navtopo-ground-truth/1", "trials": trials}))
    (folder / "route.json").write_text(
        json.dumps({"start": [0.5, 0.0, 90.0], "length_m": 8.0, "polyline": [[0.5, 0.0], [3.5, 0.0]]})
    )


def _write_graph(folder: Path) -> None:
    """Two locations (grids of 40 x 40 cells of 0.1 m, radius 2 m), one occupied cell each.

    Location 0's saved grid is cropped at row0 = 20, col0 = 30 and holds its occupied cell at
    (0, 0): its centre is ((30 - 20 + 0.5) * 0.1, (20 - 20 + 0.5) * 0.1) = (1.05, 0.05) in the
    location's frame; at the anchor (1.0, 0.5, 90°) that is (1.0 - 0.05, 0.5 + 1.05) = (0.95, 1.55).
    Location 1's grid is uncropped with its cell at (row 10, col 20): (0.05, -0.95); at (3.0, 0.5, 0°)
    that is (3.05, -0.45)."""
    (folder / "grids").mkdir(parents=True, exist_ok=True)
    cells0 = np.array([[2, 1], [1, 0]], dtype=np.uint8)
    cells1 = np.zeros((40, 40), dtype=np.uint8)
    cells1[10, 20] = 2
    cv2.imwrite(str(folder / "grids" / "000000.png"), cells0)
    cv2.imwrite(str(folder / "grids" / "000001.png"), cells1)
    np.save(folder / "descriptors.npy", np.zeros((2, 4), dtype=np.float32))
    graph = {
        "format": "navtopo-graph/1",
        "descriptor_dim": 4,
        "vertices": [
            {
                "id": 0,
                "stamp": 1.0,
                "pose_hint": HINTS[0],
                "grid": {"file": "grids/000000.png", "row0": 20, "col0": 30, "size": 40},
            },
            {
                "id": 1,
                "stamp": 2.0,
                "pose_hint": HINTS[1],
                "grid": {"file": "grids/000001.png", "row0": 0, "col0": 0, "size": 40},
            },
        ],
        "edges": [[0, 1, 0.0, -2.0, -math.pi / 2]],
        "navtopo_config": {"grid": {"resolution": 0.1, "radius": 2.0}},
    }
    (folder / "graph.json").write_text(json.dumps(graph))


def _write_grid(folder: Path) -> None:
    """A 10 x 10 map_server grid of 0.1 m, origin (-0.5, -0.5) in the map frame, free except one
    occupied cell at image row 0, col 9 (the top right): centre (0.45, 0.45) in the map frame, so
    (0.5 - 0.45, 0.0 + 0.45) = (0.05, 0.45) in the scenario frame (map frame at (0.5, 0, 90°))."""
    folder.mkdir(parents=True, exist_ok=True)
    image = np.full((10, 10), 254, dtype=np.uint8)
    image[0, 9] = 0
    cv2.imwrite(str(folder / "map.png"), image)
    (folder / "map.yaml").write_text(
        yaml.safe_dump(
            {
                "image": "map.png",
                "mode": "trinary",
                "resolution": 0.1,
                "origin": [-0.5, -0.5, 0.0],
                "negate": 0,
                "occupied_thresh": 0.65,
                "free_thresh": 0.196,
            }
        )
    )
