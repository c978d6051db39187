"""`navtopo-bench sweep scaling|drift`: studies over generated sizes and odometry noise.

The flags are checked here (one line, exit 2, before any building is generated or folder made);
``runners.sweep`` generates and checks the buildings and the runs kept in the sweep's folder, the
runs go on one executor with the progress display of `run`, and ``reports`` writes the study.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, TypeVar

import typer

from runners.commands.checks import (
    check_executor_flags,
    check_number,
    once_each,
    open_scenario,
    systems_list,
    writable_dir,
)
from runners.commands.console import console
from runners.commands.errors import Refused
from runners.commands.jobs import ExecutorOption, JobPlace, RayAddressOption, WorkersOption, executor_for

if TYPE_CHECKING:
    from runners.run import RunOptions
    from runners.sweep import RunAll
    from scenarios import Scenario

SweepOptions = TypeVar("SweepOptions", bound=JobPlace)  # runners.sweep: ScalingOptions, DriftOptions

# generating a 10 km building takes about 40 s and grows faster than the length; a building
# whose raster is too large is refused by the scenario's own size check before any run
MIN_SWEEP_LENGTH_M, MAX_SWEEP_LENGTH_M = 20.0, 10_000.0
MAX_SWEEP_TRIALS = 10_000  # trials.generate.count's bound

sweep_app = typer.Typer(help="Studies over generated sizes (scaling) and odometry noise (drift).", no_args_is_help=True)


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

    length_list = parse_lengths(lengths)
    metres = [round(v) for v in length_list]
    once_each("--lengths", lengths, metres, "a length is given twice (to the metre: each has its folder <length>m)")
    check_number("--route-factor", route_factor, "times the corridor length", low=0.5)
    if route_factor * max(length_list) > MAX_ROUTE_M:
        raise Refused(
            f"--route-factor {route_factor}: the route of the {max(length_list):g} m building would pass {MAX_ROUTE_M:g} m"
        )
    names = systems_list(systems)
    if setting not in SETTINGS:
        raise Refused(f"--setting: unknown setting {setting!r} (choose from {', '.join(SETTINGS)})")
    if building not in ("lattice", "tree"):
        raise Refused(f"--building: {building!r} is not lattice or tree")
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
    folders = run_sweep(options, run_scaling)
    sweep_report(folders, out / "report", "scaling", "Scaling: planning time and memory against environment size")


def parse_lengths(lengths: str) -> list[float]:
    """``--lengths``: comma-separated corridor lengths within the sweep's bounds."""
    try:
        length_list = [float(v) for v in lengths.split(",") if v.strip()]
        if not length_list or not all(MIN_SWEEP_LENGTH_M <= v <= MAX_SWEEP_LENGTH_M for v in length_list):
            raise ValueError
    except ValueError:
        raise Refused(
            f"--lengths: expected comma-separated lengths of {MIN_SWEEP_LENGTH_M:g} to {MAX_SWEEP_LENGTH_M:g} m, got {lengths!r}"
        ) from None
    return length_list


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
        raise Refused(f"--levels: unknown setting(s) {', '.join(bad) or repr(levels)} (choose from {', '.join(SETTINGS)})")
    once_each("--levels", levels, level_list, "a level is named twice")
    names = systems_list(systems)
    writable_dir(out, "--out")
    open_scenario(scenario)  # a bad scenario is one line before any work
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
    folders = run_sweep(options, run_drift)
    sweep_report(folders, out / "report", "drift", "Drift: the same scenario under growing odometry noise")


def run_sweep(options: SweepOptions, sweep: Callable[[SweepOptions, RunAll], list[Path]]) -> list[Path]:
    """Every run of a sweep on one executor, in flight together (one Ray instance for the whole
    sweep), opened once the sweep has generated and checked its buildings and kept runs (a
    ``SweepError`` before any run starts)."""
    from runners.commands.progress import run_with_progress

    check_executor_flags(options.executor, options.ray_address, options.workers)

    def run_all(todo: list[tuple[Scenario, RunOptions]]) -> None:
        if todo:
            with executor_for(options) as pool:
                run_with_progress(todo, pool, again="run the same command again to finish the sweep")

    return sweep(options, run_all)


def sweep_report(folders: list[Path], out: Path, study: str, title: str) -> None:
    """The study's report of the sweep's runs; its Markdown table printed."""
    from reports.report import make_report
    from reports.results import RunFormatError
    from reports.sweep import write_drift, write_scaling

    try:
        made = make_report(folders, out, study={"scaling": write_scaling, "drift": write_drift}[study], study_title=title)
    except RunFormatError as exc:  # not a BenchError yet (reports/results.py)
        raise Refused(str(exc)) from None
    for line in made.notes:
        console.print(f"note: {line}", highlight=False)
    sys.stdout.write((out / f"{study}.md").read_text(encoding="utf-8"))
    console.print(f"report: [bold]{made.html}[/]", highlight=False)
