"""One benchmark run: mapping, then navigation trials, then the summary (the `run` command).

The run's files are records of ``reports.records``: the ``Manifest`` written first (and read back
on resume), the systems' ``MappingReport`` and ``NavigationReport``, a ``TrialRecord`` per trial
and a ``SystemSummary`` per system at the end.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import itertools
import os
import platform
import shutil
import socket
import subprocess
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import psutil

from navkit.errors import BenchError
from navkit.types import FailureStage
from reports.records import (
    Manifest,
    MappingReport,
    NavigationReport,
    Protocol,
    RunFormatError,
    ScenarioInfo,
    SystemSummary,
    TrialRecord,
)
from runners.driver import Outcome, Steps, Submission, drive
from runners.executors import Event, Executor, open_executor
from runners.ground_truth import write_ground_truth
from runners.mapping import MappingJob, mapping_job
from runners.metrics import summarize, trial_record
from runners.navigation import TrialJob, trial_job, write_trial
from runners.payload import ScenarioFiles, install_dir, pack_dir, scenario_files
from runners.protocol import TrialProtocol, apply_setting, setting_of
from runners.results import RunDir, point_latest, write_json
from runners.route import RouteError
from runners.systems import SystemEntry, get_system
from scenarios import Scenario

DEFAULT_TRIAL_WALL_S = 3600.0  # far beyond any bundled trial: it catches a hang, not a slow system
PACKAGES = ["numpy", "scipy", "torch", "kiss-icp", "gtsam", "pybullet", "numba", "shapely", "opencv-python-headless", "pydantic"]


@dataclass
class RunOptions:
    systems: list[str]
    trials: int | None = None  # first N trials; None = all; 0 = mapping only
    seed: int | None = None
    out: Path | None = None
    resume: Path | None = None
    workers: int | None = None  # jobs at once; None: the machine's cores (local), the cluster's CPUs (ray)
    executor: str = "local"
    ray_address: str | None = None
    results_root: Path = Path("results")
    config_overrides: dict[str, Any] | None = None  # {system: {key: value, ...}} merged over the defaults
    setting: str | None = None  # runners.protocol.SETTINGS name; None: the scenario file's own noise
    maps_from: Path | None = None  # reuse the maps of this earlier run of the same scenario, seed and setting
    protocol: TrialProtocol = field(default_factory=TrialProtocol)
    trial_wall_s: float | None = DEFAULT_TRIAL_WALL_S  # a trial's wall-clock limit (its worker is killed past it)
    trial_memory_mb: float | None = None  # address space a trial may add (RLIMIT_AS); None: no limit


def git_revision() -> str | None:
    try:
        here = Path(__file__).resolve().parent
        rev = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5)
        if rev.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=here, capture_output=True, text=True, timeout=5
        )
        return rev.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


def scenario_fingerprint(scenario: Scenario) -> str:
    """sha256 of the scenario file and of the map files it reads: what a resume must find unchanged."""
    digest = hashlib.sha256()
    for path in scenario_files(scenario):
        digest.update(path.read_bytes())
    return digest.hexdigest()


def versions() -> dict[str, str | None]:
    out: dict[str, str | None] = {"python": platform.python_version()}
    for name in ["navtopo-bench", *PACKAGES]:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def machine() -> dict[str, Any]:
    return {
        "hostname": socket.gethostname(),
        "platform": platform.platform(),
        "processor": platform.machine(),
        "cpus": os.cpu_count(),
        "memory_bytes": psutil.virtual_memory().total,
    }


def deep_merge(base: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    merged = dict(base)
    for key, value in overrides.items():
        merged[key] = deep_merge(merged[key], value) if isinstance(value, dict) and isinstance(merged.get(key), dict) else value
    return merged


def resolved_configs(names: list[str], overrides: dict[str, Any] | None = None, setting: str | None = None) -> dict[str, Any]:
    """Each system's full config: defaults, then the system's overrides for the run's setting (its
    configuration for that odometry), then the user's, validated by its model."""
    out = {}
    for name in names:
        entry = get_system(name)
        data = entry.default_config().model_dump(mode="json")
        data = deep_merge(data, entry.setting_overrides.get(setting or "", {}))
        data = deep_merge(data, (overrides or {}).get(name) or {})
        out[name] = entry.config_model.model_validate(data).model_dump(mode="json")
    return out


def new_run_dir(options: RunOptions, scenario: Scenario, seed: int) -> RunDir:
    if options.out is not None:
        return RunDir(options.out)
    stamp = dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    base = f"{stamp}-s{seed}" + (f"-{options.setting}" if options.setting else "")
    root = options.results_root / scenario.name / base
    suffix = 1
    while root.exists():
        suffix += 1
        root = options.results_root / scenario.name / f"{base}-{suffix}"
    return RunDir(root)


@dataclass
class RunHooks:
    """What a run tells its caller as it goes (each optional).

    on_stage(stage, value): ("run_dir", Path), ("mapping", [systems]), ("navigation", trial count),
    ("done", RunDir) once its summary is written;
    on_mapping(travelled_m, route_m): the slowest mapping drive; on_trial(record): a trial recorded
    (its JSON object, as its line in trials.jsonl holds it)."""

    on_stage: Callable[[str, Any], None] | None = None
    on_mapping: Callable[[float, float], None] | None = None
    on_trial: Callable[[TrialRecord], None] | None = None


@dataclass
class RunPlan:
    scenario: Scenario
    options: RunOptions
    hooks: RunHooks = field(default_factory=RunHooks)


def in_folder(folder: Path, options: RunOptions) -> RunOptions | None:
    """``options`` for the run kept in ``folder``, as the same command run again finds it (sweeps,
    suites): None if it is finished (its summary is there), a resume if it started, else a new run."""
    if (folder / "summary.json").is_file():
        return None
    if (folder / "manifest.json").is_file():
        return dataclasses.replace(options, out=None, resume=folder)
    return dataclasses.replace(options, out=folder, resume=None)


def execute(
    scenario: Scenario,
    options: RunOptions,
    on_mapping: Callable[[float, float], None] | None = None,
    on_trial: Callable[[TrialRecord], None] | None = None,
    on_stage: Callable[[str, Any], None] | None = None,
    pool: Executor | None = None,
    on_jobs: Callable[[dict[str, int]], None] | None = None,
) -> RunDir:
    """Run (or resume) one run of one scenario with one seed; returns its folder (``execute_runs``
    with one plan; what the run raised is raised here)."""
    opened = pool is None
    pool = pool or open_executor(options.executor, options.workers, options.ray_address)
    try:
        [outcome] = execute_runs([RunPlan(scenario, options, RunHooks(on_stage, on_mapping, on_trial))], pool, on_jobs)
    finally:
        if opened:
            pool.close()
    if outcome.error is not None:
        raise outcome.error
    return outcome.value


def execute_runs(plans: list[RunPlan], pool: Executor, on_jobs: Callable[[dict[str, int]], None] | None = None) -> list[Outcome]:
    """Run (or resume) every plan on one executor, their jobs in flight together (``runners.driver``);
    an outcome per plan, in order: its ``RunDir`` as ``value``, or the ``error`` it failed with (the
    other runs went on). on_jobs({done, failed, running, queued}): the executor's jobs, all runs."""
    share = max(1, pool.slots // max(1, len(plans)))
    return drive([run_steps(plan.scenario, plan.options, plan.hooks, pool.slots, share) for plan in plans], pool, on_jobs)


def run_steps(scenario: Scenario, options: RunOptions, hooks: RunHooks, slots: int, share: int) -> Steps:
    """One run as steps (``runners.driver``): the folder and manifest, mapping, navigation once this
    run's maps are in, the summary; returns the ``RunDir``.

    slots: the executor's; share: the slots this run may count on (its mapping drives, at most one
    a system: fewer drives cost less when other runs fill the slots; see ``MappingJob``)."""
    say = hooks.on_stage or (lambda _stage, _value: None)
    with ExitStack() as held:  # the folder, for this driver alone (RunDir.hold)
        if options.resume is not None:
            run = RunDir(options.resume)
            held.enter_context(run.hold())
            manifest = Manifest.read(run.manifest_path)
            systems = list(manifest.systems)
            seed = manifest.seed
            trial_count = manifest.trial_count
            configs = manifest.config
            recorded = manifest.given("protocol")  # a manifest from before the protocol: exact initial poses
            protocol = TrialProtocol.from_json(recorded.as_json() if recorded is not None else None)
            setting_override = manifest.setting_override
            scenario = apply_setting(scenario, setting_override)
        else:
            systems = options.systems
            seed = scenario.spec.seed if options.seed is None else options.seed
            trial_count = len(scenario.trials) if options.trials is None else min(options.trials, len(scenario.trials))
            protocol = options.protocol
            setting_override = options.setting
            scenario = apply_setting(scenario, setting_override)
            configs = resolved_configs(systems, options.config_overrides, setting_of(scenario))
            run = new_run_dir(options, scenario, seed)
            run.root.mkdir(parents=True, exist_ok=True)
            held.enter_context(run.hold())
            manifest = new_manifest(scenario, systems, seed, setting_override, protocol, trial_count, configs)
            manifest.scenario_copy = keep_scenario(run, ScenarioFiles.of(scenario))
            write_json(run.manifest_path, manifest)
            if options.out is None:
                point_latest(run.root)
        say("run_dir", run.root)
        write_ground_truth(scenario, run.root, trial_count)  # what reports draw against (skipped if present)
        entries = {name: get_system(name) for name in systems}

        if options.maps_from is not None and options.resume is None:
            reuse_maps(options.maps_from, run, systems, manifest)

        files = ScenarioFiles.of(scenario)
        # stage 1: mapping, a job per drive (skipped for systems whose map and report are there)
        todo = [name for name in systems if not (run.mapping_path(name).is_file() and run.map_dir(name).is_dir())]
        if todo:
            say("mapping", todo)
            drives = min(share, len(todo))
            groups = [todo[k::drives] for k in range(drives)]
            jobs = [
                MappingJob(
                    files,
                    {name: configs[name] for name in group},
                    seed,
                    setting_override,
                    sorted({m for name in group for m in modules_of(entries[name])}),
                )
                for group in groups
            ]
            yield from map_systems(run, jobs, hooks.on_mapping)
        mapping = {name: MappingReport.read(run.mapping_path(name)) for name in systems}
        trials = TrialPlan(scenario, files, systems, configs, mapping, seed, trial_count, setting_override, protocol)
        yield from navigate(run, trials, options, slots, hooks.on_trial, say)
        if run.failed_stages:
            return run  # no summary: the run is unfinished, and --resume retries the stage
        write_summary(run, systems, mapping)
        say("done", run)
        return run


def keep_scenario(run: RunDir, files: ScenarioFiles) -> str:
    """The scenario file and the map files it reads, copied under ``<run>/scenario/`` as they were
    read: the folder alone reruns, resumes and reports on another machine. Its entry's path relative
    to the run folder (the manifest's ``scenario_copy``)."""
    return files.write(run.scenario_dir).relative_to(run.root).as_posix()


def new_manifest(
    scenario: Scenario,
    systems: list[str],
    seed: int,
    setting_override: str | None,
    protocol: TrialProtocol,
    trial_count: int | None,
    configs: dict[str, Any],
) -> Manifest:
    """What a new run is: its scenario (and the fingerprint a resume checks), systems, seed,
    setting, protocol, trial count and resolved configs; the versions, revision and machine it
    ran with, and when it started."""
    return Manifest(
        scenario=ScenarioInfo.model_validate({**scenario.summary(), "file": str(scenario.path.resolve())}),
        scenario_sha256=scenario_fingerprint(scenario),
        systems=systems,
        seed=seed,
        setting=setting_of(scenario),
        setting_override=setting_override,
        odometry_noise=scenario.spec.odometry.noise.model_dump() if scenario.spec.odometry.noise else None,
        range_noise=scenario.spec.sensor.range_noise,
        protocol=Protocol.model_validate(protocol.as_json()),
        trial_count=trial_count,
        config=configs,
        versions=versions(),
        git_revision=git_revision(),
        machine=machine(),
        created=dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
    )


def modules_of(entry: SystemEntry) -> list[str]:
    """The module a worker imports to know a system (one registered outside the runner, e.g. by a test)."""
    return [entry.cls.__module__]


def map_systems(run: RunDir, jobs: list[MappingJob], on_mapping: Callable[[float, float], None] | None) -> Steps:
    """Stage 1 as steps: the mapping jobs; the driver installs each map (whole, atomically) and then
    its report, so that a report on disk means a complete map beside it."""
    driven = {k: 0.0 for k in range(len(jobs))}
    mapped: set[str] = set()
    submit: list[Submission] = [(k, mapping_job, job) for k, job in enumerate(jobs)]
    running = len(jobs)
    while running:
        event = yield submit
        submit = []
        k, message = event.key, event.message
        if message is not None and message["kind"] == "progress":
            driven[k] = message["travelled_m"]
            if on_mapping is not None:
                on_mapping(min(driven.values()), message["route_m"])  # the slowest drive
        elif message is not None and message["kind"] == "mapped":
            driven[k] = float("inf")  # this job's drive is over: the bar follows the others
            if message["map"] is not None:
                install_dir(message["map"], run.map_dir(message["system"]))
            write_json(run.mapping_path(message["system"]), message["report"])  # a MappingReport
            mapped.add(message["system"])
        elif message is not None and message["kind"] == "route_error":
            raise RouteError(message["detail"])  # the driver ends this run's other jobs
        elif event.done:
            running -= 1
            if event.failure is not None:  # the job died or raised outside the systems' calls
                detail = f"{event.failure.kind}: {event.failure.detail}"
                for name in jobs[k].configs:
                    if name not in mapped:
                        report = MappingReport(error=detail, scans=None, map_bytes=None, map_disk_bytes=None)
                        write_json(run.mapping_path(name), report)


@dataclass
class TrialPlan:
    """What the navigation stage of a run needs to know of it."""

    scenario: Scenario
    files: ScenarioFiles
    systems: list[str]
    configs: dict[str, Any]
    mapping: dict[str, MappingReport]
    seed: int
    trial_count: int | None
    setting: str | None
    protocol: TrialProtocol


def navigate(
    run: RunDir,
    plan: TrialPlan,
    options: RunOptions,
    slots: int,
    on_trial: Callable[[TrialRecord], None] | None,
    say: Callable[[str, Any], None],
) -> Steps:
    """Stage 2 as steps: a system whose mapping failed is a failed stage (no trial of it runs or is
    recorded: a broken map is no navigation result); the others' trials run in chunks (``slots``
    a system), one job per chunk. A trial whose worker crashed or
    passed its wall-clock limit is recorded so (``crashed`` / ``timeout``) and the rest of its chunk
    runs in a new job. Each record names the worker that ran it (``worker``; None if none did)."""
    stage = NavigationStage(run, plan, options, on_trial)
    jobs = stage.jobs(slots)
    if not jobs:
        return
    say("navigation", sum(len(j.trials) for j in jobs))
    numbers = itertools.count()
    submit: list[Submission] = [((next(numbers), job), trial_job, job) for job in jobs]
    running = 0
    while submit or running:
        running += len(submit)
        event = yield submit
        submit = []
        number, job = event.key
        if event.message is not None:
            stage.on_message(number, job, event.message, event.worker)
            continue
        running -= 1
        retry = stage.on_end(number, job, event)
        if retry is not None:
            submit.append(((next(numbers), retry), trial_job, retry))


class NavigationStage:
    """The navigation stage of one run, as its jobs report: the trials done (on disk before, or
    recorded since), the trial each job started last, the failed stages."""

    def __init__(self, run: RunDir, plan: TrialPlan, options: RunOptions, on_trial: Callable[[TrialRecord], None] | None) -> None:
        self.run, self.plan, self.options, self.on_trial = run, plan, options, on_trial
        run.repair_trials()
        self.done = {(r.system, r.trial) for r in run.read_trials()}
        self.started: dict[int, int] = {}  # job number -> the trial it started last
        run.failed_stages = {}
        run.warnings = 0

    def jobs(self, slots: int) -> list[TrialJob]:
        """The trials not done yet of each system whose map is there, in chunks, a job each."""
        run, plan = self.run, self.plan
        for name in plan.systems:
            error = plan.mapping[name].error
            if error is not None:
                run.failed_stages[name] = ("mapping", error)
        jobs = []
        for name in plan.systems:
            pending = [i for i in range(plan.trial_count or 0) if (name, i) not in self.done]
            if not pending or name in run.failed_stages:
                continue
            chunks = [pending[k::slots] for k in range(slots)]
            archive = pack_dir(run.map_dir(name))
            for k, chunk in enumerate(c for c in chunks if c):
                jobs.append(
                    TrialJob(
                        scenario=plan.files,
                        system=name,
                        config=plan.configs[name],
                        map_archive=archive,
                        trials=chunk,
                        seed=plan.seed,
                        measure_memory=(k == 0 and not run.navigation_path(name).is_file()),
                        setting=plan.setting,
                        protocol=plan.protocol.as_json(),
                        anchors=plan.mapping[name].anchors,
                        trial_wall_s=self.options.trial_wall_s,
                        trial_memory_mb=self.options.trial_memory_mb,
                        modules=modules_of(get_system(name)),
                    )
                )
        return jobs

    def record(self, record: TrialRecord, worker: dict[str, Any] | None, message: dict[str, Any] | None = None) -> None:
        """A trial is done: its record (with its trajectories, from a ``trial`` message) written."""
        record.worker = worker
        if message is not None:
            write_trial(self.run, self.plan.scenario, message)
        else:
            self.run.append_trial(record)
        self.done.add((record.system, record.trial))
        self.run.warnings += record.failure_stage == FailureStage.RUNNER  # failed in its worker: an error, a crash, a limit
        if self.on_trial:
            self.on_trial(record)

    def failed(self, system: str, index: int, reason: str, detail: str) -> TrialRecord:
        """The record of a trial its worker did not finish (the worker crashed, or ran out of time)."""
        trial = self.plan.scenario.trials[index]
        stage = FailureStage.RUNNER.value
        return trial_record(
            system, index, trial, self.plan.seed, success=False, reason=reason, detail=detail[:300], failure_stage=stage
        )

    def on_message(self, number: int, job: TrialJob, message: dict[str, Any], worker: dict[str, Any] | None) -> None:
        if message["kind"] == "started":
            self.started[number] = message["trial"]
        elif message["kind"] == "trial":
            self.record(message["record"], worker, message)
        elif message["kind"] == "memory":
            write_json(self.run.navigation_path(job.system), message["report"])
        elif message["kind"] == "map_load_error":  # no trial ran: a failed stage, not failed trials
            why = f"the map in {self.run.map_dir(job.system)} cannot be loaded: {message['detail']}"
            self.run.failed_stages.setdefault(job.system, ("navigation", why))

    def on_end(self, number: int, job: TrialJob, event: Event) -> TrialJob | None:
        """A job ended: if it failed, the trial it was running is recorded as failed and the rest of
        its trials come back as a new job (returned)."""
        unrun = [i for i in job.trials if (job.system, i) not in self.done]
        if event.failure is None or not unrun or job.system in self.run.failed_stages:
            return None
        kind, detail = event.failure.kind, event.failure.detail
        if kind == "error":  # the job raised outside a trial (trials catch their own): its trials fail
            for index in unrun:
                self.record(self.failed(job.system, index, "error", detail), event.worker)
            return None
        # crashed or timeout: the trial that was running fails; if the worker died before its first
        # trial, that first trial fails (so that a job that cannot start does not come back for
        # ever); between two trials, no trial is to blame. The rest runs in a fresh process.
        current = self.started.get(number)
        culprit = current if current in unrun else (unrun[0] if current is None else None)
        if culprit is not None:
            if kind == "crashed" and self.options.trial_memory_mb is not None:
                detail += f" (under --trial-memory-mb {self.options.trial_memory_mb:g}: perhaps out of memory)"
            self.record(self.failed(job.system, culprit, kind, detail), event.worker)
        rest = [i for i in unrun if i != culprit]
        return dataclasses.replace(job, trials=rest) if rest else None


class MapsFromError(BenchError):
    """--maps-from names a run whose maps cannot serve this one."""

    exit_code = 2  # an input refused


def check_maps_from(source: Path, scenario: Scenario, seed: int, setting: str, systems: list[str]) -> None:
    """Refuse a source run of another scenario (file), seed or setting, or without a system's map."""
    try:
        manifest = Manifest.read(source / "manifest.json")
    except RunFormatError as exc:
        raise MapsFromError(str(exc)) from None  # names the file and why
    if manifest.scenario_sha256 != scenario_fingerprint(scenario):
        raise MapsFromError(f"{source}: mapped another scenario (or the scenario file changed since)")
    mapped_in = manifest.given("setting", "precise")  # runs from before the settings were precise
    if manifest.seed != seed or mapped_in != setting:
        raise MapsFromError(
            f"{source}: mapped with seed {manifest.seed} in setting {manifest.setting}, not seed {seed} in setting {setting}"
        )
    for name in systems:
        report = source / "mapping" / f"{name}.json"
        if not report.is_file() or not (source / "maps" / name).is_dir():
            raise MapsFromError(f"{source}: holds no map of {name!r} (mapping/{name}.json or maps/{name} missing)")


def reuse_maps(source: Path, run: RunDir, systems: list[str], manifest: Manifest) -> None:
    """Copy the maps and mapping reports of ``source`` into ``run`` (its mapping stage then skips
    them); both say where they came from (``maps_from``)."""
    for name in systems:
        shutil.copytree(source / "maps" / name, run.map_dir(name), dirs_exist_ok=True)
        report = MappingReport.read(source / "mapping" / f"{name}.json")
        report.maps_from = str(source)
        write_json(run.mapping_path(name), report)
    manifest.maps_from = str(source)
    write_json(run.manifest_path, manifest)


def write_summary(run: RunDir, systems: list[str], mapping: dict[str, MappingReport]) -> dict[str, SystemSummary]:
    records = run.read_trials()
    reports = {name: run.navigation_path(name) for name in systems}
    navigation = {name: NavigationReport.read(path) for name, path in reports.items() if path.is_file()}
    summary = summarize(records, mapping, navigation)
    summary = {name: summary.get(name, SystemSummary()) for name in systems}
    write_json(run.summary_path, summary)
    return summary
