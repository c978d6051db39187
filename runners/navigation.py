"""Stage 2: in a fresh worker process, load one system's saved map and run trials in order.

Per trial: the robot is placed at the start (scenario frame); the system forgets the previous
trial (``reset``), gets the goal in the map frame (and, if its entry asks, the initial pose with
the protocol's seeded error, ``runners.protocol``); the loop observes, asks the system for a
command and moves the robot until the system declares reached or failed, the robot collides,
gets stuck or times out. The worker times the map's loading (``map_load_ms``), measures RSS and
the system's memory breakdown right after its first plan, and the tracking error of the system's
own pose estimate (where it has one) against the truth at every tick. An exception inside a
trial is recorded (reason ``error``, or ``out_of_memory`` for a ``MemoryError`` under
``--trial-memory-mb``) with a one-line ``detail``, and the next trial runs.

A job (``TrialJob``) carries the scenario's files and the saved map as bytes (``runners.payload``),
never a path: the worker unpacks them into a temporary folder of its own and yields, per trial, a
``started`` message (with the trial's wall-clock limit as ``deadline_s``) and a ``trial`` message
with the record and the trajectories; the driver writes them (``runners.run``).
"""

from __future__ import annotations

import gc
import importlib
import json
import resource
import tempfile
import time
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import psutil
from numpy.typing import NDArray

from navkit import geometry as se2
from navkit import grid_search
from runners.mapping import context_for, disk_report
from runners.metrics import STUCK_DISTANCE_M, STUCK_WINDOW_S, judge, timeout_s, trajectory_length, trial_record
from runners.payload import ScenarioFiles, pack_dir, unpack_dir
from runners.protocol import TrialProtocol, apply_setting
from runners.results import MAP_FRAME_FILE, RunDir, write_json, write_map_frame, write_tum
from runners.sim import TRIAL_STREAM, Simulator
from runners.systems import Status, get_system
from scenarios import Scenario, load_scenario


class MapLoadError(RuntimeError):
    """A saved map its system cannot load (truncated, edited, another format): the navigation stage
    failed before any trial, which is not a navigation failure of the system."""


@dataclass
class TrialJob:
    scenario: ScenarioFiles
    system: str
    config: dict[str, Any]
    map_archive: bytes  # the saved map folder (runners.payload.pack_dir)
    trials: list[int]
    seed: int
    measure_memory: bool = True
    setting: str | None = None  # runners.protocol.SETTINGS name; None: the scenario file's own
    protocol: dict[str, Any] = field(default_factory=lambda: TrialProtocol().as_json())
    anchors: list[list[float]] | None = None  # [[stamp, x, y, yaw], ...]: where the system's locations were made (truth)
    trial_wall_s: float | None = None  # wall-clock limit of one trial (the executor kills the worker past it)
    trial_memory_mb: float | None = None  # address space a trial may add (RLIMIT_AS), None: no limit
    modules: list[str] = field(default_factory=list)  # to import first: systems registered outside the runner
    extra: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def packed(cls, scenario: Scenario | str | Path, map_dir: str | Path, **fields: Any) -> TrialJob:
        """A job of a scenario (or its file) and a map folder on this machine, packed."""
        loaded = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        return cls(scenario=ScenarioFiles.of(loaded), map_archive=pack_dir(Path(map_dir)), **fields)


def import_modules(modules: list[str]) -> None:
    """Import the modules that register the job's systems (those outside ``runners.systems``)."""
    for module in modules:
        importlib.import_module(module)


def limit_address_space(extra_mb: float | None) -> None:
    """Let this process grow its address space by at most ``extra_mb`` from now (RLIMIT_AS, soft
    limit, as Bench-MR limits its planners): past it allocations fail with ``MemoryError``."""
    if extra_mb is None:
        return
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = int(psutil.Process().memory_info().vms + extra_mb * 2**20)
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))


@dataclass
class Anchors:
    """The true poses (scenario frame) where a graph system made its locations, by creation stamp:
    the runner turns the system's location-relative estimates into checkable ones with them."""

    poses: dict[float, NDArray[np.float64]]

    @classmethod
    def from_rows(cls, rows: list[list[float]] | None) -> Anchors | None:
        if not rows:
            return None
        return cls({round(float(r[0]), 6): np.asarray(r[1:4], dtype=np.float64) for r in rows})

    def locate(self, anchored: tuple[float, NDArray] | None) -> NDArray[np.float64] | None:
        """(anchor stamp, pose in the anchor) -> the pose in the scenario frame, or None."""
        if anchored is None:
            return None
        anchor = self.poses.get(round(float(anchored[0]), 6))
        return None if anchor is None else se2.compose(anchor, np.asarray(anchored[1], dtype=np.float64))

    def goal_form(self, goal: NDArray, world) -> tuple[float, NDArray[np.float64]]:
        """The goal (2,) in the paper's form: the creation stamp of the location nearest to it with a
        clear line of sight in the ground-truth free space (else the nearest), and the goal in that
        location's frame."""
        stamps = list(self.poses)
        poses = np.array([self.poses[s] for s in stamps])
        order = np.argsort(np.hypot(*(poses[:, :2] - goal).T))
        chosen = int(order[0])
        goal_cell = world.to_cell(goal)
        for k in order[:20]:
            cell = world.to_cell(poses[k, :2])
            if world.inside(cell) and world.inside(goal_cell) and grid_search.line_of_sight(world.free, cell, goal_cell):
                chosen = int(k)
                break
        return stamps[chosen], se2.transform_points(se2.inverse(poses[chosen]), np.asarray(goal, float)[None, :2])[0]

    def judge(self, stats: dict[str, Any], true_at: dict[float, NDArray], goal: NDArray, tolerance: float) -> dict[str, Any]:
        """The system's start-up localization and goal conversion against the truth (diagnostics)."""
        out: dict[str, Any] = {}
        localizations = stats.get("localizations") or []
        if localizations:
            first = localizations[0]
            estimate = self.locate((first["vertex_stamp"], np.asarray(first["pose"])))
            truth = true_at.get(first["stamp"])
            if estimate is not None and truth is not None:
                error = float(se2.distance(estimate, truth))
                yaw = float(np.degrees(abs(se2.wrap_angle(estimate[2] - truth[2]))))
                out["startup_localization"] = {
                    "seconds": first.get("seconds"),
                    "error_m": round(error, 4),
                    "yaw_error_deg": round(yaw, 3),
                    "right": bool(error <= tolerance and yaw <= 15.0),
                    "looks": first.get("looks"),
                    "hypotheses": first.get("hypotheses"),
                }
        goal_estimate = stats.get("goal")
        if goal_estimate:
            anchor = self.poses.get(round(float(goal_estimate["vertex_stamp"]), 6))
            if anchor is not None:
                point = se2.transform_points(anchor, np.asarray(goal_estimate["pose"], dtype=np.float64)[None, :2])[0]
                out["goal_conversion_error_m"] = round(float(np.hypot(*(point - goal))), 4)
        return out


def _rss() -> int:
    return int(psutil.Process().memory_info().rss)


@dataclass
class FirstPlan:
    """What the worker measures once, right after the system's first plan (DESIGN.md, memory)."""

    rss_bytes: int | None = None  # growth from before the map was loaded
    rss_process_bytes: int | None = None  # the whole worker
    memory: dict[str, int] | None = None  # the system's breakdown at that moment

    def seen(self) -> bool:
        return self.rss_process_bytes is not None


def _memory(system) -> dict[str, int] | None:
    memory = getattr(system, "memory", None)
    return memory().as_dict() if memory is not None else None


def run_trial_job(job: TrialJob) -> dict[str, Any]:
    """The job in this process, all at once: {"system", "records", "memory"} (tests, tools)."""
    records, memory = [], {}
    for message in trial_job(job):
        if message["kind"] == "map_load_error":
            raise MapLoadError(f"the saved map of {job.system} cannot be loaded: {message['detail']}")
        if message["kind"] == "trial":
            records.append(message["record"])
        elif message["kind"] == "memory":
            memory = message["report"]
    return {"system": job.system, "records": records, "memory": memory}


def trial_job(job: TrialJob) -> Iterator[dict[str, Any]]:
    """A navigation job in a worker process: yields ``started`` {trial, deadline_s}, ``trial``
    {record, trajectory (T, 4), estimate (T, 4) or None} per trial, then ``memory`` {report} (the
    fresh-process figures, if ``measure_memory``); or a single ``map_load_error`` {detail}."""
    import_modules(job.modules)
    with tempfile.TemporaryDirectory(prefix="navtopo-job-") as folder:
        scenario = apply_setting(job.scenario.load(Path(folder) / "scenario"), job.setting)
        map_dir = unpack_dir(job.map_archive, Path(folder) / "map")
        protocol = TrialProtocol.from_json(job.protocol)
        entry = get_system(job.system)
        config = entry.config_model.model_validate(job.config)
        sim = Simulator(scenario, seed=job.seed, with_changes=True)  # the navigation stage: world.changes stand
        try:
            warm_up = getattr(entry.cls, "warm_up", None)
            if warm_up is not None:
                warm_up()  # compiled kernels load (or compile) here, not inside the first plan
            gc.collect()
            rss_before = _rss()
            context = context_for(entry, scenario, sim, protocol)
            anchors = Anchors.from_rows(job.anchors)
            t0 = time.perf_counter()
            try:
                system = entry.load(map_dir, config, context)
            except Exception as exc:  # noqa: BLE001 - whatever the format's reader raises
                # the job's copy of the map is a temporary folder, gone when the user reads this:
                # name it as the run folder does
                message = f"{type(exc).__name__}: {exc}".replace(str(map_dir), f"maps/{job.system}").splitlines()[0][:300]
                yield {"kind": "map_load_error", "detail": message}
                return
            map_load_ms = (time.perf_counter() - t0) * 1e3
            limit_address_space(job.trial_memory_mb)
            first = FirstPlan()
            for index in job.trials:
                yield {"kind": "started", "trial": index, "deadline_s": job.trial_wall_s}
                trial = scenario.trials[index]
                record, rows, estimate = run_one_trial(
                    scenario, sim, entry, system, trial, index, job.seed, protocol, first, rss_before, anchors
                )
                yield {"kind": "trial", "record": record, "trajectory": rows, "estimate": estimate}
            if job.measure_memory:
                stats = system.stats()
                memory = {
                    "map_bytes": int(stats.get("map_bytes", 0)),
                    "map_load_ms": round(map_load_ms, 3),
                    "rss_bytes": first.rss_bytes,
                    "rss_process_bytes": first.rss_process_bytes,
                    "rss_before_load": rss_before,
                    "memory": first.memory,
                }
                yield {"kind": "memory", "report": {**memory, **disk_report(entry, map_dir)}}
        finally:
            sim.close()


def write_trial(run: RunDir, scenario: Scenario, message: dict[str, Any]) -> None:
    """The driver's side of a ``trial`` message: trajectories first, then the record (its line in
    trials.jsonl is what marks the trial done)."""
    record = message["record"]
    write_tum(run.trajectory_path(record["system"], record["trial"]), message["trajectory"])
    estimate = message.get("estimate")
    if estimate is not None and len(estimate):
        estimate_path = run.trajectory_path(record["system"], record["trial"], estimate=True)
        write_tum(estimate_path, estimate)
        write_map_frame(estimate_path.with_name(MAP_FRAME_FILE), scenario.route_start)
    run.append_trial(record)


def write_navigation_report(run: RunDir, system: str, report: dict[str, Any]) -> None:
    write_json(run.root / "navigation" / f"{system}.json", report)


def run_one_trial(
    scenario: Scenario,
    sim: Simulator,
    entry,
    system,
    trial,
    index: int,
    seed: int,
    protocol: TrialProtocol | None = None,
    first: FirstPlan | None = None,
    rss_before: int = 0,
    anchors: Anchors | None = None,
):
    """One trial in this worker: (record, true trajectory rows, estimate rows or None)."""
    protocol = protocol or TrialProtocol()
    first = first or FirstPlan()
    robot = scenario.spec.robot
    world_from_map = scenario.route_start
    sim.reset(trial.start, stream=(TRIAL_STREAM, index))
    limit = timeout_s(trial.shortest_m, robot.max_linear)
    reason, detail = "", None
    success = False
    planning_ms: list[float] = []
    first_plan_ms: float | None = None
    estimate_rows: list[tuple[float, float, float, float]] = []
    tracking: list[float] = []
    true_at: dict[float, np.ndarray] = {}
    stats: dict[str, Any] = {}
    initial_error = None
    compute_s = 0.0
    try:
        reset = getattr(system, "reset", None)
        if reset is not None:
            reset()  # nothing of the previous trial in this worker carries over
        if entry.wants_initial_pose:
            true_start = se2.between(world_from_map, trial.start)
            initial_error = protocol.initial_pose_error(seed, index)
            system.set_initial_pose(protocol.given_initial_pose(true_start, seed, index))
        goal_map = se2.transform_points(se2.inverse(world_from_map), trial.goal[None, :])[0]
        t0 = time.perf_counter()
        if protocol.goals == "native" and anchors is not None and hasattr(system, "set_goal_anchored"):
            system.set_goal_anchored(*anchors.goal_form(trial.goal, scenario.navigation_world))
        else:
            system.set_goal(goal_map)
        compute_s += time.perf_counter() - t0
        last_progress_time, last_progress_pose = sim.time, sim.true_pose
        while True:
            obs = sim.observe()
            t0 = time.perf_counter()
            command = system.step(obs)
            compute_s += time.perf_counter() - t0
            if not first.seen() and system.stats().get("planning_ms"):  # checked only until the first plan
                process = _rss()
                first.rss_process_bytes, first.rss_bytes = process, process - rss_before
                first.memory = _memory(system)
            true_at[obs.stamp] = sim.true_pose
            estimate = getattr(system, "pose_estimate", lambda: None)()
            if estimate is not None:
                estimate = np.asarray(estimate, float)
                estimate_rows.append((obs.stamp, *estimate))
                tracking.append(se2.distance(se2.compose(world_from_map, estimate), sim.true_pose))
            elif anchors is not None and hasattr(system, "anchored_pose"):
                anchored = anchors.locate(system.anchored_pose())
                if anchored is not None:
                    tracking.append(se2.distance(anchored, sim.true_pose))
            status = system.status
            ending = ""
            if status.state == Status.REACHED:
                ending = "reached"
            elif status.state == Status.FAILED:
                ending = "failed"
            elif sim.time >= limit:
                ending = "timeout"
            else:  # the robot moves
                collided = sim.step(command).collided
                if collided:
                    ending = "collision"
                elif se2.distance(sim.true_pose, last_progress_pose) > STUCK_DISTANCE_M:
                    last_progress_time, last_progress_pose = sim.time, sim.true_pose
                elif sim.time - last_progress_time > STUCK_WINDOW_S:
                    ending = "stuck"
            if ending:
                final = float(np.hypot(*(sim.true_pose[:2] - trial.goal)))
                success, reason = judge(ending, final, protocol.goal_tolerance, status.reason)
                break
        stats = system.stats()
        planning_ms = list(stats.get("planning_ms", []))
        first_plan_ms = stats.get("first_plan_ms", planning_ms[0] if planning_ms else None)
    except MemoryError:  # past --trial-memory-mb (RLIMIT_AS): recorded, and the run goes on
        reason, detail = "out_of_memory", "MemoryError: the trial passed its address-space limit (--trial-memory-mb)"
    except Exception as exc:  # a trial that raises is recorded and the run goes on
        reason, detail = "error", f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
        traceback.print_exc()
    rows = sim.trajectory_array()
    record = trial_record(
        entry.name,
        index,
        trial,
        seed,
        success=success,
        reason=reason,
        detail=detail,
        travelled_m=trajectory_length(rows),
        final_distance_m=float(np.hypot(*(sim.true_pose[:2] - trial.goal))),
        collisions=sim.collisions,
        sim_time_s=sim.time,
        compute_s=compute_s,
        planning_ms=planning_ms,
        first_plan_ms=first_plan_ms,
        tracking_error_m=tracking,
        initial_pose_error=initial_error,
        memory=_memory(system),
    )
    if anchors is not None:
        record.update(anchors.judge(stats, true_at, trial.goal, protocol.goal_tolerance))
    json.dumps(record, allow_nan=False)  # fail here, not in the writer, if a NaN slipped in
    return record, rows, np.asarray(estimate_rows) if estimate_rows else None
