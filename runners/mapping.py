"""Stage 1: drive the mapping route and let every system build its map from the same scans.

The mapping drive (``runners.route``: the shared follower on the true pose) moves the robot
along the scenario's route; systems only observe. Each scan reaches every system in the same tick
(lock-step); the wall clock of each ``observe`` call is that system's mapping cost. Each system's
map is saved and its ``MappingReport`` (``reports.records``) written to ``mapping/<system>.json``.
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel

from reports.records import MappingReport, Stats
from runners.metrics import disk_report, edge_errors, stats_ms, unjoined_neighbours
from runners.payload import ScenarioFiles, pack_dir
from runners.protocol import apply_setting, context_for
from runners.results import RunDir, write_json
from runners.route import RouteDrive, RouteError
from runners.sim import Simulator
from runners.systems import NavigationSystem, SystemEntry, get_system, import_modules
from scenarios import Scenario

GROWTH_EVERY_M = 10.0


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


def run_mapping(
    scenario: Scenario,
    systems: list[MappingSystem],
    run: RunDir,
    seed: int,
    progress: Callable[[float, float], None] | None = None,
) -> dict[str, MappingReport]:
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
) -> Generator[tuple[float, float], None, dict[str, MappingReport]]:
    """``run_mapping`` as a generator: yields (metres driven, route length) every tick and returns
    the reports. The drive depends on the seed and the route only, never on the systems
    observing it, so each system mapped alone (a mapping job) gets the very scans it would get
    beside the others."""
    sim = Simulator(scenario, seed=seed)
    try:
        drive = RouteDrive(scenario, sim)
        mappers = Mappers({s.entry.name: s.entry.create(s.config, context_for(s.entry, scenario, sim)) for s in systems})
        route_length = scenario.route_length_m
        for _ in drive.ticks():
            mappers.observe(sim)
            yield sim.travelled_m, route_length
        drive.check()
        entries = {s.entry.name: s.entry for s in systems}
        return {name: mappers.finish(name, entries[name], run, scenario, sim) for name in mappers.systems}
    finally:
        sim.close()


class Mappers:
    """The systems mapping one drive in lock-step: every scan to each, the wall clock of each
    ``observe`` call, each map's growth every ``GROWTH_EVERY_M``, and the true pose and distance
    driven at each scan's stamp. A system that raises stops observing (its mapping failed, with the
    exception as its report's ``error``); the others go on."""

    def __init__(self, systems: dict[str, NavigationSystem]) -> None:
        self.systems = systems
        self.observe_ms: dict[str, list[float]] = {name: [] for name in systems}
        self.growth: dict[str, list[list[float]]] = {name: [] for name in systems}
        self.true_at_stamp: dict[float, np.ndarray] = {}
        self.travelled_at_stamp: dict[float, float] = {}
        self.failures: dict[str, str] = {}
        self.scans = 0
        self.next_growth = 0.0

    def guarded(self, name: str, call: Callable[[], Any]) -> Any:
        try:
            return call()
        except Exception as exc:  # noqa: BLE001 - recorded as that system's mapping failure
            self.failures[name] = f"{type(exc).__name__}: {exc}".splitlines()[0][:300]
            return None

    def observe(self, sim: Simulator) -> None:
        """One tick: the scan to every system that has not failed."""
        obs = sim.observe()
        self.true_at_stamp[obs.stamp] = sim.true_pose
        self.travelled_at_stamp[obs.stamp] = sim.travelled_m
        self.scans += 1
        for name, system in self.systems.items():
            if name in self.failures:
                continue
            t0 = time.perf_counter()
            self.guarded(name, partial(system.observe, obs))
            self.observe_ms[name].append((time.perf_counter() - t0) * 1e3)
        if sim.travelled_m >= self.next_growth:
            for name, system in self.systems.items():
                if name not in self.failures:
                    self.growth[name].append([round(sim.travelled_m, 2), int(system.mapping_stats().get("map_bytes", 0))])
            self.next_growth += GROWTH_EVERY_M

    def finish(self, name: str, entry: SystemEntry, run: RunDir, scenario: Scenario, sim: Simulator) -> MappingReport:
        """The drive is over: the system finishes and saves its map; its report, written."""
        system, map_dir = self.systems[name], run.map_dir(name)
        if name not in self.failures:
            self.guarded(name, system.finish_mapping)
        if name not in self.failures:
            self.guarded(name, partial(system.save, map_dir))
        if name in self.failures:
            report = MappingReport(error=self.failures[name], scans=self.scans, map_bytes=None, map_disk_bytes=None)
        else:
            report = self.report(name, entry, map_dir, scenario, sim)
        write_json(run.mapping_path(name), report)
        return report

    def report(self, name: str, entry: SystemEntry, map_dir: Path, scenario: Scenario, sim: Simulator) -> MappingReport:
        """The runner's figures of a system's mapping, then the system's own (``mapping_stats``)."""
        system = self.systems[name]
        stats = dict(system.mapping_stats())
        self.growth[name].append([round(sim.travelled_m, 2), int(stats.get("map_bytes", 0))])
        scan_ms = stats_ms(self.observe_ms[name])
        fields: dict[str, Any] = {
            "scans": self.scans,
            "route_length_m": round(sim.travelled_m, 3),
            "route_plan_length_m": round(scenario.route_length_m, 3),
            "collisions": sim.collisions,
            "ms_per_scan": Stats(median=scan_ms.median, mean=scan_ms.mean, p95=scan_ms.p95, max=scan_ms.max),
            "map_bytes": int(stats.pop("map_bytes", 0)),
            "growth": self.growth[name],
        }
        memory = getattr(system, "memory", None)
        if memory is not None:
            fields["memory"] = memory().as_dict()
        fields["map_disk_bytes"], fields["map_disk"] = disk_report(entry, map_dir)
        stamped_edges = stats.pop("edges_stamped", None)
        if stamped_edges is not None:
            fields["edge_error"] = edge_errors(stamped_edges, self.true_at_stamp)
        vertex_stamps = stats.pop("vertex_stamps", None)
        if vertex_stamps is not None and stamped_edges is not None:
            fields["unjoined_neighbours"] = len(unjoined_locations(scenario, vertex_stamps, stamped_edges, self.true_at_stamp))
        if vertex_stamps is not None:
            fields.update(self.locations(vertex_stamps, sim.travelled_m / 2.0))
        return MappingReport(**{**fields, **stats})

    def locations(self, vertex_stamps: list[float], half: float) -> dict[str, Any]:
        """A graph system's locations: how many it made in the route's second half (revisits should
        reuse locations), how many of those where the robot had already been (a place mapped
        twice, as opposed to a room the first half never entered), and the true pose (scenario
        frame) where each was made: the runner's key to check a graph system's own estimates
        (``anchored_pose``) afterwards; never given to it."""
        late = sum(1 for stamp in vertex_stamps if self.travelled_at_stamp.get(stamp, 0.0) > half)
        return {
            "vertices_second_half": late,
            "vertices_second_half_share": round(late / max(len(vertex_stamps), 1), 4),
            "vertices_second_half_revisited": revisited_late(vertex_stamps, self.true_at_stamp, self.travelled_at_stamp, half),
            "anchors": [[stamp, *(round(float(v), 6) for v in self.true_at_stamp[stamp])] for stamp in vertex_stamps],
        }


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
            archive = pack_dir(map_dir) if report.error is None and map_dir.is_dir() else None
            yield {"kind": "mapped", "system": name, "report": report, "map": archive}
