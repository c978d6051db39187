"""One benchmark run: mapping, then navigation trials, then the summary (the `run` command)."""

from __future__ import annotations

import datetime as dt
import hashlib
import os
import platform
import shutil
import socket
import subprocess
from collections.abc import Callable
from concurrent.futures.process import BrokenProcessPool
from contextlib import closing
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

import psutil

from runners.executors import run_jobs
from runners.ground_truth import write_ground_truth
from runners.mapping import MappingSystem, run_mapping
from runners.metrics import summarize, trial_record
from runners.navigation import MapLoadError, TrialJob, run_trial_job
from runners.protocol import TrialProtocol, apply_setting, setting_of
from runners.results import RunDir, TrialsTail, point_latest, read_json, write_json
from runners.systems import get_system
from scenarios import Scenario

PACKAGES = ["numpy", "scipy", "torch", "kiss-icp", "gtsam", "pybullet", "numba", "shapely", "opencv-python-headless", "pydantic"]


@dataclass
class RunOptions:
    systems: list[str]
    trials: int | None = None  # first N trials; None = all; 0 = mapping only
    seed: int | None = None
    out: Path | None = None
    resume: Path | None = None
    workers: int = 1
    executor: str = "local"
    ray_address: str | None = None
    results_root: Path = Path("results")
    config_overrides: dict[str, Any] | None = None  # {system: {key: value, ...}} merged over the defaults
    setting: str | None = None  # runners.protocol.SETTINGS name; None: the scenario file's own noise
    maps_from: Path | None = None  # reuse the maps of this earlier run of the same scenario, seed and setting
    protocol: TrialProtocol = field(default_factory=TrialProtocol)


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
    digest = hashlib.sha256(scenario.path.read_bytes())
    if scenario.spec.world.map is not None:
        map_yaml = scenario.path.parent / scenario.spec.world.map.yaml
        digest.update(map_yaml.read_bytes())
        for line in map_yaml.read_text().splitlines():
            if line.strip().startswith("image:"):
                image = map_yaml.parent / line.split(":", 1)[1].strip()
                if image.is_file():
                    digest.update(image.read_bytes())
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


def execute(
    scenario: Scenario,
    options: RunOptions,
    on_mapping: Callable[[float, float], None] | None = None,
    on_trial: Callable[[dict[str, Any]], None] | None = None,
    on_stage: Callable[[str, Any], None] | None = None,
) -> RunDir:
    """Run (or resume) one run of one scenario with one seed; returns its folder.

    on_stage(stage, value): ("run_dir", Path), ("mapping", [systems]), ("navigation", trial count).
    """
    say = on_stage or (lambda _stage, _value: None)
    if options.resume is not None:
        run = RunDir(options.resume)
        manifest = read_json(run.manifest_path)
        systems = list(manifest["systems"])
        seed = int(manifest["seed"])
        trial_count = manifest.get("trial_count")
        configs = manifest["config"]
        protocol = TrialProtocol.from_json(manifest.get("protocol"))
        setting_override = manifest.get("setting_override")
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
        write_json(
            run.manifest_path,
            {
                "scenario": {**scenario.summary(), "file": str(scenario.path.resolve())},
                "scenario_sha256": scenario_fingerprint(scenario),
                "systems": systems,
                "seed": seed,
                "setting": setting_of(scenario),
                "setting_override": setting_override,
                "odometry_noise": scenario.spec.odometry.noise.model_dump() if scenario.spec.odometry.noise else None,
                "range_noise": scenario.spec.sensor.range_noise,
                "protocol": protocol.as_json(),
                "trial_count": trial_count,
                "config": configs,
                "versions": versions(),
                "git_revision": git_revision(),
                "machine": machine(),
                "created": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            },
        )
        if options.out is None:
            point_latest(run.root)
    say("run_dir", run.root)
    write_ground_truth(scenario, run.root, trial_count)  # what reports draw against (skipped if present)
    entries = {name: get_system(name) for name in systems}

    if options.maps_from is not None and options.resume is None:
        reuse_maps(options.maps_from, run, systems, manifest_of_run=read_json(run.manifest_path))

    # stage 1: mapping (skipped for systems whose map and report are already there)
    todo = [name for name in systems if not (run.mapping_path(name).is_file() and run.map_dir(name).is_dir())]
    if todo:
        say("mapping", todo)
        run_mapping(
            scenario,
            [MappingSystem(entries[n], entries[n].config_model.model_validate(configs[n])) for n in todo],
            run,
            seed,
            on_mapping,
        )
    mapping = {name: read_json(run.mapping_path(name)) for name in systems}

    # stage 2: navigation (a system whose mapping failed fails its trials with that reason)
    run.repair_trials()
    done = {(r["system"], r["trial"]) for r in run.read_trials()}
    for name in systems:
        if "error" in mapping[name]:
            for i in range(trial_count or 0):
                if (name, i) not in done:
                    reason = f"error: mapping failed: {mapping[name]['error']}"[:300]
                    run.append_trial(trial_record(name, i, scenario.trials[i], seed, success=False, reason=reason))
                    done.add((name, i))
    jobs = []
    for name in systems:
        pending = [i for i in range(trial_count or 0) if (name, i) not in done]
        if not pending:
            continue
        chunks = [pending[k :: options.workers] for k in range(options.workers)] if options.workers > 1 else [pending]
        for k, chunk in enumerate(c for c in chunks if c):
            jobs.append(
                TrialJob(
                    scenario=str(scenario.path.resolve()),
                    system=name,
                    config=configs[name],
                    map_dir=str(run.map_dir(name).resolve()),
                    trials=chunk,
                    seed=seed,
                    run_dir=str(run.root.resolve()),
                    measure_memory=(k == 0 and not (run.root / "navigation" / f"{name}.json").is_file()),
                    setting=setting_override,
                    protocol=protocol.as_json(),
                    anchors=mapping[name].get("anchors"),
                )
            )
    run.incomplete = []
    run.failed_stages = {}
    if jobs:
        say("navigation", sum(len(j.trials) for j in jobs))
        tail = TrialsTail(run, skip=done)

        def poll() -> None:
            for record in tail.new_records():
                if on_trial:
                    on_trial(record)

        jobs_run = run_jobs(run_trial_job, jobs, options.workers, options.executor, options.ray_address, on_poll=poll)
        with closing(jobs_run):  # Ctrl-C in this loop also cancels the queued jobs and ends the workers
            for job, _result, error in jobs_run:
                poll()
                if error is None:
                    continue
                if isinstance(error, MapLoadError):  # no trial ran: a failed stage, not failed trials
                    run.failed_stages.setdefault(job.system, str(error))
                    continue
                recorded = {r["trial"] for r in run.read_trials() if r["system"] == job.system}
                unrun = [i for i in job.trials if i not in recorded]
                if isinstance(error, BrokenProcessPool):
                    # the worker died (killed, out of memory) inside the first unrecorded trial: that
                    # trial fails with the reason; the others stay unrun for --resume
                    failed, left = unrun[:1], unrun[1:]
                    reason = "error: worker process died"
                else:
                    # the system raised (a bug, not a lost process): the job's unrecorded trials fail
                    failed, left = unrun, []
                    reason = f"error: {type(error).__name__}: {error}".splitlines()[0][:300]
                for index in failed:
                    run.append_trial(trial_record(job.system, index, scenario.trials[index], seed, success=False, reason=reason))
                run.incomplete.extend((job.system, i) for i in left)
                poll()
    if run.failed_stages:
        return run  # no summary: the run is unfinished, and --resume retries the stage
    write_summary(run, systems, mapping)
    return run


class MapsFromError(ValueError):
    """--maps-from names a run whose maps cannot serve this one."""


def check_maps_from(source: Path, scenario: Scenario, seed: int, setting: str, systems: list[str]) -> None:
    """Refuse a source run of another scenario (file), seed or setting, or without a system's map."""
    manifest_path = source / "manifest.json"
    try:
        manifest = read_json(manifest_path)
    except (OSError, ValueError) as exc:
        raise MapsFromError(f"{manifest_path}: not a readable run manifest ({exc})") from None
    if not isinstance(manifest, dict):
        raise MapsFromError(f"{manifest_path}: not a run manifest")
    if manifest.get("scenario_sha256") != scenario_fingerprint(scenario):
        raise MapsFromError(f"{source}: mapped another scenario (or the scenario file changed since)")
    if manifest.get("seed") != seed or manifest.get("setting", "precise") != setting:
        raise MapsFromError(
            f"{source}: mapped with seed {manifest.get('seed')} in setting {manifest.get('setting')}, "
            f"not seed {seed} in setting {setting}"
        )
    for name in systems:
        report = source / "mapping" / f"{name}.json"
        if not report.is_file() or not (source / "maps" / name).is_dir():
            raise MapsFromError(f"{source}: holds no map of {name!r} (mapping/{name}.json or maps/{name} missing)")


def reuse_maps(source: Path, run: RunDir, systems: list[str], manifest_of_run: dict[str, Any]) -> None:
    """Copy the maps and mapping reports of ``source`` into ``run`` (its mapping stage then skips them)."""
    for name in systems:
        shutil.copytree(source / "maps" / name, run.map_dir(name), dirs_exist_ok=True)
        report = read_json(source / "mapping" / f"{name}.json")
        report["maps_from"] = str(source)
        write_json(run.mapping_path(name), report)
    write_json(run.manifest_path, {**manifest_of_run, "maps_from": str(source)})


def write_summary(run: RunDir, systems: list[str], mapping: dict[str, dict]) -> dict[str, Any]:
    records = run.read_trials()
    navigation = {}
    for name in systems:
        nav_path = run.root / "navigation" / f"{name}.json"
        navigation[name] = read_json(nav_path) if nav_path.is_file() else {}
    summary = summarize(records, mapping, navigation)
    summary = {name: summary.get(name, {}) for name in systems}
    write_json(run.summary_path, summary)
    return summary
