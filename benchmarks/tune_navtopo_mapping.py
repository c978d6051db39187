"""NavTopo's mapping on generated scenes, replayed from recorded drives: edge errors against the
truth, locations made in the route's second half (and how many of those at places already
visited), locations left unjoined though close in the open, the maintainer's counters, for candidate configs.

Each (scene, setting) mapping drive is simulated once (``_tuning.record_drive``, as
``runners.mapping`` drives it) and cached under ``--cache``; each candidate replays it through
``NavTopo.create(config).observe(obs)``. Scenes come from ``scenarios.generators`` with seeds apart
from the benchmark's (the tuning rule); a candidate is a name and a YAML mapping of NavTopo config
overrides.

    .venv/bin/python benchmarks/tune_navtopo_mapping.py --kind ring --length 140 --seeds 101 \\
        --settings precise,noisy --candidate 'no-refine={mapping: {edge_measurements: 1}}'

Any generated scene written by ``generate_scene.py`` (aliased, SLAM-like, ...), its own route:

    .venv/bin/python benchmarks/generate_scene.py aliased-wing --seed 131 -o /tmp/wing131.yaml
    .venv/bin/python benchmarks/tune_navtopo_mapping.py --scene /tmp/wing131.yaml --settings precise
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
from _tuning import Recording, git_state, replay_parser, scenes
from _tuning import candidates as candidates_of

from navkit import geometry as se2
from navtopo.graph_poses import relaxed_poses
from navtopo.system import NavTopo, NavTopoConfig
from runners.mapping import revisited_late, unjoined_locations
from runners.metrics import each_edge_error
from runners.systems import SystemContext


def merge(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for key, value in overrides.items():
        out[key] = merge(out[key], value) if isinstance(value, dict) and isinstance(out.get(key), dict) else value
    return out


def replay(scenario, rec: Recording, overrides: dict[str, Any]) -> dict[str, Any]:
    config = NavTopoConfig.model_validate(merge(NavTopoConfig().model_dump(), overrides))
    system = NavTopo.create(config, SystemContext(robot=scenario.spec.robot, sensor=scenario.spec.sensor))
    started = time.perf_counter()
    for k in range(len(rec)):
        system.observe(rec.observation(k))
    system.finish_mapping()
    seconds = time.perf_counter() - started
    stats = system.mapping_stats()
    true = {float(s): rec.true[k] for k, s in enumerate(rec.stamps)}
    steps = np.hypot(*np.diff(rec.true[:, :2], axis=0).T)
    travelled = dict(zip((float(s) for s in rec.stamps), np.r_[0.0, np.cumsum(steps)], strict=True))
    half = float(travelled[float(rec.stamps[-1])]) / 2.0
    edges = each_edge_error(stats["edges_stamped"], true)
    stamps = stats["vertex_stamps"]
    late = sum(1 for s in stamps if travelled[s] > half)
    worst = max(edges, default=(0.0, 0.0, 0.0, 0.0))
    # the locations' map-frame positions as a map-frame goal is converted with them
    origin = true[stamps[0]]
    placed = np.hypot(*(relaxed_poses(system.graph)[:, :2] - [se2.between(origin, true[s])[:2] for s in stamps]).T)
    return {
        "vertices": stats["vertices"],
        "edges": stats["edges"],
        "edge_m_median": round(float(np.median([e[0] for e in edges])), 4) if edges else None,
        "edge_m_max": round(worst[0], 4),
        "edge_deg_max": round(max((e[1] for e in edges), default=0.0), 3),
        "edges_over_0.3m_or_3deg": sum(1 for e in edges if e[0] > 0.3 or e[1] > 3.0),
        "worst_edge_at": [np.round(true[worst[2]][:2], 2).tolist(), np.round(true[worst[3]][:2], 2).tolist()] if edges else None,
        "map_pose_m_median": round(float(np.median(placed)), 3),
        "map_pose_m_p95": round(float(np.percentile(placed, 95)), 3),
        "map_pose_m_max": round(float(np.max(placed)), 3),
        "map_frame_hints": stats["map_frame_hints"],
        "second_half": late,
        "second_half_share": round(late / max(len(stamps), 1), 4),
        "second_half_revisited": revisited_late(stamps, true, travelled, half),
        "unjoined_neighbours": len(unjoined_locations(scenario, stamps, stats["edges_stamped"], true)),
        "counters": stats["counters"],
        "accepted_checks_over_0.3m": audit_checks(stats["edge_checks"], true),
        "seconds": round(seconds, 1),
    }


def audit_checks(checks: list[dict[str, Any]], true: dict[float, np.ndarray], bad: float = 0.3, right: float = 0.15) -> list:
    """The edges accepted off the truth by more than ``bad`` (m) as measured when checked, each
    against the graph's way it was checked on: the way's own error, the two's discrepancy, its
    squared Mahalanobis distance and its offset from the lidar hints; and how many edges accepted
    within ``right`` of the truth stand at least as far on each of those three (``right_as_far``):
    where every count is above 0, no gate on that statistic refuses the bad edge and keeps the right
    ones."""
    rows = []
    for check in checks:
        if check["verdict"] != "accepted":
            continue
        truth = se2.between(true[check["stamps"][0]], true[check["stamps"][1]])
        pose, composed = np.asarray(check["pose"]), np.asarray(check["composed"])
        rows.append(
            {
                "stamps": check["stamps"],
                "way": check["way"],
                "error": round(float(np.hypot(*(pose[:2] - truth[:2]))), 3),
                "way_error": round(float(np.hypot(*(composed[:2] - truth[:2]))), 3),
                "discrepancy": round(float(np.hypot(*(pose[:2] - composed[:2]))), 3),
                "distance": check["distance"],
                "hint_offset": check["hint_offset"],
            }
        )
    rights = [row for row in rows if row["error"] <= right]
    out = []
    for row in sorted((row for row in rows if row["error"] > bad), key=lambda row: -row["error"]):
        row["right_as_far"] = {
            key: sum(1 for other in rights if other[key] is not None and row[key] is not None and other[key] >= row[key])
            for key in ("discrepancy", "distance", "hint_offset")
        }
        row["right_checked"] = len(rights)
        out.append(row)
    return out


def main() -> None:
    args = replay_parser(__doc__, kind="ring", length=140.0, seeds="101", settings="precise,noisy").parse_args()
    candidates = candidates_of(args.candidate)
    rows = []
    for setting, scenario, rec, key in scenes(args):
        for name, overrides in candidates.items():
            row = {"scene": key, "setting": setting, "candidate": name, **replay(scenario, rec, overrides)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"code": git_state(), "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
