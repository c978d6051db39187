"""Stage 1: drive the mapping route and let every system build its map from the same scans.

A ground-truth route follower (the shared follower on the true pose) moves the robot along the
scenario's route; systems only observe. Each scan reaches every system in the same tick
(lock-step); the wall clock of each ``observe`` call is that system's mapping cost.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel

from navkit.follower import FollowerConfig, PathFollower
from navkit.types import MEMORY_PARTS
from runners.metrics import edge_errors, stats_ms, unjoined_neighbours
from runners.payload import ScenarioFiles, pack_dir
from runners.protocol import TrialProtocol
from runners.results import RunDir, disk_bytes, write_json
from runners.sim import MAPPING_STREAM, Simulator
from runners.systems import GroundTruth, SystemContext, SystemEntry, get_system
from scenarios import Scenario

GROWTH_EVERY_M = 10.0
STUCK_S = 60.0  # no progress along the route for this long (simulated time) stops mapping


class RouteError(RuntimeError):
    """The mapping route cannot be driven (a property of the scenario: resuming will not help)."""


ROUTE_GOAL_TOLERANCE_M = 0.3


@dataclass
class MappingSystem:
    entry: SystemEntry
    config: BaseModel


REVISIT_RADIUS_M = 1.0  # a location made this close to a first-half pose maps a place twice


def revisited_late(
    vertex_stamps: list[float], true_at_stamp: dict[float, np.ndarray], travelled_at_stamp: dict[float, float], half: float
) -> int:
    """Locations made in the route's second half within ``REVISIT_RADIUS_M`` of a true pose the
    robot held in its first half."""
    early = np.array([pose[:2] for stamp, pose in true_at_stamp.items() if travelled_at_stamp[stamp] <= half])
    if early.size == 0:
        return 0
    count = 0
    for stamp in vertex_stamps:
        if travelled_at_stamp.get(stamp, 0.0) > half:
            gap = np.min(np.hypot(*(early - true_at_stamp[stamp][:2]).T))
            count += int(gap <= REVISIT_RADIUS_M)
    return count


def unjoined_locations(
    scenario: Scenario, vertex_stamps: list[float], stamped_edges: list, true_at_stamp: dict[float, np.ndarray]
) -> list[tuple[int, int]]:
    """A graph system's locations (by the true poses where they were made) that lie close together
    with a way between them the robot fits, yet the graph joins only the long way round
    (``metrics.unjoined_neighbours``)."""
    index = {stamp: k for k, stamp in enumerate(vertex_stamps)}
    positions = np.array([true_at_stamp[stamp][:2] for stamp in vertex_stamps])
    pairs = [(index[u], index[v]) for u, v, _ in stamped_edges if u in index and v in index]
    return unjoined_neighbours(positions, pairs, scenario.world.clearances_at, scenario.spec.robot.radius)


def context_for(
    entry: SystemEntry, scenario: Scenario, sim: Simulator | None, protocol: TrialProtocol | None = None
) -> SystemContext:
    """What a system is told: the robot, the sensor, the stop tolerance; ground truth only if the
    entry is privileged (the oracle), with the world of the stage the simulator runs."""
    protocol = protocol or TrialProtocol()
    truth = None
    if entry.privileged:
        world = scenario.world
        if sim is not None and sim.with_changes:
            world = scenario.navigation_world
        truth = GroundTruth(world=world, world_from_map=scenario.route_start, true_pose=(lambda: sim.true_pose) if sim else None)
    return SystemContext(
        robot=scenario.spec.robot, sensor=scenario.spec.sensor, stop_tolerance=protocol.stop_tolerance, ground_truth=truth
    )


def disk_report(entry: SystemEntry, map_dir: Path) -> dict[str, Any]:
    """Bytes of a saved map on disk: the whole folder, and per memory part where the system says
    which file is which (``disk_usage``); files of no part (e.g. mapping state kept for later
    re-optimisation) count under ``other``."""
    total = disk_bytes(map_dir)
    usage = getattr(entry.cls, "disk_usage", None)
    parts = dict(usage(map_dir)) if usage is not None else {"map": total}
    disk = {part: int(parts.get(part, 0)) for part in MEMORY_PARTS}
    disk["other"] = total - sum(v for k, v in parts.items() if k in MEMORY_PARTS and k != "model")
    return {"disk_bytes": total, "disk": disk}


def run_mapping(
    scenario: Scenario,
    systems: list[MappingSystem],
    run: RunDir,
    seed: int,
    progress: Callable[[float, float], None] | None = None,
) -> dict[str, dict[str, Any]]:
    """Drive the route once; save each system's map and write ``mapping/<system>.json``."""
    drive = drive_mapping(scenario, systems, run, seed)
    while True:
        try:
            travelled, total = next(drive)
        except StopIteration as finished:
            return finished.value
        if progress is not None:
            progress(travelled, total)


def drive_mapping(
    scenario: Scenario, systems: list[MappingSystem], run: RunDir, seed: int
) -> Generator[tuple[float, float], None, dict[str, dict[str, Any]]]:
    """``run_mapping`` as a generator: yields (metres driven, route length) every tick and returns
    the reports. The drive depends on the seed and the route only, never on the systems
    observing it, so each system mapped alone (a mapping job) gets the very scans it would get
    beside the others."""
    robot = scenario.spec.robot
    sim = Simulator(scenario, seed=seed)
    try:
        sim.reset(scenario.route_start, stream=(MAPPING_STREAM,))
        instances = {s.entry.name: s.entry.create(s.config, context_for(s.entry, scenario, sim)) for s in systems}
        follower = PathFollower(
            FollowerConfig(max_linear=robot.max_linear, max_angular=robot.max_angular, goal_tolerance=ROUTE_GOAL_TOLERANCE_M)
        )
        follower.set_path(scenario.route)
        route_length = scenario.route_length_m
        max_ticks = int((3.0 * route_length / robot.max_linear + 600.0) * scenario.spec.sensor.rate_hz)
        observe_ms: dict[str, list[float]] = {name: [] for name in instances}
        growth: dict[str, list[list[float]]] = {name: [] for name in instances}
        true_at_stamp: dict[float, np.ndarray] = {}
        travelled_at_stamp: dict[float, float] = {}
        failures: dict[str, str] = {}  # a system that raised stops observing; the others go on

        def guarded(name: str, call: Callable[[], Any]) -> Any:
            try:
                return call()
            except Exception as exc:  # noqa: BLE001 - recorded as that system's mapping failure
                failures[name] = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
                return None

        next_growth = 0.0
        scans = 0
        progress_mark, progress_time = -1.0, 0.0
        for _ in range(max_ticks):
            obs = sim.observe()
            true_at_stamp[obs.stamp] = sim.true_pose
            travelled_at_stamp[obs.stamp] = sim.travelled_m
            scans += 1
            for name, system in instances.items():
                if name in failures:
                    continue
                t0 = time.perf_counter()
                guarded(name, lambda system=system, obs=obs: system.observe(obs))
                observe_ms[name].append((time.perf_counter() - t0) * 1e3)
            if sim.travelled_m >= next_growth:
                for name, system in instances.items():
                    if name not in failures:
                        growth[name].append([round(sim.travelled_m, 2), int(system.mapping_stats().get("map_bytes", 0))])
                next_growth += GROWTH_EVERY_M
            yield sim.travelled_m, route_length
            command = follower.command(sim.true_pose)
            if follower.reached:
                break
            if follower.progress > progress_mark + 0.1:
                progress_mark, progress_time = follower.progress, sim.time
            elif sim.time - progress_time > STUCK_S:
                x, y = sim.true_pose[:2]
                raise RouteError(
                    f"the mapping route is blocked at ({x:.2f}, {y:.2f}), {follower.progress:.1f} m along it "
                    f"({sim.collisions} collisions): it passes too close to walls or obstacles for the robot"
                )
            sim.step(command)
        else:
            raise RouteError(f"mapping route not completed within {max_ticks} ticks")
        reports: dict[str, dict[str, Any]] = {}
        entries = {s.entry.name: s.entry for s in systems}
        for name, system in instances.items():
            map_dir = run.map_dir(name)
            if name not in failures:
                guarded(name, system.finish_mapping)
            if name not in failures:
                guarded(name, lambda system=system, map_dir=map_dir: system.save(map_dir))
            if name in failures:
                report = {"error": failures[name], "scans": scans, "map_bytes": None, "map_disk_bytes": None}
                write_json(run.mapping_path(name), report)
                reports[name] = report
                continue
            stats = dict(system.mapping_stats())
            growth[name].append([round(sim.travelled_m, 2), int(stats.get("map_bytes", 0))])
            report: dict[str, Any] = {
                "scans": scans,
                "route_length_m": round(sim.travelled_m, 3),
                "route_plan_length_m": round(route_length, 3),
                "collisions": sim.collisions,
                "ms_per_scan": {k: v for k, v in stats_ms(observe_ms[name]).items() if k in ("median", "p95", "mean", "max")},
                "map_bytes": int(stats.pop("map_bytes", 0)),
                "growth": growth[name],
            }
            memory = getattr(system, "memory", None)
            if memory is not None:
                report["memory"] = memory().as_dict()
            disk = disk_report(entries[name], map_dir)
            report["map_disk_bytes"], report["map_disk"] = disk["disk_bytes"], disk["disk"]
            stamped_edges = stats.pop("edges_stamped", None)
            if stamped_edges is not None:
                report["edge_error"] = edge_errors(stamped_edges, true_at_stamp)
            vertex_stamps = stats.pop("vertex_stamps", None)
            if vertex_stamps is not None and stamped_edges is not None:
                report["unjoined_neighbours"] = len(unjoined_locations(scenario, vertex_stamps, stamped_edges, true_at_stamp))
            if vertex_stamps is not None:
                # revisits should reuse locations: the share of vertices made in the route's second half
                half = sim.travelled_m / 2.0
                late = sum(1 for stamp in vertex_stamps if travelled_at_stamp.get(stamp, 0.0) > half)
                report["vertices_second_half"] = late
                report["vertices_second_half_share"] = round(late / max(len(vertex_stamps), 1), 4)
                # of those, the ones made where the robot had already been (a place mapped twice),
                # as opposed to places the route's first half never entered (a room visited late)
                report["vertices_second_half_revisited"] = revisited_late(vertex_stamps, true_at_stamp, travelled_at_stamp, half)
                # the true pose (scenario frame) where each location was made: the runner's key to
                # check a graph system's own estimates (``anchored_pose``) afterwards; never given to it
                report["anchors"] = [[stamp, *(round(float(v), 6) for v in true_at_stamp[stamp])] for stamp in vertex_stamps]
            report.update(stats)
            write_json(run.mapping_path(name), report)
            reports[name] = report
        return reports
    finally:
        sim.close()


# ---------------------------------------------------------------------------------------------
# a mapping job: (scenario, seed, system) in a worker process


@dataclass
class MappingJob:
    """Systems mapping the route together in one drive (lock-step): one system per job when the
    executor has a slot for each (a cluster), several when it has fewer (on 2 cores a drive costs
    as much as NavTopo's mapping, so three drives would cost more than one shared)."""

    scenario: ScenarioFiles
    configs: dict[str, dict[str, Any]]  # system -> its resolved config
    seed: int
    setting: str | None = None  # runners.protocol.SETTINGS name; None: the scenario file's own
    modules: list[str] = field(default_factory=list)  # to import first: systems registered outside the runner


PROGRESS_EVERY_S = 0.5


def mapping_job(job: MappingJob) -> Iterator[dict[str, Any]]:
    """The job's systems map the route in a worker: yields ``progress`` {travelled_m, route_m} (at
    most every ``PROGRESS_EVERY_S``), then per system ``mapped`` {system, report, map (tar bytes,
    None if its mapping failed)}; or ``route_error`` {detail} (the route cannot be driven: a
    property of the scenario)."""
    from runners.navigation import import_modules
    from runners.protocol import apply_setting

    import_modules(job.modules)
    systems = []
    for name, config in job.configs.items():
        entry = get_system(name)
        systems.append(MappingSystem(entry, entry.config_model.model_validate(config)))
    with tempfile.TemporaryDirectory(prefix="navtopo-job-") as folder:
        scenario = apply_setting(job.scenario.load(Path(folder) / "scenario"), job.setting)
        run = RunDir(Path(folder) / "run")
        drive = drive_mapping(scenario, systems, run, job.seed)
        shown = 0.0
        try:
            while True:
                travelled, total = next(drive)
                if time.monotonic() - shown >= PROGRESS_EVERY_S:
                    shown = time.monotonic()
                    yield {"kind": "progress", "travelled_m": travelled, "route_m": total}
        except StopIteration as finished:
            reports = finished.value
        except RouteError as exc:
            yield {"kind": "route_error", "detail": str(exc)}
            return
        for name, report in reports.items():
            map_dir = run.map_dir(name)
            archive = pack_dir(map_dir) if "error" not in report and map_dir.is_dir() else None
            yield {"kind": "mapped", "system": name, "report": report, "map": archive}
