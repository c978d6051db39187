"""What `navtopo-bench run` does with a ``RunRequest``: new runs, a resume, or a suite's runs.

Each shape reads its files (the scenarios, a ``--config``, the suite file, the manifest of a run
folder) and refuses in one line what it cannot use, before any folder is made or ``latest``
moves; then every run of the command goes on one executor, its jobs in flight together
(``runners.commands.progress.run_with_progress``).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from runners.commands.checks import open_scenario, writable_dir
from runners.commands.console import err, note
from runners.commands.errors import Refused
from runners.commands.jobs import executor_for
from runners.commands.progress import run_with_progress
from runners.commands.request import RunRequest
from runners.commands.resume import read_resumable

if TYPE_CHECKING:
    from scenarios import Scenario


def start_runs(request: RunRequest) -> None:
    """The runs ``request`` asks, to their end (or one line why not)."""
    if request.suite is not None:
        out = request.out if request.out is not None else request.results / request.suite.stem
        run_suite(request.suite, out, request)
    elif request.resume is not None:
        resume_run(request.resume, request)
    else:
        new_runs(request)


def new_runs(request: RunRequest) -> None:
    """One run per scenario x setting x seed, each into a new folder (``--out``, or a folder of its
    own under ``--results``)."""
    from runners.run import RunOptions

    out = request.out
    if out is not None:
        if out.exists() and not out.is_dir():
            raise Refused(f"--out {out}: is a file, not a folder")
        writable_dir(out, "--out")
    else:
        writable_dir(request.results, "--results")
    names = request.system_list
    overrides = read_overrides(request.config_file, names) if request.config_file is not None else None
    loaded = [open_scenario(name) for name in request.scenarios]
    for scenario in loaded:  # more trials than a scene lists: refused, never silently capped
        if request.trials is not None and request.trials > len(scenario.trials):
            raise Refused(
                f"--trials {request.trials}: {scenario.path} lists {len(scenario.trials)} trials; "
                f"ask for at most {len(scenario.trials)}, or add trials to the scenario file"
            )
    if request.maps_from is not None:
        check_maps_from(request, loaded[0])
    todo = [
        (
            scenario,
            RunOptions(
                systems=names,
                trials=request.trials,
                seed=seed,
                out=out,
                config_overrides=overrides,
                setting=setting,
                maps_from=request.maps_from,
                **request.shared_options(),
            ),
        )
        for scenario in loaded
        for setting in request.setting_list
        for seed in request.seed_list
    ]
    with executor_for(todo[0][1]) as pool:
        run_with_progress(todo, pool)


def check_maps_from(request: RunRequest, scenario: Scenario) -> None:
    """The run named by ``--maps-from`` must have mapped this scenario, seed and setting."""
    from runners.protocol import apply_setting, setting_of
    from runners.run import MapsFromError
    from runners.run import check_maps_from as check

    assert request.maps_from is not None
    scenario = apply_setting(scenario, request.setting_list[0])
    seed = request.seed_list[0]
    seed = scenario.spec.seed if seed is None else seed
    try:
        check(request.maps_from, scenario, seed, setting_of(scenario), request.system_list)
    except MapsFromError as exc:  # not a BenchError yet (runners/run.py)
        raise Refused(str(exc)) from None


def resume_run(folder: Path, request: RunRequest) -> None:
    """Finish the run in ``folder`` as its manifest says: its scenario (unchanged since), systems,
    seed, setting, protocol and configs; flags that would change them are ignored, with a note."""
    from runners.run import RunOptions, scenario_fingerprint
    from runners.systems import system_names

    manifest = read_resumable(folder, system_names())
    stored = manifest.scenario
    if request.scenarios and request.scenarios[0] not in (stored.name, stored.file):
        raise Refused(f"{folder}: holds a run of {stored.name!r}, not {request.scenarios[0]!r}")
    file = stored.file
    copy = folder / manifest.scenario_copy if manifest.scenario_copy else None
    if copy is not None and copy.is_file() and not (file and Path(file).is_file()):
        note(f"{file}: not here; the run's own copy is read: {copy}")
        file = str(copy)
    scenario = open_scenario(file)
    if manifest.scenario_sha256 not in (None, scenario_fingerprint(scenario)):
        raise Refused(f"{stored.file}: changed since the run started (sha256 differs from {folder}/manifest.json)")
    if ignored := request.ignored_by_resume:
        err.print(f"note: {', '.join(ignored)} ignored with --resume (the run's manifest decides)", highlight=False)
    options = RunOptions(
        systems=manifest.systems,
        resume=folder,
        workers=request.workers,
        executor=request.executor,
        ray_address=request.ray_address,
        trial_wall_s=request.trial_timeout_s,
        trial_memory_mb=request.trial_memory_mb,
    )
    with executor_for(options) as pool:
        run_with_progress([(scenario, options)], pool)


def run_suite(path: Path, out: Path, request: RunRequest) -> None:
    """The runs of a suite file, each in its folder under ``out``: a finished one kept, a started
    one resumed (the same command again finishes the suite), the others made; all on one executor."""
    from runners.run import RunOptions, in_folder, scenario_fingerprint
    from runners.suite import read_suite
    from runners.systems import system_names

    runs = read_suite(path)
    if out.exists() and not out.is_dir():
        raise Refused(f"--out {out}: is a file, not a folder")
    if (out / "manifest.json").exists():
        raise Refused(f"--out {out}: holds a run, not the runs of a suite; give another --out")
    writable_dir(out, "--out")
    names = sorted({name for run in runs for name in run.systems})
    overrides = read_overrides(request.config_file, names) if request.config_file is not None else None
    todo = []
    for run in runs:
        options = RunOptions(
            systems=run.systems,
            trials=run.trials,
            seed=run.seed,
            setting=run.setting,
            config_overrides=overrides,
            **request.shared_options(),
        )
        kept = in_folder(out / run.folder, options)
        if kept is None:
            note(f"{out / run.folder}: finished before; kept")
            continue
        if kept.resume is not None and read_resumable(kept.resume, system_names()).scenario_sha256 not in (
            None,
            scenario_fingerprint(run.scenario),
        ):
            raise Refused(f"{run.scenario.path}: changed since {kept.resume} started (sha256 differs from its manifest.json)")
        todo.append((run.scenario, kept))
    if todo:
        with executor_for(todo[0][1]) as pool:
            run_with_progress(todo, pool, again=f"run the same command again to finish the suite in {out}")


def read_overrides(path: Path, names: list[str]) -> dict[str, Any]:
    """``--config``: a YAML mapping {system: {key: value}} of this run's systems, each merged over
    the defaults and validated by the system's config model before any run starts."""
    from pydantic import ValidationError

    from runners.run import resolved_configs
    from scenarios import ScenarioError
    from scenarios.schema import read_yaml

    try:
        data = read_yaml(path)
    except ScenarioError as exc:
        raise Refused(f"--config {exc}") from None
    if not isinstance(data, dict):
        raise Refused(f"--config {path}: expected a mapping of system names to settings")
    for name, value in data.items():
        if name not in names:
            raise Refused(f"--config {path}: {name}: not one of the systems of this run ({', '.join(names)})")
        if value is not None and not isinstance(value, dict):
            raise Refused(f"--config {path}: {name}: expected a mapping of settings")
    for name in data:
        try:
            resolved_configs([name], data)
        except ValidationError as exc:
            first = exc.errors()[0]
            key = ".".join(str(p) for p in first["loc"])
            raise Refused(f"--config {path}: {name}.{key}: {first['msg'].removeprefix('Value error, ')}") from None
    return data
