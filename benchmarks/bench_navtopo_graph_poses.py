"""Where NavTopo's locations lie in the map frame, against the truth: the odometry hints, and the
relaxation of the graph (``navtopo.graph_poses``) that map-frame goals are converted with, over the
hints it chose (``hint_chain``); where those are the lidar hints, also the lidar hints alone and the
relaxation over the odometry hints alone.

The runner records the true pose where each location was made (``mapping/navtopo.json``,
``anchors``, scenario frame); the map frame is the mapping run's first pose. A benchmark may read
ground truth; the system never does.

    .venv/bin/python benchmarks/bench_navtopo_graph_poses.py RUN_DIR [RUN_DIR ...]

``--lidar-drift 0,0.005,...`` sweeps the lidar hints' drift floor (``graph_poses.LIDAR_DRIFT_XY``)
instead: per floor, each run's worst location, and over the runs the mean of the medians and p95s,
the worst location and the share of locations over 0.25 m (a goal converted that far off may end
0.5 m from the goal by the stop tolerance of 0.25 m).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from navkit import geometry as se2
from navtopo import graph_poses
from navtopo.graph import TopologicalGraph
from navtopo.graph_poses import hint_chain, relaxed_poses


def errors(estimate: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    translation = np.hypot(*(estimate[:, :2] - truth[:, :2]).T)
    rotation = np.degrees(np.abs(se2.wrap_angle(estimate[:, 2] - truth[:, 2])))
    return {
        "translation_m_median": round(float(np.median(translation)), 4),
        "translation_m_p95": round(float(np.percentile(translation, 95)), 4),
        "translation_m_max": round(float(translation.max()), 4),
        "rotation_deg_max": round(float(rotation.max()), 3),
    }


def load(run: Path) -> tuple[TopologicalGraph, np.ndarray]:
    """A run's saved NavTopo map and the true poses of its locations in the map frame."""
    mapping = json.loads((run / "mapping" / "navtopo.json").read_text())
    graph, _ = TopologicalGraph.load(run / "maps" / "navtopo")
    anchors = {round(row[0], 6): np.array(row[1:4]) for row in mapping["anchors"]}
    origin = np.array(anchors[round(graph.vertices[0].stamp, 6)])
    return graph, np.array([se2.between(origin, anchors[round(v.stamp, 6)]) for v in graph.vertices])


def sweep_lidar_drift(runs: list[Path], floors: list[float]) -> None:
    maps = [(run.name, *load(run)) for run in runs]
    for floor in floors:
        graph_poses.LIDAR_DRIFT_XY = floor
        rows = []
        for _, graph, truth in maps:
            translation = np.hypot(*(relaxed_poses(graph)[:, :2] - truth[:, :2]).T)
            rows.append((np.median(translation), np.percentile(translation, 95), translation.max(), np.mean(translation > 0.25)))
        table = np.array(rows)
        worst = " ".join(f"{name} {row[2]:.2f}" for (name, *_), row in zip(maps, rows, strict=True))
        print(
            f"floor {floor:.4f}: median {table[:, 0].mean():.3f}  p95 {table[:, 1].mean():.3f}  worst {table[:, 2].max():.3f}"
            f"  over 0.25 m {100 * table[:, 3].mean():.1f} %  | worst by run: {worst}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dirs", type=Path, nargs="+")
    parser.add_argument("--lidar-drift", help="comma-separated floors (m/sqrt(m)) to sweep")
    args = parser.parse_args()
    if args.lidar_drift:
        sweep_lidar_drift(args.run_dirs, [float(f) for f in args.lidar_drift.split(",")])
        return
    for run in args.run_dirs:
        manifest = json.loads((run / "manifest.json").read_text())
        graph, truth = load(run)
        hints = np.array([v.pose_hint for v in graph.vertices])
        t0 = time.perf_counter()
        relaxed = relaxed_poses(graph)
        elapsed = (time.perf_counter() - t0) * 1e3
        chain, _ = hint_chain(graph)
        compared = {}
        if chain == "lidar":  # the same relaxation on the odometry hints alone, for comparison
            compared["lidar_hints"] = errors(np.array([v.lidar_hint for v in graph.vertices]), truth)
            for vertex in graph.vertices:
                vertex.lidar_hint = None
            compared["relaxed_without_lidar"] = errors(relaxed_poses(graph), truth)
        print(
            json.dumps(
                {
                    "run": str(run),
                    "setting": manifest.get("setting"),
                    "vertices": len(graph),
                    "edges": graph.edge_count,
                    "hints": errors(hints, truth),
                    "hint_chain": chain,
                    **compared,
                    "relaxed": errors(relaxed, truth),
                    "relaxation_ms": round(elapsed, 2),
                },
                indent=2,
            )
        )


if __name__ == "__main__":
    main()
