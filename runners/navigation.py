"""Stage 2: in a fresh worker process, load one system's saved map and run trials in order.

Per trial: the robot is placed at the start (scenario frame); the system forgets the previous
trial (``reset``), gets the goal in the map frame (and, if its entry asks, the initial pose with
the protocol's seeded error, ``runners.protocol``); the loop observes, asks the system for a
command and moves the robot until the system declares reached or failed, the robot collides,
gets stuck or times out; the record says where it failed (``failure_stage``: the system's status,
or ``runners.metrics.failure_stage`` for the endings the runner decides) with a one-line ``detail``
(the runner's words on its own endings, then the system's). The worker times the map's loading (``map_load_ms``), measures RSS and
the system's memory breakdown right after its first plan, and the tracking error of the system's
own pose estimate (where it has one) against the truth at every tick. An exception inside a
trial is recorded (reason ``error``, or ``out_of_memory`` for a ``MemoryError`` under
``--trial-memory-mb``; stage ``runner``) with a one-line ``detail``, and the next trial runs.

Each trial's record is a ``TrialRecord`` and the worker's figures a ``NavigationReport``
(``reports.records``). A job (``TrialJob``) carries the scenario's files and the saved map as
bytes (``runners.payload``), never a path: the worker unpacks them into a temporary folder of its
own and yields, per trial, a ``started`` message (with the trial's wall-clock limit as
``deadline_s``) and a ``trial`` message with the record and the trajectories; the driver writes
them (``runners.run``).
"""

from __future__ import annotations

import gc
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
from navkit.errors import BenchError
from navkit.types import Command, FailureStage, NavStatus
from reports.records import NavigationReport, TrialRecord
from runners.anchors import Anchors
from runners.metrics import (
    STUCK_DISTANCE_M,
    STUCK_WINDOW_S,
    disk_report,
    efficiency,
    failure_stage,
    judge,
    timeout_s,
    trajectory_length,
    trial_record,
)
from runners.payload import ScenarioFiles, pack_dir, unpack_dir
from runners.protocol import TrialProtocol, apply_setting, context_for
from runners.results import MAP_FRAME_FILE, RunDir, write_map_frame, write_tum
from runners.sim import TRIAL_STREAM, Simulator
from runners.systems import NavigationSystem, Status, SystemEntry, get_system, import_modules
from scenarios import Scenario, load_scenario
from scenarios.route_space import polyline_length, shortest_path


class SavedMapError(BenchError):
    """A saved map its system cannot load (truncated, edited, another format): the navigation stage
    failed before any trial, which is not a navigation failure of the system."""

    exit_code = 1  # the navigation stage failed


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


def _rss() -> int:
    return int(psutil.Process().memory_info().rss)


def _memory(system: Any) -> dict[str, int] | None:
    memory = getattr(system, "memory", None)
    return memory().as_dict() if memory is not None else None


@dataclass
class FirstPlan:
    """What the worker measures once, right after the system's first plan (DESIGN.md, memory)."""

    rss_bytes: int | None = None  # growth from before the map was loaded
    rss_process_bytes: int | None = None  # the whole worker
    memory: dict[str, int] | None = None  # the system's breakdown at that moment

    def seen(self) -> bool:
        return self.rss_process_bytes is not None

    def measure(self, system: Any, rss_before: int) -> None:
        process = _rss()
        self.rss_process_bytes, self.rss_bytes = process, process - rss_before
        self.memory = _memory(system)


def run_trial_job(job: TrialJob) -> dict[str, Any]:
    """The job in this process, all at once: {"system", "records": [TrialRecord], "memory":
    NavigationReport or None} (tests, tools)."""
    records: list[TrialRecord] = []
    memory: NavigationReport | None = None
    for message in trial_job(job):
        if message["kind"] == "map_load_error":
            raise SavedMapError(f"the saved map of {job.system} cannot be loaded: {message['detail']}")
        if message["kind"] == "trial":
            records.append(message["record"])
        elif message["kind"] == "memory":
            memory = message["report"]
    return {"system": job.system, "records": records, "memory": memory}


def trial_job(job: TrialJob) -> Iterator[dict[str, Any]]:
    """A navigation job in a worker process: yields ``started`` {trial, deadline_s}, ``trial``
    {record (TrialRecord), trajectory (T, 4), estimate (T, 4) or None} per trial, then ``memory``
    {report (NavigationReport)} (the fresh-process figures, if ``measure_memory``); or a single
    ``map_load_error`` {detail}."""
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
                disk_total, disk = disk_report(entry, map_dir)
                report = NavigationReport(
                    map_bytes=int(system.stats().get("map_bytes", 0)),
                    map_load_ms=round(map_load_ms, 3),
                    rss_bytes=first.rss_bytes,
                    rss_process_bytes=first.rss_process_bytes,
                    rss_before_load=rss_before,
                    memory=first.memory,
                    disk_bytes=disk_total,
                    disk=disk,
                )
                yield {"kind": "memory", "report": report}
        finally:
            sim.close()


def write_trial(run: RunDir, scenario: Scenario, message: dict[str, Any]) -> None:
    """The driver's side of a ``trial`` message: trajectories first, then the record (its line in
    trials.jsonl is what marks the trial done)."""
    record: TrialRecord = message["record"]
    write_tum(run.trajectory_path(record.system, record.trial), message["trajectory"])
    estimate = message.get("estimate")
    if estimate is not None and len(estimate):
        estimate_path = run.trajectory_path(record.system, record.trial, estimate=True)
        write_tum(estimate_path, estimate)
        write_map_frame(estimate_path.with_name(MAP_FRAME_FILE), scenario.route_start)
    run.append_trial(record)


# ---------------------------------------------------------------------------------------------
# one trial


@dataclass
class Tracking:
    """A trial's estimates against the truth, per tick: the system's own map-frame estimate (its
    rows for ``*.est.tum`` and its distance to the true pose), or a graph system's
    location-relative estimate placed by the anchors (its distance only); and the true pose
    (scenario frame) at each stamp."""

    world_from_map: NDArray[np.float64]
    anchors: Anchors | None
    estimate_rows: list[tuple[float, float, float, float]] = field(default_factory=list)
    errors: list[float] = field(default_factory=list)
    true_at: dict[float, NDArray[np.float64]] = field(default_factory=dict)

    def add(self, system: Any, stamp: float, true_pose: NDArray[np.float64]) -> None:
        self.true_at[stamp] = true_pose
        estimate = getattr(system, "pose_estimate", lambda: None)()
        if estimate is not None:
            estimate = np.asarray(estimate, float)
            self.estimate_rows.append((stamp, *estimate))
            self.errors.append(float(se2.distance(se2.compose(self.world_from_map, estimate), true_pose)))
        elif self.anchors is not None and hasattr(system, "anchored_pose"):
            anchored = self.anchors.locate(system.anchored_pose())
            if anchored is not None:
                self.errors.append(float(se2.distance(anchored, true_pose)))


class StuckWatch:
    """The robot moved by a command: ``collision``, ``stuck`` (not ``STUCK_DISTANCE_M`` from where
    it last was for ``STUCK_WINDOW_S`` of simulated time) or "" (it goes on)."""

    def __init__(self, sim: Simulator) -> None:
        self.sim = sim
        self.time, self.pose = sim.time, sim.true_pose

    def move(self, command: Command) -> str:
        sim = self.sim
        if sim.step(command).collided:
            return "collision"
        if se2.distance(sim.true_pose, self.pose) > STUCK_DISTANCE_M:
            self.time, self.pose = sim.time, sim.true_pose
        elif sim.time - self.time > STUCK_WINDOW_S:
            return "stuck"
        return ""


@dataclass
class TrialOutcome:
    """What a trial leaves for its record, filled as it goes (an exception keeps what was set)."""

    success: bool = False
    reason: str = ""
    detail: str | None = None
    stage: str | None = None  # navkit.types.FailureStage of a failure
    compute_s: float = 0.0  # wall clock inside the system's calls
    initial_error: NDArray[np.float64] | None = None  # the protocol's error in the given initial pose
    stats: dict[str, Any] = field(default_factory=dict)  # the system's, at the trial's end
    planning_ms: list[float] = field(default_factory=list)
    first_plan_ms: float | None = None


def run_one_trial(
    scenario: Scenario,
    sim: Simulator,
    entry: SystemEntry,
    system: NavigationSystem,
    trial: Any,
    index: int,
    seed: int,
    protocol: TrialProtocol | None = None,
    first: FirstPlan | None = None,
    rss_before: int = 0,
    anchors: Anchors | None = None,
) -> tuple[TrialRecord, NDArray[np.float64], NDArray[np.float64] | None]:
    """One trial in this worker: (record, true trajectory rows, estimate rows or None)."""
    protocol = protocol or TrialProtocol()
    first = first or FirstPlan()
    sim.reset(trial.start, stream=(TRIAL_STREAM, index))
    mapped_m = mapped_shortest_m(scenario, trial)
    limit = timeout_s(trial.shortest_m, scenario.spec.robot.max_linear, mapped_m or 0.0)
    outcome = TrialOutcome()
    tracking = Tracking(scenario.route_start, anchors)
    try:
        start_trial(scenario, entry, system, trial, index, seed, protocol, anchors, outcome)
        ending, status = drive_trial(sim, system, limit, first, rss_before, tracking, outcome)
        final = float(np.hypot(*(sim.true_pose[:2] - trial.goal)))
        outcome.success, outcome.reason = judge(ending, final, protocol.goal_tolerance, status.reason)
        outcome.stage = failure_stage(ending, outcome.success, outcome.reason, status.stage)
        outcome.detail = None if outcome.success else ending_detail(ending, status, sim.true_pose, limit, final)
        outcome.stats = system.stats()
        outcome.planning_ms = list(outcome.stats.get("planning_ms", []))
        outcome.first_plan_ms = outcome.stats.get("first_plan_ms", outcome.planning_ms[0] if outcome.planning_ms else None)
    except MemoryError:  # past --trial-memory-mb (RLIMIT_AS): recorded, and the run goes on
        outcome.reason, outcome.stage = "out_of_memory", FailureStage.RUNNER.value
        outcome.detail = "MemoryError: the trial passed its address-space limit (--trial-memory-mb)"
    except Exception as exc:  # a trial that raises is recorded and the run goes on
        outcome.reason, outcome.detail = "error", f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
        outcome.stage = FailureStage.RUNNER.value
        traceback.print_exc()
    rows = sim.trajectory_array()
    memory = _memory(system)
    diagnostics = {} if anchors is None else anchors.judge(outcome.stats, trial.goal)
    startup = startup_check(outcome.stats, tracking, rows, protocol.goal_tolerance)
    if startup is not None:
        diagnostics["startup_localization"] = startup
    diagnostics.update(extra_efficiencies(scenario, trial, rows, startup if outcome.success else None, outcome.success, mapped_m))
    record = trial_record(
        entry.name,
        index,
        trial,
        seed,
        success=outcome.success,
        reason=outcome.reason,
        detail=outcome.detail,
        failure_stage=outcome.stage,
        travelled_m=trajectory_length(rows),
        final_distance_m=float(np.hypot(*(sim.true_pose[:2] - trial.goal))),
        collisions=sim.collisions,
        sim_time_s=sim.time,
        compute_s=outcome.compute_s,
        planning_ms=outcome.planning_ms,
        first_plan_ms=outcome.first_plan_ms,
        tracking_error_m=tracking.errors,
        initial_pose_error=outcome.initial_error,
        memory=memory,
        diagnostics=diagnostics,
    )
    json.dumps(record.as_json(), allow_nan=False)  # fail here, not in the writer, if a NaN slipped in
    return record, rows, np.asarray(tracking.estimate_rows) if tracking.estimate_rows else None


STARTUP_YAW_DEG = 15.0  # a start-up is right within the goal tolerance and this many degrees


def startup_check(stats: dict[str, Any], tracking: Tracking, rows: NDArray, tolerance: float) -> dict[str, Any] | None:
    """The system's start-up localization (its first, ``stats["localizations"][0]``) against the
    truth: seconds, metres driven before it, its error, right or wrong, whether it came from the given
    pose. A graph system names the location (``vertex_stamp``, placed by the anchors), a metric one
    gives its map-frame pose (``map_pose``). None: the system reported none."""
    localizations = stats.get("localizations") or []
    if not localizations:
        return None
    first = localizations[0]
    estimate: NDArray[np.float64] | None
    if "map_pose" in first:
        estimate = se2.compose(tracking.world_from_map, np.asarray(first["map_pose"], dtype=np.float64))
    elif tracking.anchors is not None:
        estimate = tracking.anchors.locate((first["vertex_stamp"], np.asarray(first["pose"])))
    else:
        return None
    truth = tracking.true_at.get(first["stamp"])
    if estimate is None or truth is None:
        return None
    error = float(se2.distance(estimate, truth))
    yaw = float(np.degrees(abs(float(se2.wrap_angle(estimate[2] - truth[2])))))
    before = rows[rows[:, 0] <= first["stamp"] + 1e-9] if len(rows) else rows
    return {
        "seconds": first.get("seconds"),
        "metres": round(trajectory_length(before), 4) if len(before) else 0.0,
        "error_m": round(error, 4),
        "yaw_error_deg": round(yaw, 3),
        "right": bool(error <= tolerance and yaw <= STARTUP_YAW_DEG),
        "given_pose": bool(first.get("given_pose", False)),
        "stamp": first["stamp"],
        **{k: first[k] for k in ("looks", "hypotheses") if k in first},
    }


def mapped_shortest_m(scenario: Scenario, trial: Any) -> float | None:
    """On a scene with ``world.changes``: the shortest path from the trial's start to its goal in the
    world as it was mapped (None elsewhere, or where there is none)."""
    if scenario.navigation_world is scenario.world:
        return None
    path = shortest_path(scenario.world, scenario.passable, trial.start[:2], trial.goal)
    return None if path is None else polyline_length(path)


def extra_efficiencies(
    scenario: Scenario,
    trial: Any,
    rows: NDArray,
    startup: dict[str, Any] | None,
    success: bool,
    mapped_m: float | None = None,
) -> dict[str, Any]:
    """A successful trial's efficiency from the moment the system committed to its pose
    (``efficiency_after_startup``: the true shortest path from where the robot was then, over the
    metres driven after), and, on a scene with ``world.changes``, against the shortest path in the
    world as it was mapped (``efficiency_mapped_world``: what discovering the change cost; ``mapped_m``,
    that path's length, by ``mapped_shortest_m``)."""
    out: dict[str, Any] = {}
    if not success or not len(rows):
        return out
    travelled = trajectory_length(rows)
    if startup is not None:
        before = rows[rows[:, 0] <= startup["stamp"] + 1e-9]
        driven = trajectory_length(before) if len(before) else 0.0
        if driven < 0.05:  # committed where it started: the trial's own figure
            out["efficiency_after_startup"] = round(efficiency(trial.shortest_m, travelled), 6)
        else:
            at = before[-1, 1:3]
            path = shortest_path(scenario.navigation_world, scenario.navigation_passable, at, trial.goal)
            if path is not None:
                shortest = polyline_length(path)
                out["efficiency_after_startup"] = round(efficiency(shortest, travelled - driven), 6)
    if mapped_m is not None:
        out["efficiency_mapped_world"] = round(efficiency(mapped_m, travelled), 6)
    return out


def start_trial(
    scenario: Scenario,
    entry: SystemEntry,
    system: Any,
    trial: Any,
    index: int,
    seed: int,
    protocol: TrialProtocol,
    anchors: Anchors | None,
    outcome: TrialOutcome,
) -> None:
    """The system forgets the previous trial, gets its initial pose (if its entry wants one: the
    true start in the map frame with the protocol's error) and the goal."""
    world_from_map = scenario.route_start
    reset = getattr(system, "reset", None)
    if reset is not None:
        reset()  # nothing of the previous trial in this worker carries over
    if entry.wants_initial_pose and protocol.gives_pose:
        true_start = se2.between(world_from_map, trial.start)
        outcome.initial_error = protocol.initial_pose_error(seed, index)
        system.set_initial_pose(protocol.given_initial_pose(true_start, seed, index))
    goal_map = se2.transform_points(se2.inverse(world_from_map), trial.goal[None, :])[0]
    t0 = time.perf_counter()
    if protocol.goals == "native" and anchors is not None and hasattr(system, "set_goal_anchored"):
        system.set_goal_anchored(*anchors.goal_form(trial.goal, scenario.navigation_world))
    else:
        system.set_goal(goal_map)
    outcome.compute_s += time.perf_counter() - t0


def drive_trial(
    sim: Simulator,
    system: NavigationSystem,
    limit: float,
    first: FirstPlan,
    rss_before: int,
    tracking: Tracking,
    outcome: TrialOutcome,
) -> tuple[str, NavStatus]:
    """Tick by tick until the trial ends: observe, the system's command, then the robot moved by it
    unless the system declared reached or failed or the time (``limit``, simulated s) is up.
    Returns the ending (``metrics.ENDINGS``) and the system's status then (its reason, its stage,
    its detail)."""
    watch = StuckWatch(sim)
    while True:
        obs = sim.observe()
        t0 = time.perf_counter()
        command = system.step(obs)
        outcome.compute_s += time.perf_counter() - t0
        if not first.seen() and system.stats().get("planning_ms"):  # checked only until the first plan
            first.measure(system, rss_before)
        tracking.add(system, obs.stamp, sim.true_pose)
        status = system.status
        if status.state == Status.REACHED:
            return "reached", status
        if status.state == Status.FAILED:
            return "failed", status
        if sim.time >= limit:
            return "timeout", status
        ending = watch.move(command)
        if ending:
            return ending, status


def ending_detail(ending: str, status: NavStatus, true_pose: NDArray[np.float64], limit: float, final: float) -> str | None:
    """The one line of a failed trial: the runner's words on an ending it decided (where the robot
    was, by the truth, in the scenario frame; which clock ran out), then the system's own
    (``status.detail``), joined by "; ", at most 300 characters."""
    x, y = float(true_pose[0]), float(true_pose[1])
    runner = {
        "reached": f"declared reached {final:.2f} m from the goal",
        "collision": f"collided at ({x:.2f}, {y:.2f}) in the scenario frame, {final:.1f} m from the goal",
        "stuck": f"moved less than {STUCK_DISTANCE_M:g} m in {STUCK_WINDOW_S:g} s, at ({x:.2f}, {y:.2f}) in the scenario frame, "
        f"{final:.1f} m from the goal",
        "timeout": f"passed its simulated-time limit of {limit:.0f} s, {final:.1f} m from the goal",
    }.get(ending)
    parts = [part for part in (runner, status.detail) if part]
    return " ".join("; ".join(parts).split())[:300] if parts else None
