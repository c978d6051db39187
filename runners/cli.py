"""The `navtopo-bench` command (DESIGN.md, "Contracts: the command line")."""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
from pathlib import Path
from typing import Annotated, NoReturn

import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

# the heavy modules (scenarios: scipy, shapely, numba; the systems: torch) are imported inside the
# commands that need them, so that `--help` and argument errors answer at once

app = typer.Typer(
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
scenario_app = typer.Typer(help="List, inspect, validate and draw scenarios.", no_args_is_help=True)
app.add_typer(scenario_app, name="scenario")


def _flag_type_shown(display_type_rich):
    """Typer's help panels give every option a type label, a flag too (`--help <bool>`, `--json
    <bool>`): a flag takes no value, so it gets none, as in click's own help."""

    def shown(self, ctx):
        return None if getattr(self, "is_flag", False) else display_type_rich(self, ctx)

    return shown


if hasattr(typer.core.TyperOption, "display_type_rich"):
    typer.core.TyperOption.display_type_rich = _flag_type_shown(typer.core.TyperOption.display_type_rich)
console = Console(width=None if sys.stdout.isatty() else 160)
err = Console(stderr=True, width=None if sys.stderr.isatty() else 200)


# the executor options of `run` and `sweep`
WorkersOption = Annotated[
    int | None, typer.Option(help="jobs at once (default: the cores; with --executor ray: the cluster's CPUs)", min=1)
]
ExecutorOption = Annotated[str, typer.Option(help="where jobs run: local (a fresh process each) or ray")]
RayAddressOption = Annotated[
    str | None, typer.Option(help="with --executor ray: auto or HOST:PORT of a running cluster (default: a private one)")
]


def fail(message: str, code: int = 2) -> NoReturn:
    error_line(message)
    raise typer.Exit(code)


def error_line(message: str) -> None:
    err.print(f"[bold red]error:[/] {escape(one_line(message))}", highlight=False, soft_wrap=True)


def note(message: str) -> None:
    err.print(f"note: {escape(one_line(message))}", highlight=False, soft_wrap=True)


def one_line(message: str) -> str:
    return " ".join(str(message).split("\n")).strip()


def _version(value: bool) -> None:
    if value:
        from importlib import metadata

        try:
            version = metadata.version("navtopo-bench")
        except metadata.PackageNotFoundError:
            version = "unknown (not installed)"
        console.print(f"navtopo-bench {version}", highlight=False)
        raise typer.Exit()


@app.callback()
def _main(
    version: Annotated[
        bool, typer.Option("--version", help="print the version and exit", callback=_version, is_eager=True)
    ] = False,
) -> None:
    """navtopo-bench: topological (NavTopo) vs metric-SLAM navigation, one PyBullet scenario runner."""
    # a file name that is not UTF-8 (a folder named in Latin-1) is printed as its own bytes, as ls
    # and Python in the C locale print it, instead of failing every line that names it
    for stream in (sys.stdout, sys.stderr):
        if hasattr(stream, "reconfigure"):
            stream.reconfigure(errors="surrogateescape")


def _load(name: str, with_trials: bool = True, quiet: bool = False):
    from scenarios import ScenarioError, load_scenario

    try:
        scenario = load_scenario(name, with_trials=with_trials)
    except ScenarioError as exc:
        fail(str(exc))
    except Exception as exc:  # noqa: BLE001 - a bug or an odd file: still one line, naming the file
        fail(f"{name}: cannot be loaded: {type(exc).__name__}: {exc}")
    if not quiet:
        for line in scenario.notes:
            note(line)
    return scenario


def writable_file(path: Path, option: str, suffixes: tuple[str, ...] | None = None) -> Path:
    """Refuse (one line) an output file that cannot be written, before any work is done."""
    if suffixes is not None and path.suffix.lower() not in suffixes:
        fail(f"{option} {path}: the file name must end in {' or '.join(suffixes)}")
    if path.is_dir():
        fail(f"{option} {path}: is a folder; give a file name")
    writable_dir(path.parent, option, named=path)
    return path


def writable_dir(path: Path, option: str, named: Path | None = None) -> Path:
    """Refuse a folder that cannot be made or written (an ancestor that is a file, no permission);
    the message names ``named`` (default: the folder)."""
    import os

    probe = Path(path)
    while not probe.exists():
        if probe.parent == probe:
            break
        probe = probe.parent
    named = path if named is None else named
    if probe.exists() and not probe.is_dir():
        fail(f"{option} {named}: {probe} is a file, not a folder")
    if probe.exists() and not os.access(probe, os.W_OK | os.X_OK):
        fail(f"{option} {named}: {probe} is not writable")
    if probe.is_dir():
        # os.access says yes to root everywhere: a read-only mount or /sys answers only a real write
        # (an unnamed file where the system has them, else one removed at once: nothing is left)
        import tempfile

        try:
            with tempfile.TemporaryFile(dir=probe):
                pass
        except OSError as exc:
            fail(f"{option} {named}: {probe} is not writable ({exc.strerror or exc})")
    return path


# ---------------------------------------------------------------------------------------------
# run


@app.command()
def run(
    scenarios: Annotated[
        list[str] | None, typer.Argument(help="bundled scenario names or YAML files (with --resume: the run's own)")
    ] = None,
    systems: Annotated[str, typer.Option(help="comma-separated systems (see `config`)")] = "navtopo,metric_grid,oracle",
    trials: Annotated[int | None, typer.Option(help="run the first N trials (0: mapping only)", min=0)] = None,
    seed: Annotated[int | None, typer.Option(help="seed of sensor and odometry noise (default: the scenario's)")] = None,
    seeds: Annotated[str | None, typer.Option(help="comma-separated seeds: one run per seed")] = None,
    out: Annotated[Path | None, typer.Option(help="results folder (default results/<scenario>/<run-id>)")] = None,
    resume: Annotated[Path | None, typer.Option(help="finish an interrupted run folder")] = None,
    workers: WorkersOption = None,
    executor: ExecutorOption = "local",
    ray_address: RayAddressOption = None,
    trial_timeout: Annotated[
        float,
        typer.Option(
            "--trial-timeout-s", help="wall-clock limit of one trial (at least 1; inf: none): its worker is killed past it"
        ),
    ] = 3600.0,
    trial_memory_mb: Annotated[
        float | None,
        typer.Option(help="address space a trial may add (RLIMIT_AS; at least 1): past it the trial is out_of_memory"),
    ] = None,
    results: Annotated[Path, typer.Option(help="root of the results folders")] = Path("results"),
    config_file: Annotated[
        Path | None, typer.Option("--config", help="YAML {system: {key: value}} merged over the defaults (see `config`)")
    ] = None,
    setting: Annotated[
        str | None,
        typer.Option(
            help="precise (exact odometry) or noisy (odometry 2 %, 0.5°/m; lidar range noise 1 cm); "
            "comma-separated for one run each (default: the scenario file's own noise)"
        ),
    ] = None,
    initial_pose_error: Annotated[
        str,
        typer.Option(help="XY_M,YAW_DEG: uniform error of the initial pose given to systems that take one (0,0: exact)"),
    ] = "0.5,10",
    stop_tolerance: Annotated[
        float,
        typer.Option(
            help="m (0.01 to 0.5, the runner's STOP rule): systems that stop by their own estimate stop this close to the goal"
        ),
    ] = 0.35,
    goals: Annotated[
        str,
        typer.Option(
            help="map: goals as map-frame points for every system; native: graph systems get the paper's "
            "(location, pose in it) form (the same as map with precise odometry)"
        ),
    ] = "map",
    maps_from: Annotated[
        Path | None,
        typer.Option(help="reuse the maps of an earlier run (same scenario, seed, setting): navigation trials only"),
    ] = None,
    suite: Annotated[
        Path | None,
        typer.Option(
            help="a suite file listing the runs (scenarios, seeds, settings, systems, trials; docs/DESIGN.md): "
            "a folder per run under --out (default <results>/<suite name>); the same command again finishes them"
        ),
    ] = None,
) -> None:
    """Map each scenario's route with every system, then run the navigation trials.

    Several scenarios, seeds or settings (or a --suite file) make one run each, all on one
    executor with their jobs in flight together.

    The protocol is the same for every system (docs/DESIGN.md): systems that take an initial pose
    get the trial's start with a seeded error (--initial-pose-error), and every system that
    declares "reached" by its own estimate stops within --stop-tolerance of the goal; success is
    the robot's true position within 0.5 m of the goal when it stops.
    """
    from runners.run import RunOptions, scenario_fingerprint
    from runners.systems import system_names

    _check_executor(executor, ray_address, workers)
    limits = {"trial_wall_s": trial_timeout, "trial_memory_mb": trial_memory_mb}
    known = system_names()
    names = _systems_option(systems) if resume is None else []  # a resume runs the manifest's systems
    from runners.protocol import SETTINGS, TrialProtocol

    setting_list: list[str | None] = [None]
    if setting is not None:
        setting_list = [x.strip() for x in setting.split(",") if x.strip()]
        bad = [x for x in setting_list if x not in SETTINGS]
        if bad or not setting_list:
            fail(f"--setting: unknown setting {', '.join(bad) or repr(setting)} (choose from {', '.join(SETTINGS)})")
        once_each("--setting", setting, setting_list, "a setting is named twice (the same run twice)")
    try:
        error_xy, error_yaw = (float(v) for v in initial_pose_error.split(","))
        if not (0 <= error_xy < math.inf and 0 <= error_yaw < math.inf):
            raise ValueError
    except ValueError:
        fail(f"--initial-pose-error: expected two non-negative numbers XY_M,YAW_DEG, got {initial_pose_error!r}")
    from runners.metrics import GOAL_TOLERANCE_M

    # a system stopping farther out than the runner's STOP rule would fail every trial
    check_number("--stop-tolerance", stop_tolerance, "metres", low=0.01, high=GOAL_TOLERANCE_M)
    check_number("--trial-timeout-s", trial_timeout, "seconds", low=1.0, finite=False)
    check_number("--trial-memory-mb", trial_memory_mb, "MB", low=1.0, high=MAX_TRIAL_MEMORY_MB)
    if goals not in ("map", "native"):
        fail(f"--goals: {goals!r} is not map or native")
    protocol = TrialProtocol(
        initial_pose_error_xy=error_xy, initial_pose_error_yaw_deg=error_yaw, stop_tolerance=stop_tolerance, goals=goals
    )
    seed_list: list[int | None] = [seed]
    if seeds:
        try:
            seed_list = [int(s) for s in seeds.split(",") if s.strip()]
        except ValueError:
            fail(f"--seeds: not a list of integers: {seeds!r}")
        if not seed_list:
            fail(f"--seeds {seeds!r}: give at least one seed")
        once_each("--seeds", seeds, seed_list, "a seed is given twice (the same run twice)")
    for flag, value in [("--seed", seed)] + [("--seeds", s) for s in seed_list]:
        if value is not None and value < 0:
            fail(f"{flag} {value}: a seed is a non-negative integer")
    scenarios = list(scenarios or [])
    common = {
        "workers": workers,
        "executor": executor,
        "ray_address": ray_address,
        "results_root": results,
        "protocol": protocol,
        **limits,
    }
    if suite is not None:
        given = [
            flag
            for flag, value in (
                ("SCENARIO", bool(scenarios)),
                ("--systems", systems != "navtopo,metric_grid,oracle"),
                ("--trials", trials is not None),
                ("--seed", seed is not None),
                ("--seeds", seeds is not None),
                ("--setting", setting is not None),
                ("--resume", resume is not None),
                ("--maps-from", maps_from is not None),
            )
            if value
        ]
        if given:
            fail(f"--suite {suite}: {', '.join(given)}: the suite file lists the runs; give these there, not here")
        _run_suite(suite, out if out is not None else results / suite.stem, config_file, common)
        return
    if resume is not None:
        if not (resume / "manifest.json").is_file():
            fail(f"{resume}: not a run folder (manifest.json missing)")
        if len(seed_list) > 1 or len(scenarios) > 1:
            fail("--resume finishes one run folder: give at most its scenario and no --seeds")
        manifest = _read_manifest(resume, known)
        stored = manifest["scenario"]
        if scenarios and scenarios[0] not in (stored["name"], stored["file"]):
            fail(f"{resume}: holds a run of {stored['name']!r}, not {scenarios[0]!r}")
        scenario = _load(stored["file"])
        if manifest.get("scenario_sha256") not in (None, scenario_fingerprint(scenario)):
            fail(f"{stored['file']}: changed since the run started (sha256 differs from {resume}/manifest.json)")
        ignored = [
            flag
            for flag, value in (
                ("--systems", systems != "navtopo,metric_grid,oracle"),
                ("--trials", trials is not None),
                ("--seed", seed is not None),
                ("--config", config_file is not None),
                ("--setting", setting is not None),
                ("--initial-pose-error", initial_pose_error != "0.5,10"),
                ("--stop-tolerance", stop_tolerance != 0.35),
                ("--goals", goals != "map"),
            )
            if value
        ]
        if ignored:
            err.print(f"note: {', '.join(ignored)} ignored with --resume (the run's manifest decides)", highlight=False)
        options = RunOptions(
            systems=manifest["systems"], resume=resume, workers=workers, executor=executor, ray_address=ray_address, **limits
        )
        with _executor(options) as pool:
            _run_all([(scenario, options)], pool)
        return
    if not scenarios:
        fail("give at least one SCENARIO (see `navtopo-bench scenario list`)")
    if out is not None and resume is None and (out / "manifest.json").exists():
        fail(f"{out}: already holds a run; use --resume {out} to finish it, or another --out")
    if out is not None and (len(scenarios) > 1 or len(seed_list) > 1 or len(setting_list) > 1):
        fail("--out takes one scenario, one seed and one setting; leave it out to get a folder per run")
    if out is not None:
        if out.exists() and not out.is_dir():
            fail(f"--out {out}: is a file, not a folder")
        writable_dir(out, "--out")
    else:
        writable_dir(results, "--results")
    overrides = _read_overrides(config_file, names) if config_file is not None else None
    loaded = []
    for name in scenarios:
        loaded.append(_load(name))
    if maps_from is not None:
        from runners.protocol import apply_setting, setting_of
        from runners.run import MapsFromError, check_maps_from

        if len(loaded) > 1 or len(seed_list) > 1 or len(setting_list) > 1:
            fail("--maps-from serves one scenario, one seed and one setting")
        if trials == 0:
            fail("--trials 0 with --maps-from would run nothing: the maps are there already")
        scenario = apply_setting(loaded[0], setting_list[0])
        try:
            check_maps_from(
                maps_from, scenario, scenario.spec.seed if seed_list[0] is None else seed_list[0], setting_of(scenario), names
            )
        except MapsFromError as exc:
            fail(str(exc))
    todo = [
        (
            scenario,
            RunOptions(
                systems=names,
                trials=trials,
                seed=s,
                out=out,
                config_overrides=overrides,
                setting=setting_name,
                maps_from=maps_from,
                **common,
            ),
        )
        for scenario in loaded
        for setting_name in setting_list
        for s in seed_list
    ]
    with _executor(todo[0][1]) as pool:
        _run_all(todo, pool)


MAX_TRIAL_MEMORY_MB = 1e9  # 1 PB: RLIMIT_AS counts bytes in 63 bits, and no machine has more


def check_number(flag: str, value: float | None, unit: str, low: float, high: float = math.inf, finite: bool = True) -> None:
    """Refuse (one line, exit 2) a number flag that is nan, infinite (unless ``finite`` is False)
    or outside [low, high]: typer's own range check would call nan "not greater than" its bound."""
    if value is None:
        return
    if math.isnan(value) or (finite and math.isinf(value)) or not low <= value <= high:
        bound = f"at least {low:,.12g}" if high == math.inf else f"{low:,.12g} to {high:,.12g}"
        fail(f"{flag} {value:g}: expected {'a finite' if finite else 'a'} number of {unit}, {bound}")


def once_each(flag: str, raw: str, items: list, what: str) -> None:
    """Refuse (one line, exit 2) a comma list ``raw`` of ``flag`` whose parsed ``items`` repeat one."""
    if len(set(items)) < len(items):
        fail(f"{flag} {raw!r}: {what}")


def _systems_option(systems: str) -> list[str]:
    """The names of ``--systems``: known, at least one, none twice (else one line, exit 2)."""
    from runners.systems import system_names

    known = system_names()
    names = [s.strip() for s in systems.split(",") if s.strip()]
    unknown = [s for s in names if s not in known]
    if unknown:
        fail(f"--systems: unknown system(s) {', '.join(unknown)} (available: {', '.join(sorted(known))})")
    if not names:
        fail(f"--systems {systems!r}: give at least one system (available: {', '.join(sorted(known))})")
    once_each("--systems", systems, names, "a system is named twice")
    return names


def _run_suite(path: Path, out: Path, config_file: Path | None, common: dict) -> None:
    """The runs of a suite file, each in its folder under ``out``: a finished one kept, a started
    one resumed (the same command again finishes the suite), the others made; all on one executor."""
    from runners.run import RunOptions, in_folder, scenario_fingerprint
    from runners.suite import read_suite
    from runners.systems import system_names
    from scenarios import ScenarioError

    try:
        runs = read_suite(path)
    except ScenarioError as exc:  # SuiteError, or the file's YAML
        fail(str(exc))
    if out.exists() and not out.is_dir():
        fail(f"--out {out}: is a file, not a folder")
    if (out / "manifest.json").exists():
        fail(f"--out {out}: holds a run, not the runs of a suite; give another --out")
    writable_dir(out, "--out")
    names = sorted({name for run in runs for name in run.systems})
    overrides = _read_overrides(config_file, names) if config_file is not None else None
    todo = []
    for run in runs:
        options = RunOptions(
            systems=run.systems,
            trials=run.trials,
            seed=run.seed,
            setting=run.setting,
            config_overrides=overrides,
            **common,
        )
        kept = in_folder(out / run.folder, options)
        if kept is None:
            note(f"{out / run.folder}: finished before; kept")
            continue
        if kept.resume is not None and _read_manifest(kept.resume, system_names()).get("scenario_sha256") not in (
            None,
            scenario_fingerprint(run.scenario),
        ):
            fail(f"{run.scenario.path}: changed since {kept.resume} started (sha256 differs from its manifest.json)")
        todo.append((run.scenario, kept))
    if todo:
        with _executor(todo[0][1]) as pool:
            _run_all(todo, pool, again=f"run the same command again to finish the suite in {out}")


LOCAL_WORKERS_PER_CORE = 4  # each local worker holds a simulator and the network weights (~0.5 GB)


def _check_executor(executor: str, ray_address: str | None, workers: int | None = None) -> None:
    """Refuse an unknown executor, Ray when it is not installed, an address without Ray, more local
    workers than the machine can hold: one line, exit 2."""
    from runners.executors import ExecutorUnavailable, check_executor

    try:
        check_executor(executor)
        if ray_address is not None and executor != "ray":
            raise ExecutorUnavailable("--ray-address: only with --executor ray")
    except ExecutorUnavailable as exc:
        fail(str(exc))
    cores = os.cpu_count() or 1
    if executor == "local" and workers is not None and workers > LOCAL_WORKERS_PER_CORE * cores:
        fail(
            f"--workers {workers}: more than {LOCAL_WORKERS_PER_CORE} per core on this machine ({cores} cores; each "
            "worker holds a simulator and the network weights, ~0.5 GB); use --executor ray for a cluster"
        )


@contextlib.contextmanager
def _executor(options):
    """The executor every run of one command shares (one Ray instance, not one per run)."""
    from runners.executors import ExecutorUnavailable, open_executor

    try:
        pool = open_executor(options.executor, options.workers, options.ray_address)
    except ExecutorUnavailable as exc:
        fail(str(exc))
    with pool:
        yield pool


def _read_manifest(run_dir: Path, known: list[str]) -> dict:
    """The manifest of a run folder to resume, with the keys a resume reads, or one line why not."""
    path = run_dir / "manifest.json"
    try:
        manifest = json.loads(path.read_bytes())
    except OSError as exc:
        fail(f"--resume {path}: cannot be read: {exc.strerror or exc}")
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        fail(f"--resume {path}: not valid JSON ({exc}); this folder cannot be resumed")
    problem = None
    if not isinstance(manifest, dict):
        problem = "not a JSON object"
    elif not (isinstance(manifest.get("scenario"), dict) and isinstance(manifest["scenario"].get("file"), str)):
        problem = "scenario.file missing"
    elif not (isinstance(manifest.get("systems"), list) and manifest["systems"]):
        problem = "systems missing"
    elif unknown := [s for s in manifest["systems"] if s not in known]:
        problem = f"systems: unknown system(s) {', '.join(map(str, unknown))}"
    elif not isinstance(manifest.get("seed"), int) or isinstance(manifest["seed"], bool):
        problem = "seed missing or not an integer"
    elif not isinstance(manifest.get("config"), dict) or not all(
        isinstance(manifest["config"].get(s), dict) for s in manifest["systems"]
    ):
        problem = "config of a system missing"
    elif not isinstance(manifest.get("trial_count", 0), int | None):
        problem = "trial_count not an integer"
    if problem is not None:
        fail(f"--resume {path}: {problem}; this folder cannot be resumed")
    manifest["scenario"].setdefault("name", manifest["scenario"]["file"])
    return manifest


def _read_overrides(path: Path, names: list[str]) -> dict:
    from pydantic import ValidationError

    from runners.run import resolved_configs
    from scenarios import ScenarioError
    from scenarios.schema import read_yaml

    try:
        data = read_yaml(path)
    except ScenarioError as exc:
        fail(f"--config {exc}")
    if not isinstance(data, dict):
        fail(f"--config {path}: expected a mapping of system names to settings")
    for name, value in data.items():
        if name not in names:
            fail(f"--config {path}: {name}: not one of the systems of this run ({', '.join(names)})")
        if value is not None and not isinstance(value, dict):
            fail(f"--config {path}: {name}: expected a mapping of settings")
    for name in data:
        try:
            resolved_configs([name], data)
        except ValidationError as exc:
            first = exc.errors()[0]
            key = ".".join(str(p) for p in first["loc"])
            fail(f"--config {path}: {name}.{key}: {first['msg'].removeprefix('Value error, ')}")
    return data


class _RunProgress:
    """One run's bars (mapping, trials) and lines on the command's progress display."""

    def __init__(self, progress, scenario, many: bool) -> None:
        self.progress, self.scenario, self.many = progress, scenario, many
        self.folder: Path | None = None
        self.mapping_task = None  # shown only when a system maps (a resume may find every map done)
        self.trial_task = None
        self.logged_tenths = -1

    @property
    def label(self) -> str:
        """The scenario's name; with several runs, and the run's folder."""
        if self.many and self.folder is not None:
            return f"{self.scenario.name} ({self.folder.name})"
        return self.scenario.name

    def hooks(self):
        from runners.run import RunHooks

        return RunHooks(on_stage=self.on_stage, on_mapping=self.on_mapping, on_trial=self.on_trial)

    def on_stage(self, stage: str, value) -> None:
        route_m = round(self.scenario.route_length_m)
        if stage == "run_dir":
            self.folder = value
        elif stage == "mapping":
            self.mapping_task = self.progress.add_task(f"[cyan]{escape(self.label)}[/] mapping (m)", total=route_m)
        elif stage == "navigation":
            if self.mapping_task is not None:
                self.progress.update(self.mapping_task, completed=route_m)
            self.trial_task = self.progress.add_task(f"[cyan]{escape(self.label)}[/] trials", total=value)
        elif stage == "done" and self.mapping_task is not None and self.trial_task is None:
            # --trials 0: no navigation stage completes the mapping bar
            self.progress.update(self.mapping_task, completed=route_m)

    def on_mapping(self, travelled: float, total: float) -> None:
        if self.mapping_task is not None:
            self.progress.update(self.mapping_task, completed=min(round(travelled), round(total)))
        tenth = int(10 * travelled / max(total, 1e-9))
        if not console.is_terminal and tenth > self.logged_tenths:  # logs and CI: a line every 10 %
            self.logged_tenths = tenth
            self.progress.console.print(f"  mapping {self.label}: {travelled:.0f} / {total:.0f} m", highlight=False)

    def on_trial(self, record: dict) -> None:
        if self.trial_task is not None:
            self.progress.advance(self.trial_task)
        mark = "[green]ok[/]" if record["success"] else f"[red]{record['reason']}[/]"
        if record.get("detail"):
            mark += f" ({escape(record['detail'])})"
        eff = record["efficiency"]
        where = f"{escape(self.label)}: " if self.many else ""
        self.progress.console.print(
            f"  {where}{record['system']:>12} trial {record['trial']:>3}: {mark}"
            + (f" efficiency {eff:.3f}" if eff is not None else ""),
            highlight=False,
        )


def _run_all(todo: list, pool, again: str | None = None) -> None:
    """Every (scenario, options) on ``pool``, their jobs in flight together, with a bar per run and
    stage and one for the jobs of all runs (done, running, failed); then ``_report_outcomes``.
    Ctrl-C exits 130 saying how to finish (``again``, else the --resume of each unfinished run)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from runners.run import RunPlan, execute_runs

    if not todo:
        return
    columns = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn()]
    with Progress(*columns, console=console, transient=False) as progress:
        shown = [_RunProgress(progress, scenario, many=len(todo) > 1) for scenario, _ in todo]
        jobs_task = progress.add_task("jobs", total=0)

        def on_jobs(counts: dict) -> None:
            ended = counts["done"] + counts["failed"]
            progress.update(
                jobs_task,
                completed=ended,
                total=ended + counts["running"] + counts["queued"],
                description=f"jobs ({counts['done']} done, {counts['running']} running, {counts['failed']} failed)",
            )

        plans = [RunPlan(scenario, options, run.hooks()) for (scenario, options), run in zip(todo, shown, strict=True)]
        try:
            outcomes = execute_runs(plans, pool, on_jobs)
        except KeyboardInterrupt:
            if again is not None:
                fail(f"interrupted; {again}", code=130)
            unfinished = [run.folder for run in shown if run.folder is not None and not (run.folder / "summary.json").is_file()]
            how = ", ".join(f"--resume {folder}" for folder in unfinished)
            fail(
                f"interrupted; finish the run{'s' if len(unfinished) > 1 else ''} with {how}" if how else "interrupted", code=130
            )
    _report_outcomes(shown, outcomes)


def _report_outcomes(shown: list[_RunProgress], outcomes: list) -> None:
    """Each run's summary and warnings, in order; then an error line per failed run, exit 1."""
    from runners.results import read_json

    failures = []
    for run, outcome in zip(shown, outcomes, strict=True):
        if outcome.error is not None:  # its traceback goes to <run>/logs/error.log
            exc = outcome.error
            message = f"run of {run.label} failed: {type(exc).__name__}: {exc}"
            if run.folder is not None:
                log = run.folder / "logs" / "error.log"
                log.parent.mkdir(parents=True, exist_ok=True)
                log.write_text(outcome.traceback)
                message += f" (traceback in {log})"
            failures.append(message)
            continue
        run_dir = outcome.value
        if run_dir.failed_stages:
            stages = " and ".join(dict.fromkeys(stage for stage, _ in run_dir.failed_stages.values()))
            why = "; ".join(f"{name}: {why}" for name, (_, why) in run_dir.failed_stages.items())
            failures.append(f"{stages} stage failed, no trial counted ({why}); after fixing it: --resume {run_dir.root}")
            continue
        if read_json(run_dir.manifest_path).get("trial_count") == 0:
            if run.scenario.trials:
                console.print(f"mapped, no trials run (--trials 0): navigate these maps with --maps-from {run_dir.root}")
            else:
                console.print(f"mapped, no trials run: {run.scenario.path} lists no trials")
        else:
            print_summary(run_dir.root)
        console.print(f"results: [bold]{run_dir.root}[/]")
        if run_dir.warnings:
            err.print(
                f"warning: {run_dir.warnings} trial(s) failed in their worker (error, crashed, timeout or out_of_memory; "
                f"the record's detail says why): {run_dir.trials_path}",
                highlight=False,
            )
    for message in failures:
        error_line(message)
    if failures:
        raise typer.Exit(1)


def print_summary(run_dir: Path) -> None:
    from reports.tables import COLUMNS, rows

    table = Table(title=f"summary of {run_dir}", show_lines=False)
    for _, title in COLUMNS:
        table.add_column(title, justify="right" if title != "system" else "left")
    for row in rows(run_dir):
        table.add_row(*[row[key] for key, _ in COLUMNS])
    console.print(table)


# ---------------------------------------------------------------------------------------------
# scenarios

IMAGE_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg")


@scenario_app.command("list")
def scenario_list() -> None:
    """The bundled scenarios, one line each."""
    from scenarios import bundled_names
    from scenarios.scenario import resolve_path
    from scenarios.schema import read_spec

    table = Table(show_header=True)
    table.add_column("name")
    table.add_column("description")
    for name in bundled_names():
        spec = read_spec(resolve_path(name))
        table.add_row(name, spec.description)
    console.print(table)


@scenario_app.command("show")
def scenario_show(
    scenario: Annotated[str, typer.Argument(help="bundled name or YAML file")],
    as_json: Annotated[bool, typer.Option("--json", help="print JSON")] = False,
) -> None:
    """Statistics of a scenario: corridor length, free area, route, trials, bounds."""
    summary = _load(scenario).summary()
    if as_json:
        sys.stdout.write(json.dumps(summary, indent=2) + "\n")
        return
    table = Table(show_header=False)
    for key, value in summary.items():
        table.add_row(key, str(value))
    console.print(table)


@scenario_app.command("validate")
def scenario_validate(files: Annotated[list[str], typer.Argument(help="scenario YAML files")]) -> None:
    """Check scenario files; exit 0, or 2 with one line per bad file."""
    from scenarios import ScenarioError, load_scenario

    bad = 0
    for name in files:
        try:
            scenario = load_scenario(name)
        except ScenarioError as exc:
            bad += 1
            err.print(str(exc), highlight=False, soft_wrap=True)
        except Exception as exc:  # noqa: BLE001 - one line per file, and the next file is checked
            bad += 1
            err.print(
                f"{name}: cannot be loaded: {type(exc).__name__}: {exc}".replace("\n", " "), highlight=False, soft_wrap=True
            )
        else:
            for line in scenario.notes:
                note(line)
            console.print(f"{name}: ok", highlight=False)
    if bad:
        raise typer.Exit(2)


@scenario_app.command("render")
def scenario_render(
    scenario: Annotated[str, typer.Argument(help="bundled name or YAML file")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG file to write")],
    no_route: Annotated[bool, typer.Option("--no-route", help="leave out the mapping route")] = False,
) -> None:
    """Draw the ground-truth map, obstacles, mapping route and trials."""
    writable_file(output, "-o", IMAGE_SUFFIXES)
    from scenarios.render import render

    loaded = _load(scenario)
    try:
        path = render(loaded, output, show_route=not no_route)
    except OSError as exc:
        fail(f"-o {output}: cannot be written: {exc.strerror or exc}")
    console.print(f"wrote {path}")


# ---------------------------------------------------------------------------------------------
# reports and configs


@app.command()
def report(
    run_dirs: Annotated[list[Path], typer.Argument(help="results folders of runs")],
    out: Annotated[Path | None, typer.Option(help="folder of the report (default: the first RUN_DIR's report/)")] = None,
) -> None:
    """Table 1 (table.md, .csv, .tex), plots (PNG and SVG) and a self-contained report.html.

    Several RUN_DIRs (scenarios, settings, seeds) make one combined report, written under --out or,
    without it, under the first RUN_DIR's report/. Reads the results folders only."""
    from reports.report import make_report
    from reports.results import RunFormatError

    writable_dir(out if out is not None else run_dirs[0] / "report", "--out" if out is not None else "report")
    try:
        made = make_report(run_dirs, out)
    except RunFormatError as exc:
        fail(str(exc))
    except Exception as exc:  # noqa: BLE001 - a bug or an odd file: still one line, naming the runs
        fail(f"report of {', '.join(map(str, run_dirs))} failed: {type(exc).__name__}: {exc}".replace("\n", " "), code=1)
    for section in made.sections:  # each run once: a folder named twice or a copied run is left out
        print_summary(section.run.root)
    for line in made.notes:
        console.print(f"note: {escape(line)}", highlight=False, soft_wrap=True)
    console.print(f"tables: {made.out / 'table.md'}, table.csv, table.tex", highlight=False)
    console.print(f"report: [bold]{made.html}[/]", highlight=False)


@app.command("plot-graph")
def plot_graph_command(
    run_dir: Annotated[Path, typer.Argument(help="a results folder with a NavTopo map")],
    output: Annotated[Path, typer.Option("-o", "--output", help="PNG file to write (an SVG is written beside it)")],
    system: Annotated[str, typer.Option(help="the system whose graph map to draw")] = "navtopo",
) -> None:
    """Draw a graph map (locations, their walls, edges) over the ground-truth map."""
    writable_file(output, "-o", IMAGE_SUFFIXES)
    from reports.plots import plot_graph_map
    from reports.results import Run, RunFormatError

    try:
        run = Run.load(run_dir, require_summary=False)
    except RunFormatError as exc:
        fail(str(exc))
    if run.map_kind(system) != "graph":
        fail(f"{run_dir}: no graph map of {system} (maps/{system}/graph.json missing)")
    plot = plot_graph_map(run, system, output.parent, name=output.stem)
    if not plot.files:
        fail(plot.note)
    console.print(f"wrote {plot.png}" + (f" ({plot.note})" if plot.note else ""), highlight=False)


@app.command()
def config(system: Annotated[str | None, typer.Argument(help="a system name; all when left out")] = None) -> None:
    """The resolved configuration a run will use (YAML)."""
    import yaml

    from runners.systems import registry

    systems = registry()
    names = [system] if system else sorted(systems)
    for name in names:
        if name not in systems:
            fail(f"unknown system {name!r} (available: {', '.join(sorted(systems))})")
    data = {name: systems[name].default_config().model_dump(mode="json") for name in names}
    sys.stdout.write(yaml.safe_dump(data, sort_keys=False))


# ---------------------------------------------------------------------------------------------
# studies

# generating a 10 km building takes about 40 s and grows faster than the length; a building
# whose raster is too large is refused by the scenario's own size check before any run
MIN_SWEEP_LENGTH_M, MAX_SWEEP_LENGTH_M = 20.0, 10_000.0
MAX_SWEEP_TRIALS = 10_000  # trials.generate.count's bound

sweep_app = typer.Typer(help="Studies over generated sizes (scaling) and odometry noise (drift).", no_args_is_help=True)
app.add_typer(sweep_app, name="sweep")


@sweep_app.command("scaling")
def sweep_scaling(
    lengths: Annotated[str, typer.Option(help="total corridor lengths (m) of the generated buildings")] = "150,300,600,1200,2400",
    systems: Annotated[str, typer.Option(help="comma-separated systems")] = "navtopo,metric_grid",
    trials: Annotated[int, typer.Option(help="navigation trials per size", min=1, max=MAX_SWEEP_TRIALS)] = 5,
    seed: Annotated[int, typer.Option(help="seed of the generated buildings", min=0)] = 31,
    building: Annotated[str, typer.Option(help="lattice (corridors round blocks: loops) or tree")] = "lattice",
    route_factor: Annotated[
        float, typer.Option(help="the mapping route drives at least this x the corridor length (at least 0.5)")
    ] = 1.0,
    setting: Annotated[str, typer.Option(help="precise or noisy")] = "precise",
    workers: WorkersOption = None,
    executor: ExecutorOption = "local",
    ray_address: RayAddressOption = None,
    out: Annotated[Path, typer.Option(help="the sweep's folder: scenarios/, <length>m/ runs, report/")] = Path(
        "results/sweep_scaling"
    ),
) -> None:
    """Map and navigate generated buildings of growing size; planning time and memory against size.

    One run per length under OUT/<length>m (a finished one is kept, an interrupted one resumed: run
    the same command again), then OUT/report/: scaling.md and scaling.csv (fitted growth exponents),
    the log-log plot, and the usual tables, plots and report.html of all the runs."""
    from runners.protocol import SETTINGS
    from runners.sweep import ScalingOptions, run_scaling
    from scenarios.schema import MAX_ROUTE_M

    try:
        length_list = [float(v) for v in lengths.split(",") if v.strip()]
        if not length_list or not all(MIN_SWEEP_LENGTH_M <= v <= MAX_SWEEP_LENGTH_M for v in length_list):
            raise ValueError
    except ValueError:
        fail(
            f"--lengths: expected comma-separated lengths of {MIN_SWEEP_LENGTH_M:g} to {MAX_SWEEP_LENGTH_M:g} m, got {lengths!r}"
        )
    metres = [round(v) for v in length_list]
    once_each("--lengths", lengths, metres, "a length is given twice (to the metre: each has its folder <length>m)")
    check_number("--route-factor", route_factor, "times the corridor length", low=0.5)
    if route_factor * max(length_list) > MAX_ROUTE_M:
        fail(f"--route-factor {route_factor}: the route of the {max(length_list):g} m building would pass {MAX_ROUTE_M:g} m")
    names = _systems_option(systems)
    if setting not in SETTINGS:
        fail(f"--setting: unknown setting {setting!r} (choose from {', '.join(SETTINGS)})")
    if building not in ("lattice", "tree"):
        fail(f"--building: {building!r} is not lattice or tree")
    writable_dir(out, "--out")
    options = ScalingOptions(
        building=building,
        lengths=length_list,
        systems=names,
        trials=trials,
        seed=seed,
        route_factor=route_factor,
        setting=setting,
        workers=workers,
        executor=executor,
        ray_address=ray_address,
        out=out,
    )
    folders = _run_sweep(options, run_scaling)
    _sweep_report(folders, out / "report", "scaling", "Scaling: planning time and memory against environment size")


@sweep_app.command("drift")
def sweep_drift(
    scenario: Annotated[str, typer.Argument(help="bundled name or YAML file")] = "loop_office",
    levels: Annotated[str, typer.Option(help="odometry-noise settings in order: off, moderate, strong")] = "precise,noisy,strong",
    systems: Annotated[str, typer.Option(help="comma-separated systems")] = "navtopo,metric_grid",
    trials: Annotated[int, typer.Option(help="navigation trials per level", min=1, max=MAX_SWEEP_TRIALS)] = 5,
    workers: WorkersOption = None,
    executor: ExecutorOption = "local",
    ray_address: RayAddressOption = None,
    out: Annotated[Path, typer.Option(help="the sweep's folder: <level>/ runs, report/")] = Path("results/sweep_drift"),
) -> None:
    """One scenario under odometry noise off, moderate and strong: success, efficiency, map quality.

    One run per level under OUT/<level> (a finished one is kept, an interrupted one resumed), then
    OUT/report/: drift.md and drift.csv, the per-level plot, Figure 1 (the metric grid built under
    the strongest drift over the GT map beside the graph of locations) and the usual report."""
    from runners.protocol import SETTINGS
    from runners.sweep import DriftOptions, run_drift

    level_list = [v.strip() for v in levels.split(",") if v.strip()]
    bad = [v for v in level_list if v not in SETTINGS]
    if bad or not level_list:
        fail(f"--levels: unknown setting(s) {', '.join(bad) or repr(levels)} (choose from {', '.join(SETTINGS)})")
    once_each("--levels", levels, level_list, "a level is named twice")
    names = _systems_option(systems)
    writable_dir(out, "--out")
    _load(scenario)  # a bad scenario is one line before any work
    options = DriftOptions(
        scenario=scenario,
        levels=level_list,
        systems=names,
        trials=trials,
        workers=workers,
        executor=executor,
        ray_address=ray_address,
        out=out,
    )
    folders = _run_sweep(options, run_drift)
    _sweep_report(folders, out / "report", "drift", "Drift: the same scenario under growing odometry noise")


def _run_sweep(options, run_sweep) -> list[Path]:
    """Every run of a sweep on one executor, in flight together (one Ray instance for the whole
    sweep), opened once the sweep has generated and checked its buildings and kept runs."""
    from runners.sweep import SweepError

    _check_executor(options.executor, options.ray_address, options.workers)

    def run_all(todo: list) -> None:
        if todo:
            with _executor(options) as pool:
                _run_all(todo, pool, again="run the same command again to finish the sweep")

    try:
        return run_sweep(options, run_all)
    except SweepError as exc:  # raised before the sweep's first run starts
        fail(str(exc))


def _sweep_report(folders: list[Path], out: Path, study: str, title: str) -> None:
    from reports.report import make_report
    from reports.results import RunFormatError
    from reports.sweep import write_drift, write_scaling

    try:
        made = make_report(folders, out, study={"scaling": write_scaling, "drift": write_drift}[study], study_title=title)
    except RunFormatError as exc:
        fail(str(exc))
    for note in made.notes:
        console.print(f"note: {note}", highlight=False)
    sys.stdout.write((out / f"{study}.md").read_text(encoding="utf-8"))
    console.print(f"report: [bold]{made.html}[/]", highlight=False)


# ---------------------------------------------------------------------------------------------
# place recognition


@app.command("train-descriptor")
def train_descriptor(
    descriptor: Annotated[str, typer.Option(help="minkloc3d or polar_bev")] = "minkloc3d",
    minutes: Annotated[float, typer.Option(help="training time budget (at least 0.1)")] = 15.0,
    worlds: Annotated[int, typer.Option(help="generated training worlds (never the bundled scenarios)", min=1)] = 9,
    threads: Annotated[int | None, typer.Option(help="torch threads (1 is fastest on a shared 2-core machine)", min=1)] = 1,
    data_dir: Annotated[Path, typer.Option(help="cache of generated scans")] = Path("data/place_recognition"),
    out: Annotated[
        Path | None,
        typer.Option(
            help="a folder for the weights (default: a new weights/<descriptor>-<time>; the package's shipped "
            "weights are never overwritten: copy new ones there by hand to ship them)"
        ),
    ] = None,
) -> None:
    """Train a place-recognition descriptor on scans of generated corridor worlds."""
    check_number("--minutes", minutes, "minutes", low=0.1)
    from navtopo.place_recognition import available_descriptors
    from runners.place_recognition_data import default_training_out, existing_weights
    from runners.place_recognition_data import train_descriptor as train

    if descriptor not in available_descriptors() or descriptor == "scan_context":
        fail(f"--descriptor: {descriptor!r} is not a learned descriptor (minkloc3d, polar_bev)")
    out = out or default_training_out(descriptor)
    if out.exists() and not out.is_dir():
        fail(f"--out {out}: is a file, not a folder")
    if found := existing_weights(out, descriptor):
        fail(f"--out {out}: already holds {found[0].name}; train into another folder (it is never overwritten)")
    writable_dir(out, "--out")
    writable_dir(data_dir, "--data-dir")
    summary = train(descriptor, minutes, worlds, threads, data_dir, out, say=lambda m: console.print(m, highlight=False))
    sys.stdout.write(json.dumps(summary, indent=2, default=str) + "\n")


RECALL_RADIUS_M = 3.0  # a retrieved scan this close to the query is a hit (retrieval.evaluate_revisits)
MIN_SCAN_SPACING_M = 0.05
MAX_EVAL_SCANS = 50_000


@app.command("eval-place-recognition")
def eval_place_recognition(
    scenario: Annotated[str, typer.Argument(help="bundled name or YAML file")],
    as_json: Annotated[bool, typer.Option("--json", help="print JSON")] = False,
    descriptors: Annotated[str, typer.Option(help="comma-separated descriptors")] = "minkloc3d,scan_context,polar_bev",
    spacing: Annotated[float, typer.Option(help="a scan every this many metres of the route")] = 1.0,
    min_gap: Annotated[float, typer.Option(help="query only scans at least this far back along the route (m)")] = 30.0,
) -> None:
    """Recall@1/@5 (3 m) of each descriptor: every route scan queried against earlier passes."""
    names = [d.strip() for d in descriptors.split(",") if d.strip()]
    if not names:
        fail("--descriptors: give at least one descriptor")
    if not (math.isfinite(spacing) and spacing >= MIN_SCAN_SPACING_M):
        fail(f"--spacing {spacing}: a scan every at least {MIN_SCAN_SPACING_M} m of the route is needed")
    if not (math.isfinite(min_gap) and min_gap > RECALL_RADIUS_M):
        fail(
            f"--min-gap {min_gap}: must be more than the {RECALL_RADIUS_M} m recall radius, "
            "else the scans just behind a query match it trivially"
        )
    import torch

    from navtopo.place_recognition import available_descriptors
    from runners.place_recognition_data import evaluate_scenario

    unknown = [d for d in names if d not in available_descriptors()]
    if unknown:
        fail(f"--descriptors: unknown descriptor(s) {', '.join(unknown)} (available: {', '.join(available_descriptors())})")
    loaded = _load(scenario, with_trials=False)
    scans = loaded.route_length_m / spacing
    if scans > MAX_EVAL_SCANS:
        fail(f"--spacing {spacing}: {scans:,.0f} scans on the {loaded.route_length_m:.0f} m route (at most {MAX_EVAL_SCANS:,})")
    torch.set_num_threads(1)
    results = evaluate_scenario(loaded, names, spacing_m=spacing, min_gap_m=min_gap)
    if all(not r.get("queries") for r in results.values() if "error" not in r):
        note(f"no scan of {scenario} has an earlier pass ({min_gap} m or more of driving before) within {RECALL_RADIUS_M} m")
    if as_json:
        sys.stdout.write(json.dumps(results, indent=2) + "\n")
        return
    table = Table(title=f"place recognition on {scenario} (3 m)")
    for column in ("descriptor", "recall@1", "recall@5", "queries"):
        table.add_column(column)
    for name, r in results.items():
        if "error" in r:
            table.add_row(name, escape(str(r["error"])), "", "")
            continue
        recalls = [r.get(key) for key in ("recall_at_1", "recall_at_5")]
        table.add_row(name, *["–" if v is None else f"{v:.3f}" for v in recalls], str(r.get("queries", "")))
    console.print(table)


def main() -> int:
    """The `navtopo-bench` entry point: a usage error (a flag's value or type, an unknown option
    or command) is one `error:` line too, like every other refusal, instead of typer's panel."""
    try:
        code = app(standalone_mode=False)
    except Exception as exc:
        # click's ClickException (typer vendors click in some versions: recognised by its interface)
        if not (hasattr(exc, "format_message") and isinstance(getattr(exc, "exit_code", None), int)):
            raise
        if not exc.format_message():  # no arguments at all: the answer is the help, as typer shows it
            app()
        context = getattr(exc, "ctx", None)
        hint = f" (see `{context.command_path} --help`)" if context is not None else ""
        err.print(f"[bold red]error:[/] {one_line(exc.format_message())}{hint}", highlight=False, soft_wrap=True)
        return exc.exit_code
    return code if isinstance(code, int) else 0


if __name__ == "__main__":
    sys.exit(main())
