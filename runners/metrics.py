"""The measures of a run, each defined once (DESIGN.md, "Measurement definitions").

Reference path: the any-angle ground-truth shortest path from start to goal on the scenario's
0.05 m raster, free space eroded by the robot radius (``Trial.shortest_m``).

* success: the system declared ``reached`` while the robot's true position was within
  ``goal_tolerance`` of the goal, before the timeout, with no collision.
* travelled: length of the true 2D trajectory sampled at every simulation tick.
* efficiency: shortest / max(shortest, travelled) per successful trial; mean over successes.
* SPL: success × shortest / max(shortest, travelled); mean over all trials.
* planning time: wall clock of each planning call, in ms: every call (``planning_ms``), the first
  full start-to-goal plan of each trial (``first_plan_ms``), and loading the map with everything
  precomputed before the first plan (``map_load_ms``), each reported on its own.
* memory: one breakdown for every system (``navkit.types.MemoryBreakdown``: map, localization,
  derived, model, total; exact bytes), the saved map on disk (all, and per part), RSS growth of a
  fresh worker from before loading the map to after the first plan, and its whole RSS then.
* tracking error: distance between a system's own map-frame pose estimate and the truth, per tick.
Figures that are undefined (no successes, no planning calls) are ``None`` (JSON null), never NaN.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from navkit import geometry as se2
from navkit.types import MEMORY_PARTS, FailureStage
from reports.records import (
    DiskParts,
    EdgeError,
    MappingReport,
    NavigationReport,
    Stats,
    SummaryMemory,
    SystemSummary,
    TrialRecord,
)
from runners.results import disk_bytes
from scenarios.schema import GOAL_TOLERANCE_M

TIMEOUT_FACTOR = 3.0
TIMEOUT_EXTRA_S = 60.0
STUCK_WINDOW_S = 30.0
STUCK_DISTANCE_M = 0.1


def timeout_s(shortest_m: float, max_linear: float, mapped_m: float = 0.0) -> float:
    """Simulated seconds a trial may take: 3x the shortest path at full speed, plus 60 s. In a world
    changed since mapping, 3x the shortest path now plus the shortest path as mapped (``mapped_m``):
    a robot that trusts its map drives the way the map promised up to a shut door before it takes
    the way there is. (On a generated ring with two corridors shut, both systems chose the same one
    of two ways the map made 0.1 m apart, met the second shut stretch at its end, drove 175 m for
    a 48 m path and ran out of the 3x limit 0.2-1.7 m from the goal.)"""
    return TIMEOUT_FACTOR * (shortest_m + mapped_m) / max_linear + TIMEOUT_EXTRA_S


ENDINGS = ("reached", "failed", "timeout", "collision", "stuck")


def judge(ending: str, final_distance_m: float, goal_tolerance: float = GOAL_TOLERANCE_M, failure: str = "") -> tuple[bool, str]:
    """The STOP rule: (success, reason) of a trial that ended with ``ending`` (one of ``ENDINGS``).

    Only a system's own "reached" can succeed, and only with the robot's true position within
    ``goal_tolerance`` of the goal (else ``reached_wrong_place``); the runner never ends a trial
    because the robot happens to pass the goal. ``failure`` is a failed system's own reason.
    """
    if ending not in ENDINGS:
        raise ValueError(f"unknown trial ending {ending!r}")
    if ending == "reached":
        return (True, "") if final_distance_m <= goal_tolerance else (False, "reached_wrong_place")
    if ending == "failed":
        return False, failure or "failed"
    return False, ending


#: the stage of a system's own failure that gives none (a system of another author), by its reason;
#: and of the reasons the runner gives itself
REASON_STAGES: dict[str, FailureStage] = {
    "not_localized": FailureStage.STARTUP,
    "no_path": FailureStage.GLOBAL_PLAN,
    "stuck": FailureStage.FOLLOWER,
    "collision": FailureStage.FOLLOWER,
    "timeout": FailureStage.FOLLOWER,
    "reached_wrong_place": FailureStage.LOCALIZATION,
    "error": FailureStage.RUNNER,
    "crashed": FailureStage.RUNNER,
    "out_of_memory": FailureStage.RUNNER,
}


def failure_stage(ending: str, success: bool, reason: str, status_stage: str | None = None) -> str | None:
    """The stage a trial that ended with ``ending`` failed in (``navkit.types.FailureStage``; None
    for a success), the system's status saying ``status_stage`` at the end (docs/DESIGN.md, "Trial end").

    * ``reached`` away from the goal: ``localization`` (the system believed it was at the goal);
    * ``failed``: the stage the system gives, else the one its reason names (``REASON_STAGES``),
      else None (a reason the runner does not know, from a system that gives no stage);
    * collision, stuck, the simulated-time limit (the runner's endings): ``startup`` while the
      system had not localized yet, ``localization`` while it said it was lost, else ``follower``.
    """
    if ending not in ENDINGS:
        raise ValueError(f"unknown trial ending {ending!r}")
    if success:
        return None
    if ending == "reached":
        return FailureStage.LOCALIZATION.value
    if ending == "failed":
        return FailureStage(status_stage).value if status_stage else _reason_stage(reason)
    if status_stage in (FailureStage.STARTUP, FailureStage.LOCALIZATION):
        return FailureStage(status_stage).value
    return FailureStage.FOLLOWER.value


def _reason_stage(reason: str) -> str | None:
    stage = REASON_STAGES.get(reason)
    return None if stage is None else stage.value


def trajectory_length(trajectory: NDArray) -> float:
    """Length of a (T, >=3) array of (time, x, y, ...) rows."""
    xy = np.asarray(trajectory)[:, 1:3]
    return float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum()) if len(xy) > 1 else 0.0


def efficiency(shortest_m: float, travelled_m: float) -> float:
    return float(shortest_m / max(shortest_m, travelled_m)) if max(shortest_m, travelled_m) > 0 else 1.0


def stats_ms(values: list[float] | NDArray) -> Stats:
    """median, mean, p95, max, count of a list of durations (ms); None when empty."""
    v = np.asarray(values, dtype=np.float64)
    if v.size == 0:
        return Stats(median=None, mean=None, p95=None, max=None, count=0)
    return Stats(
        median=round(float(np.median(v)), 4),
        mean=round(float(v.mean()), 4),
        p95=round(float(np.percentile(v, 95)), 4),
        max=round(float(v.max()), 4),
        count=int(v.size),
    )


def tracking_stats(errors: list[float] | None) -> dict[str, float] | None:
    """median, p95, max and final of a trial's tracking errors (m); None without an estimate."""
    if not errors:
        return None
    v = np.asarray(errors, dtype=np.float64)
    return {
        "median": round(float(np.median(v)), 4),
        "p95": round(float(np.percentile(v, 95)), 4),
        "max": round(float(v.max()), 4),
        "final": round(float(v[-1]), 4),
    }


def _mean_or_none(values: list[Any]) -> float | None:
    return round(float(np.mean(values)), 6) if values else None


def summarize(
    records: list[TrialRecord], mapping: dict[str, MappingReport], navigation: dict[str, NavigationReport] | None = None
) -> dict[str, SystemSummary]:
    """summary.json: keyed by system name only.

    records: trials.jsonl; mapping: ``mapping/<system>.json``; navigation: ``navigation/<system>.json``
    (the worker's load time, RSS and memory breakdown at the first plan, the saved map's disk bytes).
    Planning statistics are over every call of every trial; ``first_plan_ms`` over the trials'
    first plans. The memory parts are the largest each reached at any trial's end or at the first
    plan (caches grow while a system runs); the tracking error is the median over trials of each
    trial's median and p95, and the largest error seen.
    """
    navigation = navigation or {}
    systems = sorted({r.system for r in records} | set(mapping))
    out: dict[str, SystemSummary] = {}
    for name in systems:
        mine = [r for r in records if r.system == name]
        successes = [r for r in mine if r.success]
        nav = navigation.get(name) or NavigationReport()
        report = mapping.get(name) or MappingReport()
        out[name] = SystemSummary(
            trials=len(mine),
            successes=len(successes),
            success_rate=round(len(successes) / len(mine), 6) if mine else None,
            efficiency_mean=_mean_or_none([r.efficiency for r in successes]),
            efficiency_to_goal_mean=_mean_or_none([r.efficiency_to_goal for r in successes if r.efficiency_to_goal is not None]),
            efficiency_after_startup_mean=_mean_or_none(
                [r.efficiency_after_startup for r in successes if r.efficiency_after_startup is not None]
            ),
            efficiency_mapped_world_mean=_mean_or_none(
                [r.efficiency_mapped_world for r in successes if r.efficiency_mapped_world is not None]
            ),
            spl_mean=_mean_or_none([r.spl for r in mine]),
            planning_ms=stats_ms([v for r in mine for v in r.planning_ms_samples]),
            first_plan_ms=stats_ms([r.first_plan_ms for r in mine if r.first_plan_ms is not None]),
            map_load_ms=nav.map_load_ms,
            memory=memory_summary(mine, report, nav),
            tracking_error_m=_tracking_summary([r.tracking_error_m for r in mine if r.tracking_error_m]),
            **_localization_summary(mine),
            mapping_ms_per_scan=report.ms_per_scan,
            failure_reasons=_count([r.reason for r in mine if not r.success]),
            failure_stages=_count([r.failure_stage for r in mine if not r.success and r.failure_stage]),
        )
    return out


def memory_summary(records: list[TrialRecord], mapping: MappingReport, navigation: NavigationReport) -> SummaryMemory:
    """One system's memory figures: the breakdown's parts (exact bytes), the saved map on disk (all
    and per part), RSS growth and the worker's whole RSS after the first plan."""
    breakdowns = [r.memory for r in records if r.memory is not None]
    if navigation.memory is not None:
        breakdowns.append(navigation.memory)
    parts: dict[str, int | None] = {part: None for part in (*MEMORY_PARTS, "total")}
    if breakdowns:
        parts = {part: max(int(getattr(b, part) or 0) for b in breakdowns) for part in (*MEMORY_PARTS, "total")}
    return SummaryMemory(
        map_bytes=mapping.map_bytes,
        disk_bytes=navigation.given("disk_bytes", mapping.map_disk_bytes),
        rss_bytes=navigation.rss_bytes,
        rss_process_bytes=navigation.rss_process_bytes,
        loaded_map_bytes=navigation.map_bytes,
        **parts,
        disk=navigation.given("disk", mapping.map_disk),
    )


def _localization_summary(records: list[TrialRecord]) -> dict[str, Any]:
    """Start-up localizations checked against the truth, and goal conversions (graph systems)."""
    out: dict[str, Any] = {}
    found = [r.startup_localization for r in records if r.startup_localization]
    if found or any(r.reason == "not_localized" for r in records):
        seconds = [f["seconds"] for f in found if f.get("seconds") is not None]
        metres = [f["metres"] for f in found if f.get("metres") is not None]
        out["startup_localization"] = {
            "right": sum(1 for f in found if f["right"]),
            "wrong": sum(1 for f in found if not f["right"]),
            "not_localized": sum(1 for r in records if r.reason == "not_localized"),
            "seconds": stats_ms(seconds).as_json() if seconds else None,
            "metres": stats_ms(metres).as_json() if metres else None,
            "from_given_pose": sum(1 for f in found if f.get("given_pose")),
            "error_m_median": round(float(np.median([f["error_m"] for f in found])), 4) if found else None,
        }
    errors = [r.goal_conversion_error_m for r in records if r.goal_conversion_error_m is not None]
    if errors:
        out["goal_conversion_error_m"] = {"median": round(float(np.median(errors)), 4), "max": round(float(max(errors)), 4)}
    return out


def _tracking_summary(per_trial: list[dict[str, Any]]) -> dict[str, float] | None:
    if not per_trial:
        return None
    return {
        "median": round(float(np.median([t["median"] for t in per_trial])), 4),
        "p95": round(float(np.median([t["p95"] for t in per_trial])), 4),
        "max": round(float(max(t["max"] for t in per_trial)), 4),
        "final_median": round(float(np.median([t["final"] for t in per_trial])), 4),
    }


def _count(values: list[str]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for v in values:
        counts[v] = counts.get(v, 0) + 1
    return counts


def each_edge_error(
    edges: list[tuple[float, float, list[float]]], true_pose_at: dict[float, NDArray]
) -> list[tuple[float, float, float, float]]:
    """(translation m, rotation deg, stamp_u, stamp_v) of each edge (stamp_u, stamp_v, T_uv) against
    the true relative pose of its observation points; edges without true poses are left out."""
    out = []
    for stamp_u, stamp_v, t_uv in edges:
        if stamp_u not in true_pose_at or stamp_v not in true_pose_at:
            continue
        truth = se2.between(true_pose_at[stamp_u], true_pose_at[stamp_v])
        error = se2.between(truth, np.asarray(t_uv, float))
        out.append((float(np.hypot(error[0], error[1])), float(np.degrees(abs(error[2]))), stamp_u, stamp_v))
    return out


def edge_errors(edges: list[tuple[float, float, list[float]]], true_pose_at: dict[float, NDArray]) -> EdgeError:
    """Each edge (stamp_u, stamp_v, T_uv) against the true relative pose of its observation points."""
    each = each_edge_error(edges, true_pose_at)
    translation, rotation = [e[0] for e in each], [e[1] for e in each]

    def two(v: list[float]) -> Stats:
        return Stats(median=round(float(np.median(v)), 4) if v else None, max=round(float(np.max(v)), 4) if v else None)

    return EdgeError(translation_m=two(translation), rotation_deg=two(rotation), count=len(translation))


def disk_report(entry: Any, map_dir: Path) -> tuple[int, DiskParts]:
    """Bytes of a saved map on disk: the whole folder, and per memory part where the system says
    which file is which (``disk_usage`` of the entry's class); files of no part (e.g. mapping
    state kept for later re-optimisation) count under ``other``."""
    total = disk_bytes(map_dir)
    usage = getattr(entry.cls, "disk_usage", None)
    parts = dict(usage(map_dir)) if usage is not None else {"map": total}
    disk = {part: int(parts.get(part, 0)) for part in MEMORY_PARTS}
    disk["other"] = total - sum(v for k, v in parts.items() if k in MEMORY_PARTS and k != "model")
    return total, DiskParts(**disk)


JOIN_RADIUS_M = 6.0  # locations this close, with a way between them, should be joined directly (or nearly)
JOIN_DETOUR = 2.0  # ... or joined by a path at most this many times their distance (+ 2 m)


def unjoined_neighbours(
    positions: NDArray,
    pairs: list[tuple[int, int]],
    clearances_at: Callable[[NDArray], NDArray],
    clearance: float,
    radius: float = JOIN_RADIUS_M,
    detour: float = JOIN_DETOUR,
) -> list[tuple[int, int]]:
    """Pairs of locations a graph leaves unjoined: true positions (N, 2) within ``radius`` of each
    other with a straight way between them that the robot fits through (``clearances_at`` of
    points along it at least ``clearance``), whose shortest path over the graph's edges ``pairs``
    (lengths between the true positions) is longer than ``detour`` times their distance plus 2 m,
    or missing. A navigation planned over such a graph goes the long way round, or nowhere when
    the long way is blocked."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import shortest_path

    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    count = len(positions)
    if count < 2:
        return []
    index = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    weights = np.hypot(*(positions[index[:, 0]] - positions[index[:, 1]]).T) + 1e-9
    graph = coo_matrix((weights, (index[:, 0], index[:, 1])), shape=(count, count)).tocsr()
    over_graph = shortest_path(graph, directed=False)
    out = []
    for i in range(count):
        for j in range(i + 1, count):
            distance = float(np.hypot(*(positions[i] - positions[j])))
            if distance > radius or over_graph[i, j] <= detour * distance + 2.0:
                continue
            steps = max(int(np.ceil(distance / 0.05)), 1)
            line = positions[i] + np.linspace(0.0, 1.0, steps + 1)[:, None] * (positions[j] - positions[i])
            if np.all(clearances_at(line) >= clearance):
                out.append((i, j))
    return out


def gap_keys(trial: Any) -> dict[str, Any]:
    """``narrowest_gap_m`` and ``narrow`` of a trial whose gap was measured (``scenarios.gaps``), else none."""
    gap = getattr(trial, "narrowest_gap_m", None)
    return {} if gap is None else {"narrowest_gap_m": round(float(gap), 4), "narrow": bool(getattr(trial, "narrow", False))}


def trial_record(
    system: str,
    index: int,
    trial: Any,
    seed: int,
    *,
    success: bool,
    reason: str,
    detail: str | None = None,
    failure_stage: str | None = None,
    travelled_m: float = 0.0,
    final_distance_m: float | None = None,
    collisions: int = 0,
    sim_time_s: float = 0.0,
    compute_s: float = 0.0,
    planning_ms: list[float] | None = None,
    first_plan_ms: float | None = None,
    tracking_error_m: list[float] | None = None,
    initial_pose_error: NDArray | None = None,
    memory: dict[str, int] | None = None,
    diagnostics: dict[str, Any] | None = None,
) -> TrialRecord:
    """One line of trials.jsonl (the contract's keys, plus planning samples and extras).

    tracking_error_m: the distance between the system's own pose estimate and the truth at every
    tick (systems with a map-frame estimate only); initial_pose_error: the protocol's error
    [dx, dy, dyaw] added to the initial pose the system was given (None: it was given none);
    detail: one line on a failure: the exception, the signal, the limit (``error``, ``crashed``,
    ``timeout``, ``out_of_memory``), or the system's own words on where it failed;
    failure_stage: the stage it failed in (``failure_stage``; None for a success; not given: the one
    its reason names, ``REASON_STAGES``); diagnostics: the
    keys a graph system's start-up localization and goal conversion add (``Anchors.judge``)."""
    eff = efficiency(trial.shortest_m, travelled_m) if success else None
    to_goal = None
    if success and final_distance_m is not None:
        # the capped figure hides a robot that stops up to goal_tolerance short; this one does not
        to_goal = efficiency(trial.shortest_m, travelled_m + final_distance_m)
    samples = list(planning_ms or [])
    return TrialRecord(
        system=system,
        trial=index,
        success=bool(success),
        reason=reason,
        detail=detail,
        failure_stage=None if success else (failure_stage or _reason_stage(reason)),
        start=[round(float(trial.start[0]), 4), round(float(trial.start[1]), 4), round(float(np.degrees(trial.start[2])), 3)],
        goal=[round(float(trial.goal[0]), 4), round(float(trial.goal[1]), 4)],
        shortest_m=round(trial.shortest_m, 4),
        **gap_keys(trial),
        travelled_m=round(travelled_m, 4),
        efficiency=round(eff, 6) if eff is not None else None,
        spl=round(eff, 6) if eff is not None else 0.0,
        efficiency_to_goal=round(to_goal, 6) if to_goal is not None else None,
        collisions=int(collisions),
        sim_time_s=round(sim_time_s, 3),
        compute_s=round(compute_s, 4),
        planning_ms=stats_ms(samples),
        planning_ms_samples=[round(v, 4) for v in samples],
        first_plan_ms=round(float(first_plan_ms), 4) if first_plan_ms is not None else None,
        tracking_error_m=tracking_stats(tracking_error_m),
        initial_pose_error=(
            None
            if initial_pose_error is None
            else [
                round(float(initial_pose_error[0]), 4),
                round(float(initial_pose_error[1]), 4),
                round(float(np.degrees(initial_pose_error[2])), 3),
            ]
        ),
        memory=memory,
        final_distance_m=round(final_distance_m, 4) if final_distance_m is not None else None,
        seed=seed,
        **(diagnostics or {}),
    )
