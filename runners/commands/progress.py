"""What a user sees of runs: a bar per run and stage while they go, then each run's outcome.

``run_with_progress`` runs every (scenario, options) on one executor with a rich ``Progress``: per
run a mapping bar (metres of the route) and a trials bar, one bar for the jobs of all runs (done,
running, failed), a line per trial; without a terminal (logs, CI) a mapping line every 10 %. Once
every run has ended, ``report_outcomes`` prints each run's summary table and warnings in order,
then an ``error:`` line per failed run (``RunsFailed``, exit 1).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from rich.markup import escape
from rich.table import Table

from navkit.errors import BenchError
from runners.commands.console import console, err
from runners.commands.errors import Interrupted, RunsFailed

if TYPE_CHECKING:
    from rich.progress import Progress, TaskID

    from reports.records import TrialRecord
    from runners.driver import Outcome
    from runners.executors import Executor
    from runners.results import RunDir
    from runners.run import RunHooks, RunOptions
    from scenarios import Scenario


class RunProgress:
    """One run's bars (mapping, trials) and lines on the command's progress display."""

    def __init__(self, progress: Progress, scenario: Scenario, many: bool) -> None:
        self.progress, self.scenario, self.many = progress, scenario, many
        self.folder: Path | None = None
        self.mapping_task: TaskID | None = None  # shown only when a system maps (a resume may find every map done)
        self.trial_task: TaskID | None = None
        self.logged_tenths = -1

    @property
    def label(self) -> str:
        """The scenario's name; with several runs, and the run's folder."""
        if self.many and self.folder is not None:
            return f"{self.scenario.name} ({self.folder.name})"
        return self.scenario.name

    def hooks(self) -> RunHooks:
        from runners.run import RunHooks

        return RunHooks(on_stage=self.on_stage, on_mapping=self.on_mapping, on_trial=self.on_trial)

    def on_stage(self, stage: str, value: Any) -> None:
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

    def on_trial(self, record: TrialRecord) -> None:
        if self.trial_task is not None:
            self.progress.advance(self.trial_task)
        mark = "[green]ok[/]" if record.success else f"[red]{record.reason}[/]"
        if record.failure_stage:
            mark += f", {escape(record.failure_stage)}"
        if record.detail:
            mark += f" ({escape(record.detail)})"
        eff = record.efficiency
        where = f"{escape(self.label)}: " if self.many else ""
        self.progress.console.print(
            f"  {where}{record.system:>12} trial {record.trial:>3}: {mark}"
            + (f" efficiency {eff:.3f}" if eff is not None else ""),
            highlight=False,
        )


def run_with_progress(todo: list[tuple[Scenario, RunOptions]], pool: Executor, again: str | None = None) -> None:
    """Every (scenario, options) on ``pool``, their jobs in flight together, with a bar per run and
    stage and one for the jobs of all runs (done, running, failed); then ``report_outcomes``.
    Ctrl-C is ``Interrupted`` (exit 130) saying how to finish (``again``, else the --resume of each
    unfinished run)."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from runners.run import RunPlan, execute_runs

    if not todo:
        return
    columns = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), TimeRemainingColumn()]
    with Progress(*columns, console=console, transient=False) as progress:
        shown = [RunProgress(progress, scenario, many=len(todo) > 1) for scenario, _ in todo]
        jobs_task = progress.add_task("jobs", total=0)

        def on_jobs(counts: dict[str, int]) -> None:
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
            raise Interrupted(how_to_finish(shown, again)) from None
    report_outcomes(shown, outcomes)


def how_to_finish(shown: list[RunProgress], again: str | None) -> str:
    """The line of an interrupted command: ``again``, else the --resume of each unfinished run."""
    if again is not None:
        return f"interrupted; {again}"
    unfinished = [run.folder for run in shown if run.folder is not None and not (run.folder / "summary.json").is_file()]
    how = ", ".join(f"--resume {folder}" for folder in unfinished)
    return f"interrupted; finish the run{'s' if len(unfinished) > 1 else ''} with {how}" if how else "interrupted"


def report_outcomes(shown: list[RunProgress], outcomes: list[Outcome]) -> None:
    """Each run's summary and warnings, in order; then ``RunsFailed`` naming each failed run."""
    failures = []
    for run, outcome in zip(shown, outcomes, strict=True):
        if outcome.error is not None:  # its traceback goes to <run>/logs/error.log
            failures.append(run_error(run, outcome))
            continue
        run_dir = outcome.value
        if run_dir.failed_stages:
            stages = " and ".join(dict.fromkeys(stage for stage, _ in run_dir.failed_stages.values()))
            why = "; ".join(f"{name}: {why}" for name, (_, why) in run_dir.failed_stages.items())
            failures.append(f"{stages} stage failed, no trial counted ({why}); after fixing it: --resume {run_dir.root}")
            continue
        show_finished(run, run_dir)
    if failures:
        raise RunsFailed(failures)


def run_error(run: RunProgress, outcome: Outcome) -> str:
    """The line of a run that raised; its traceback is written to the run's logs/error.log."""
    exc = outcome.error
    if isinstance(exc, BenchError):  # refused (a folder another driver holds): its one line, nothing written
        return str(exc)
    message = f"run of {run.label} failed: {type(exc).__name__}: {exc}"
    if run.folder is not None:
        log = run.folder / "logs" / "error.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        log.write_text(outcome.traceback)
        message += f" (traceback in {log})"
    return message


def show_finished(run: RunProgress, run_dir: RunDir) -> None:
    """A finished run: its summary (or why no trial ran), its folder, its trials that failed in their worker."""
    from runners.results import read_json

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


def print_summary(run_dir: Path) -> None:
    """The summary table of a finished run (``reports.tables``), as wide as the terminal: columns are
    left out from the last (``COLUMNS`` order) until it fits, never cut; a line names those left out."""
    from reports.tables import COLUMNS, rows

    table_rows = rows(run_dir)
    kept, left_out = fitting_columns(COLUMNS, table_rows, console.width)
    table = Table(title=f"summary of {run_dir}", show_lines=False, title_justify="left")
    for key, title, width in kept:
        table.add_column(title, justify="left" if key in ("system", "failures") else "right", width=width)
    for row in table_rows:
        table.add_row(*[row[key] for key, _, _ in kept])
    console.print(table)
    if left_out:
        console.print(f"(not shown at {console.width} columns: {', '.join(t for _, t in left_out)}; the report has them)")


def fitting_columns(
    columns: list[tuple[str, str]], table_rows: list[dict[str, str]], width: int
) -> tuple[list[tuple[str, str, int]], list[tuple[str, str]]]:
    """The columns that fit ``width`` whole, in order from the first, each with its width (a rich
    table adds one space of padding each side and a border between columns); and those left out.
    A cell is never cut: a column is as wide as its widest cell, or the longest word of its title
    (titles wrap at spaces); failures wrap between reasons ("no_path 2,")."""
    kept: list[tuple[str, str, int]] = []
    used = 1
    for key, title in columns:
        cells = [row[key] for row in table_rows]
        if key == "failures":
            cells = [part + "," for cell in cells for part in cell.split(", ")]
        need = max([len(c) for c in cells] + [max(len(word) for word in title.split())])
        if used + need + 3 > width and len(kept) >= 2:
            break
        kept.append((key, title, need))
        used += need + 3
    names = [key for key, _, _ in kept]
    return kept, [(key, title) for key, title in columns if key not in names]
