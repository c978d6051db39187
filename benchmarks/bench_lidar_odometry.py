"""The lidar odometry (``navkit.odometry``) alone on generated scenes, replayed from recorded
mapping drives, against the true poses: for candidate configs, the position error over the whole
drive and at each place's first visit (where NavTopo makes its locations, so what a map-frame goal
is converted with), the heading error, and the seconds the replay took.

The drives are the ones ``tune_navtopo_mapping.py`` and ``tune_metric_mapping.py`` record (one per
scene and setting, cached under ``--cache``); scenes come from ``scenarios.generators`` with seeds
apart from the benchmark's (the tuning rule). Both the estimate and the truth are taken relative to
the drive's first pose (the map frame). A "first visit" is the first scan more than 2 m from every
earlier one. A candidate is a name and a YAML mapping of ``OdometryConfig`` overrides.

    .venv/bin/python benchmarks/bench_lidar_odometry.py --kind tree --seeds 103,105 --settings noisy \\
        --candidate 'kiss-only={point_to_line: false, line_bootstrap: false}'
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
from _tuning import Recording, git_state, replay_parser, scenes
from _tuning import candidates as candidates_of

from navkit import geometry as se2
from navkit.odometry import LidarOdometry, OdometryConfig

FIRST_VISIT_M = 2.0


def first_visits(truth: np.ndarray) -> np.ndarray:
    """Indices of the scans more than FIRST_VISIT_M from every earlier scan (the first included)."""
    seen = np.zeros((0, 2))
    out = []
    for k, position in enumerate(truth[:, :2]):
        if not len(seen) or np.min(np.hypot(*(seen - position).T)) > FIRST_VISIT_M:
            out.append(k)
            seen = np.vstack([seen, position])
    return np.array(out, dtype=np.int64)


def replay(rec: Recording, overrides: dict[str, Any]) -> dict[str, Any]:
    odometry = LidarOdometry(OdometryConfig.model_validate({"source": "lidar", **overrides}))
    started = time.perf_counter()
    poses = []
    for k in range(len(rec)):
        observation = rec.observation(k)
        poses.append(odometry.update(observation.points, observation.odom))
    seconds = time.perf_counter() - started
    truth = np.array([se2.between(rec.true[0], pose) for pose in rec.true])
    estimate = np.array([se2.between(poses[0], pose) for pose in poses])
    error = np.hypot(*(estimate[:, :2] - truth[:, :2]).T)
    heading = np.degrees(se2.wrap_angle(estimate[:, 2] - truth[:, 2]))
    first = error[first_visits(truth)]

    def stats(values: np.ndarray) -> list[float]:
        return [round(float(np.median(values)), 3), round(float(np.percentile(values, 95)), 3), round(float(values.max()), 3)]

    return {
        "scans": len(rec),
        "error_m": stats(error),
        "first_visit_error_m": stats(first),
        "first_visits": len(first),
        "heading_deg_median": round(float(np.median(heading)), 3),
        "heading_deg_max_abs": round(float(np.abs(heading).max()), 3),
        "ms_per_scan": round(1000.0 * seconds / max(len(rec), 1), 2),
    }


def main() -> None:
    args = replay_parser(__doc__, kind="tree", length=150.0, seeds="101,102,103", settings="noisy").parse_args()
    candidates = candidates_of(args.candidate)
    rows = []
    print(
        "| scene | candidate | error median / p95 / max (m) | first visits median / p95 / max (m) "
        "| heading median / max abs (°) | ms a scan |"
    )
    print("|---|---|---|---|---|---|")
    for setting, _, rec, key in scenes(args):
        for name, overrides in candidates.items():
            row = {"scene": key, "setting": setting, "candidate": name, **replay(rec, overrides)}
            rows.append(row)
            print(
                f"| {key} | {name} | {' / '.join(map(str, row['error_m']))} | "
                f"{' / '.join(map(str, row['first_visit_error_m']))} | "
                f"{row['heading_deg_median']:+.2f} / {row['heading_deg_max_abs']:.2f} | {row['ms_per_scan']} |",
                flush=True,
            )
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"code": git_state(), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
