"""The measures of a run, each defined once (DESIGN.md, "Measurement definitions").

Reference path: the any-angle ground-truth shortest path from start to goal on the scenario's
0.05 m raster, free space eroded by the robot radius (``Trial.shortest_m``).

* success: the system declared ``reached`` while the robot's true position was within
  ``goal_tolerance`` of the goal, before the timeout, with no collision.
* travelled: length of the true 2D trajectory sampled at every simulation tick.
* efficiency: shortest / max(shortest, travelled) per successful trial; mean over successes.
* SPL: success × shortest / max(shortest, travelled); mean over all trials.
* planning time: wall clock of each planning call, in ms.
Figures that are undefined (no successes, no planning calls) are ``None`` (JSON null), never NaN.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from navtopo import geometry as se2

GOAL_TOLERANCE_M = 0.5
TIMEOUT_FACTOR = 3.0
TIMEOUT_EXTRA_S = 60.0
STUCK_WINDOW_S = 30.0
STUCK_DISTANCE_M = 0.1


def timeout_s(shortest_m: float, max_linear: float) -> float:
    return TIMEOUT_FACTOR * shortest_m / max_linear + TIMEOUT_EXTRA_S


def trajectory_length(trajectory: NDArray) -> float:
    """Length of a (T, >=3) array of (time, x, y, ...) rows."""
    xy = np.asarray(trajectory)[:, 1:3]
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0


def efficiency(shortest_m: float, travelled_m: float) -> float:
    return float(shortest_m / max(shortest_m, travelled_m)) if max(shortest_m, travelled_m) > 0 else 1.0


def stats_ms(values: list[float] | NDArray) -> dict[str, float | int | None]:
    """median, mean, p95, max, count of a list of durations (ms); None when empty."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return {"median": None, "mean": None, "p95": None, "max": None, "count": 0}
    return {
        "median": round(float(np.median(v)), 4),
        "mean": round(float(v.mean()), 4),
        "p95": round(float(np.percentile(v, 95)), 4),
        "max": round(float(v.max()), 4),
        "count": int(v.size),
    }


def _mean_or_none(values: list[float]) -> float | None:
    return round(float(np.mean(values)), 6) if values else None


def summarize(
    records: list[dict[str, Any]], planning_ms: dict[str, list[float]], memory: dict[str, dict], mapping: dict[str, dict]
) -> dict[str, Any]:
    """summary.json: keyed by system name only."""
    systems = sorted({r["system"] for r in records} | set(mapping))
    out: dict[str, Any] = {}
    for name in systems:
        mine = [r for r in records if r["system"] == name]
        successes = [r for r in mine if r["success"]]
        out[name] = {
            "trials": len(mine),
            "successes": len(successes),
            "success_rate": round(len(successes) / len(mine), 6) if mine else None,
            "efficiency_mean": _mean_or_none([r["efficiency"] for r in successes]),
            "spl_mean": _mean_or_none([r["spl"] for r in mine]),
            "planning_ms": stats_ms(planning_ms.get(name, [])),
            "memory": memory.get(name, {"map_bytes": None, "disk_bytes": None, "rss_bytes": None}),
            "mapping_ms_per_scan": (mapping.get(name) or {}).get("ms_per_scan"),
            "failure_reasons": _count([r["reason"] for r in mine if not r["success"]]),
        }
    return out


def _count(values: list[str]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for v in values:
        counts[v] = counts.get(v, 0) + 1
    return counts


def edge_errors(edges: list[tuple[float, float, list[float]]], true_pose_at: dict[float, NDArray]) -> dict[str, Any]:
    """Each edge (stamp_u, stamp_v, T_uv) against the true relative pose of its observation points."""
    translation, rotation = [], []
    for stamp_u, stamp_v, t_uv in edges:
        if stamp_u not in true_pose_at or stamp_v not in true_pose_at:
            continue
        truth = se2.between(true_pose_at[stamp_u], true_pose_at[stamp_v])
        error = se2.between(truth, np.asarray(t_uv, float))
        translation.append(float(np.hypot(error[0], error[1])))
        rotation.append(float(np.degrees(abs(error[2]))))

    def two(v: list[float]) -> dict[str, float | None]:
        return {"median": round(float(np.median(v)), 4) if v else None, "max": round(float(np.max(v)), 4) if v else None}

    return {"translation_m": two(translation), "rotation_deg": two(rotation), "count": len(translation)}


def trial_record(
    system: str,
    index: int,
    trial: Any,
    seed: int,
    *,
    success: bool,
    reason: str,
    travelled_m: float = 0.0,
    final_distance_m: float | None = None,
    collisions: int = 0,
    sim_time_s: float = 0.0,
    compute_s: float = 0.0,
    planning_ms: list[float] | None = None,
) -> dict[str, Any]:
    """One line of trials.jsonl (the contract's keys, plus planning samples and extras)."""
    eff = efficiency(trial.shortest_m, travelled_m) if success else None
    to_goal = None
    if success and final_distance_m is not None:
        # the capped figure hides a robot that stops up to goal_tolerance short; this one does not
        to_goal = efficiency(trial.shortest_m, travelled_m + final_distance_m)
    samples = list(planning_ms or [])
    return {
        "system": system,
        "trial": index,
        "success": bool(success),
        "reason": reason,
        "start": [round(float(trial.start[0]), 4), round(float(trial.start[1]), 4), round(float(np.degrees(trial.start[2])), 3)],
        "goal": [round(float(trial.goal[0]), 4), round(float(trial.goal[1]), 4)],
        "shortest_m": round(trial.shortest_m, 4),
        "travelled_m": round(travelled_m, 4),
        "efficiency": round(eff, 6) if eff is not None else None,
        "spl": round(eff, 6) if eff is not None else 0.0,
        "efficiency_to_goal": round(to_goal, 6) if to_goal is not None else None,
        "collisions": int(collisions),
        "sim_time_s": round(sim_time_s, 3),
        "compute_s": round(compute_s, 4),
        "planning_ms": stats_ms(samples),
        "planning_ms_samples": [round(v, 4) for v in samples],
        "final_distance_m": round(final_distance_m, 4) if final_distance_m is not None else None,
        "seed": seed,
    }
