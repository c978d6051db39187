"""Stage 2: in a fresh worker process, load one system's saved map and run trials in order.

Per trial: the robot is placed at the start (scenario frame); the system gets the goal in the
map frame (and, if its entry asks, the initial pose); the loop observes, asks the system for a
command and moves the robot until the system declares reached or failed, the robot collides,
gets stuck or times out. Any exception inside a trial is recorded with its reason and the next
trial runs. The worker appends each finished record to ``trials.jsonl`` itself (so an interrupted
run loses no finished trial) when it shares the run folder, and returns the records either way.
"""

from __future__ import annotations

import gc
import json
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from navtopo import geometry as se2
from runners.mapping import context_for
from runners.metrics import GOAL_TOLERANCE_M, STUCK_DISTANCE_M, STUCK_WINDOW_S, timeout_s, trajectory_length, trial_record
from runners.results import RunDir, disk_bytes, write_json, write_tum
from runners.sim import TRIAL_STREAM, Simulator
from runners.systems import Status, get_system
from scenarios import Scenario, load_scenario


@dataclass
class TrialJob:
    scenario: str  # path of the scenario file
    system: str
    config: dict[str, Any]
    map_dir: str
    trials: list[int]
    seed: int
    run_dir: str | None = None  # write records and trajectories there as trials finish
    measure_memory: bool = True
    extra: dict[str, Any] = field(default_factory=dict)


def _rss() -> int:
    return int(psutil.Process().memory_info().rss)


def run_trial_job(job: TrialJob) -> dict[str, Any]:
    """Entry point of a worker process (picklable arguments, JSON-able result)."""
    scenario = load_scenario(job.scenario)
    entry = get_system(job.system)
    config = entry.config_model.model_validate(job.config)
    sim = Simulator(scenario, seed=job.seed)
    run = RunDir(Path(job.run_dir)) if job.run_dir else None
    records: list[dict[str, Any]] = []
    memory: dict[str, Any] = {}
    try:
        warm_up = getattr(entry.cls, "warm_up", None)
        if warm_up is not None:
            warm_up()  # compiled kernels load (or compile) here, not inside the first plan
        gc.collect()
        rss_before = _rss()
        context = context_for(entry, scenario, sim)
        system = entry.load(Path(job.map_dir), config, context)
        first_plan_rss: list[int] = []
        for index in job.trials:
            trial = scenario.trials[index]
            record, rows, estimate = run_one_trial(scenario, sim, entry, system, trial, index, job.seed, first_plan_rss)
            records.append(record)
            if run is not None:
                write_tum(run.trajectory_path(job.system, index), rows)
                if estimate is not None and len(estimate):
                    write_tum(run.trajectory_path(job.system, index, estimate=True), estimate)
                run.append_trial(record)
        stats = system.stats()
        memory = {
            "map_bytes": int(stats.get("map_bytes", 0)),
            "rss_bytes": (first_plan_rss[0] - rss_before) if first_plan_rss else None,
            "rss_before_load": rss_before,
        }
        if run is not None and job.measure_memory:
            write_json(
                run.root / "navigation" / f"{job.system}.json",
                {**memory, "disk_bytes": disk_bytes(Path(job.map_dir))},
            )
    finally:
        sim.close()
    return {"system": job.system, "records": records, "memory": memory}


def run_one_trial(scenario: Scenario, sim: Simulator, entry, system, trial, index: int, seed: int, first_plan_rss: list[int]):
    robot = scenario.spec.robot
    world_from_map = scenario.route_start
    sim.reset(trial.start, stream=(TRIAL_STREAM, index))
    limit = timeout_s(trial.shortest_m, robot.max_linear)
    reason = ""
    success = False
    planning_ms: list[float] = []
    estimate_rows: list[tuple[float, float, float, float]] = []
    compute_s = 0.0
    try:
        if entry.wants_initial_pose:
            system.set_initial_pose(se2.between(world_from_map, trial.start))
        goal_map = se2.transform_points(se2.inverse(world_from_map), trial.goal[None, :])[0]
        t0 = time.perf_counter()
        system.set_goal(goal_map)
        compute_s += time.perf_counter() - t0
        last_progress_time, last_progress_pose = sim.time, sim.true_pose
        while True:
            obs = sim.observe()
            t0 = time.perf_counter()
            command = system.step(obs)
            compute_s += time.perf_counter() - t0
            if not first_plan_rss and system.stats().get("planning_ms"):  # checked only until the first plan
                first_plan_rss.append(_rss())
            estimate = getattr(system, "pose_estimate", lambda: None)()
            if estimate is not None:
                estimate_rows.append((obs.stamp, *np.asarray(estimate, float)))
            status = system.status
            if status.state == Status.REACHED:
                distance = float(np.hypot(*(sim.true_pose[:2] - trial.goal)))
                success = distance <= GOAL_TOLERANCE_M
                reason = "" if success else "reached_wrong_place"
                break
            if status.state == Status.FAILED:
                reason = status.reason or "failed"
                break
            if sim.time >= limit:
                reason = "timeout"
                break
            result = sim.step(command)
            if result.collided:
                reason = "collision"
                break
            if se2.distance(sim.true_pose, last_progress_pose) > STUCK_DISTANCE_M:
                last_progress_time, last_progress_pose = sim.time, sim.true_pose
            elif sim.time - last_progress_time > STUCK_WINDOW_S:
                reason = "stuck"
                break
        planning_ms = list(system.stats().get("planning_ms", []))
    except Exception as exc:  # a trial that raises is recorded and the run goes on
        reason = f"error: {type(exc).__name__}: {exc}".splitlines()[0][:300]
        traceback.print_exc()
    rows = sim.trajectory_array()
    record = trial_record(
        entry.name,
        index,
        trial,
        seed,
        success=success,
        reason=reason,
        travelled_m=trajectory_length(rows),
        final_distance_m=float(np.hypot(*(sim.true_pose[:2] - trial.goal))),
        collisions=sim.collisions,
        sim_time_s=sim.time,
        compute_s=compute_s,
        planning_ms=planning_ms,
    )
    json.dumps(record, allow_nan=False)  # fail here, not in the writer, if a NaN slipped in
    return record, rows, np.asarray(estimate_rows) if estimate_rows else None
