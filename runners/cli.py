"""The `navtopo-bench` command (DESIGN.md, "Contracts: the command line").

The command surface only: each command parses its flags, builds a request, calls the modules that
do the work and prints. ``runners/commands/`` holds the parts: the run request and its rules
(``request.py``), what `run` does with it (``runs.py``), the progress display (``progress.py``),
the `scenario` and `sweep` commands (``scenario.py``, ``sweep.py``) and the refusals commands
share (``checks.py``).

Every expected failure is a ``navkit.errors.BenchError``; ``BenchGroup.invoke`` catches them in one
place and prints ``error: <message>`` (one line), exiting with the error's code: 2 an input refused,
1 a run or report that failed, 130 interrupted. A usage error (a flag's type, an unknown option or
command) is one such line too (``main``). Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.markup import escape
from rich.table import Table
from typer.core import TyperGroup, TyperOption

from navkit.errors import BenchError
from runners.commands.checks import IMAGE_SUFFIXES, check_number, open_scenario, writable_dir, writable_file
from runners.commands.console import console, err, error_line, note, one_line
from runners.commands.errors import Refused, ReportFailed, RunsFailed
from runners.commands.jobs import ExecutorOption, RayAddressOption, WorkersOption
from runners.commands.request import (
    DEFAULT_GOALS,
    DEFAULT_INITIAL_POSE,
    DEFAULT_INITIAL_POSE_ERROR,
    DEFAULT_STOP_TOLERANCE,
    DEFAULT_SYSTEMS,
    DEFAULT_TRIAL_TIMEOUT_S,
)
from runners.commands.scenario import scenario_app
from runners.commands.sweep import sweep_app

# the heavy modules (scenarios: scipy, shapely, numba; the systems: torch) are imported inside the
# commands that need them, so that `--help` and argument errors answer at once


class BenchGroup(TyperGroup):
    """The command group: the one place where expected failures become their ``error:`` line."""

    def invoke(self, ctx: Any) -> Any:  # typer's own (vendored) click.Context
        try:
            return super().invoke(ctx)
        except BenchError as exc:
            for line in exc.failures if isinstance(exc, RunsFailed) else [str(exc)]:
                error_line(line)
            raise typer.Exit(exc.exit_code) from None


app = typer.Typer(
    cls=BenchGroup,
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.add_typer(scenario_app, name="scenario")


def _flag_type_shown(display_type_rich: Callable[..., Any]) -> Callable[..., Any]:
    """Typer's help panels give every option a type label, a flag too (`--help <bool>`, `--json
    <bool>`): a flag takes no value, so it gets none, as in click's own help."""

    def shown(self: Any, ctx: Any) -> Any:
        return None if getattr(self, "is_flag", False) else display_type_rich(self, ctx)

    return shown


if hasattr(TyperOption, "display_type_rich"):
    TyperOption.display_type_rich = _flag_type_shown(TyperOption.display_type_rich)  # type: ignore[method-assign]


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


# ---------------------------------------------------------------------------------------------
# run


@app.command()
def run(
    scenarios: Annotated[
        list[str] | None, typer.Argument(help="bundled scenario names or YAML files (with --resume: the run's own)")
    ] = None,
    systems: Annotated[str, typer.Option(help="comma-separated systems (see `config`)")] = DEFAULT_SYSTEMS,
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
    ] = DEFAULT_TRIAL_TIMEOUT_S,
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
    ] = DEFAULT_INITIAL_POSE_ERROR,
    initial_pose: Annotated[
        str,
        typer.Option(
            help="perturbed: systems that take an initial pose get the start with --initial-pose-error (NavTopo as "
            "its start-up's prior); none: kidnapped, every system localizes globally on its own map"
        ),
    ] = DEFAULT_INITIAL_POSE,
    stop_tolerance: Annotated[
        float,
        typer.Option(
            help="m (0.01 to 0.5, the runner's STOP rule): systems that stop by their own estimate stop this close to the goal"
        ),
    ] = DEFAULT_STOP_TOLERANCE,
    goals: Annotated[
        str,
        typer.Option(
            help="map: goals as map-frame points for every system; native: graph systems get the paper's "
            "(location, pose in it) form (the same as map with precise odometry)"
        ),
    ] = DEFAULT_GOALS,
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
    get the trial's start with a seeded error (--initial-pose-error), or none with --initial-pose
    none (kidnapped: each localizes globally on its own map), and every system that
    declares "reached" by its own estimate stops within --stop-tolerance of the goal; success is
    the robot's true position within 0.5 m of the goal when it stops.
    """
    from runners.commands.request import RunRequest
    from runners.commands.runs import start_runs

    request = RunRequest(
        scenarios=list(scenarios or []),
        systems=systems,
        trials=trials,
        seed=seed,
        seeds=seeds,
        out=out,
        resume=resume,
        workers=workers,
        executor=executor,
        ray_address=ray_address,
        trial_timeout_s=trial_timeout,
        trial_memory_mb=trial_memory_mb,
        results=results,
        config_file=config_file,
        setting=setting,
        initial_pose_error=initial_pose_error,
        initial_pose=initial_pose,
        stop_tolerance=stop_tolerance,
        goals=goals,
        maps_from=maps_from,
        suite=suite,
    )
    start_runs(request)


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
    from runners.commands.progress import print_summary

    writable_dir(out if out is not None else run_dirs[0] / "report", "--out" if out is not None else "report")
    try:
        made = make_report(run_dirs, out)
    except RunFormatError as exc:  # not a BenchError yet (reports/results.py)
        raise Refused(str(exc)) from None
    except BenchError:
        raise
    except Exception as exc:  # noqa: BLE001 - a bug or an odd file: still one line, naming the runs
        raise ReportFailed(
            f"report of {', '.join(map(str, run_dirs))} failed: {type(exc).__name__}: {exc}".replace("\n", " ")
        ) from None
    for section in made.sections:  # each run once: a folder named twice or a copied run is left out
        print_summary(section.run.root)
    for line in made.notes:
        console.print(f"note: {escape(line)}", highlight=False, soft_wrap=True)
    console.print(f"tables: {made.out / 'table.md'}, table.csv, table.tex, trials.md", highlight=False)
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
    except RunFormatError as exc:  # not a BenchError yet (reports/results.py)
        raise Refused(str(exc)) from None
    if system not in run.manifest.systems:
        raise Refused(f"--system {system}: {run_dir} ran {', '.join(run.manifest.systems)}, not {system}")
    if run.map_kind(system) != "graph":
        raise Refused(f"{run_dir}: no graph map of {system} (maps/{system}/graph.json missing)")
    plot = plot_graph_map(run, system, output.parent, name=output.stem)
    if not plot.files:
        raise Refused(plot.note)
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
            raise Refused(f"unknown system {name!r} (available: {', '.join(sorted(systems))})")
    data = {name: systems[name].default_config().model_dump(mode="json") for name in names}
    sys.stdout.write(yaml.safe_dump(data, sort_keys=False))


# ---------------------------------------------------------------------------------------------
# studies

app.add_typer(sweep_app, name="sweep")


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
        raise Refused(f"--descriptor: {descriptor!r} is not a learned descriptor (minkloc3d, polar_bev)")
    out = out or default_training_out(descriptor)
    if out.exists() and not out.is_dir():
        raise Refused(f"--out {out}: is a file, not a folder")
    if found := existing_weights(out, descriptor):
        raise Refused(f"--out {out}: already holds {found[0].name}; train into another folder (it is never overwritten)")
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
        raise Refused("--descriptors: give at least one descriptor")
    if not (math.isfinite(spacing) and spacing >= MIN_SCAN_SPACING_M):
        raise Refused(f"--spacing {spacing}: a scan every at least {MIN_SCAN_SPACING_M} m of the route is needed")
    if not (math.isfinite(min_gap) and min_gap > RECALL_RADIUS_M):
        raise Refused(
            f"--min-gap {min_gap}: must be more than the {RECALL_RADIUS_M} m recall radius, "
            "else the scans just behind a query match it trivially"
        )
    import torch

    from navtopo.place_recognition import available_descriptors
    from runners.place_recognition_data import evaluate_scenario

    unknown = [d for d in names if d not in available_descriptors()]
    if unknown:
        raise Refused(
            f"--descriptors: unknown descriptor(s) {', '.join(unknown)} (available: {', '.join(available_descriptors())})"
        )
    loaded = open_scenario(scenario, with_trials=False)
    scans = loaded.route_length_m / spacing
    if scans > MAX_EVAL_SCANS:
        raise Refused(
            f"--spacing {spacing}: {scans:,.0f} scans on the {loaded.route_length_m:.0f} m route (at most {MAX_EVAL_SCANS:,})"
        )
    torch.set_num_threads(1)
    results = evaluate_scenario(loaded, names, spacing_m=spacing, min_gap_m=min_gap)
    if all(not r.get("queries") for r in results.values() if "error" not in r):
        note(f"no scan of {scenario} has an earlier pass ({min_gap} m or more of driving before) within {RECALL_RADIUS_M} m")
    if as_json:
        sys.stdout.write(json.dumps(results, indent=2) + "\n")
        return
    print_recalls(scenario, results)


def print_recalls(scenario: str, results: dict[str, dict[str, Any]]) -> None:
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
        format_message = getattr(exc, "format_message", None)
        exit_code = getattr(exc, "exit_code", None)
        if not (callable(format_message) and isinstance(exit_code, int)):
            raise
        if not format_message():  # no arguments at all: the answer is the help, as typer shows it
            app()
        context = getattr(exc, "ctx", None)
        hint = f" (see `{context.command_path} --help`)" if context is not None else ""
        err.print(f"[bold red]error:[/] {one_line(format_message())}{hint}", highlight=False, soft_wrap=True)
        return exit_code
    return code if isinstance(code, int) else 0


if __name__ == "__main__":
    sys.exit(main())
