"""``navtopo-bench report``: the tables, the plots and one self-contained HTML page of one or more runs.

Writes, under ``out`` (default: the first run's ``report/``)::

    table.md, table.csv, table.tex   Table 1 (reports/tables.py): one combined table for all runs
    plots/<name>.png, .svg            per run: maps over the GT map, trajectories, map growth;
                                      over all runs: planning time, efficiency (reports/plots.py)
    config.yaml                       the run's resolved configs, for the reproducing command
    report.html                       the table, the plots (embedded), each run's manifest and the
                                      command that reproduces it (reports/html.py)

With several runs, each run's own plots and its config go under a key naming it
(``<scenario>-<setting>-s<seed>``, with ``-2``, ``-3`` where two runs share it): ``plots/<key>/``
and ``config-<key>.yaml``. Everything is made from the results folders alone, so a report made
from a copied folder is byte for byte the one made from the original. Each run counts once: a
folder named twice, or a copy of a run named beside it, is left out with a note (``distinct_runs``).
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from pathlib import Path, PurePath
from typing import Any

import yaml

from reports.contents import Report, RunSection
from reports.failures import failure_plots
from reports.html import UNDECODED, shown, write_html
from reports.plots import PlotResult, groups_of, plot_efficiency, plot_planning, run_plots
from reports.results import Run, RunFormatError
from reports.tables import write_tables
from reports.trial_table import write_trial_table


def run_key(run: Run) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", f"{run.scenario}-{run.setting}-s{run.seed}")


def scenario_argument(run: Run, out: Path | None = None) -> str:
    """A bundled scenario by its name (its file is scenarios/bundled/<name>.yaml); else the run's
    own copy of the file (``scenario_copy``), relative to ``out`` (where the command is shown), so
    that the command works wherever the run folder goes; else (a run from before the copies) the
    file as the run read it."""
    info = run.manifest.scenario
    if info.file is None:
        return info.name
    path = PurePath(info.file)
    if path.parent.name == "bundled" and path.stem == info.name:
        return info.name
    copy = run.manifest.scenario_copy
    if copy is not None and (run.root / copy).is_file():
        return os.path.relpath(run.root / copy, out) if out is not None else str(run.root / copy)
    return info.file


def reproduce_command(run: Run, config_file: str, out: Path | None = None) -> str:
    """The ``navtopo-bench run`` line that repeats ``run``, run from ``out`` (the report's folder):
    the same scenario, systems, seed, trial count, setting and protocol, and its resolved configs
    (``--config``, relative to the report)."""
    m = run.manifest
    p = m.protocol
    parts = ["navtopo-bench", "run", _quote(scenario_argument(run, out)), "--systems", ",".join(m.systems), "--seed", str(m.seed)]
    if m.trial_count is not None:
        parts += ["--trials", str(m.trial_count)]
    if m.setting_override:
        parts += ["--setting", m.setting_override]
    parts += ["--initial-pose-error", f"{p.initial_pose_error_xy:g},{p.initial_pose_error_yaw_deg:g}"]
    parts += ["--stop-tolerance", f"{p.stop_tolerance:g}"]
    if p.goals != "map":
        parts += ["--goals", p.goals]
    if p.initial_pose != "perturbed":
        parts += ["--initial-pose", p.initial_pose]
    if m.config:
        parts += ["--config", config_file]
    return " ".join(parts)


def _quote(text: str) -> str:
    """``text`` as one shell word; a file name that is not UTF-8 in bash's $'...', whose \\xNN
    give back its very bytes."""
    if re.fullmatch(r"[A-Za-z0-9_./:=,+-]+", text):
        return text
    if UNDECODED.search(text):
        return "$'" + shown(text.replace("\\", "\\\\").replace("'", "\\'")) + "'"
    return "'" + text.replace("'", "'\\''") + "'"


Study = Callable[[list[Run], Path], list[PlotResult]]


def distinct_runs(run_dirs: list[Path]) -> tuple[list[Run], list[str]]:
    """Every run once, loaded (``RunFormatError`` on a damaged folder), and a note for each left
    out: a folder named twice (``results/tiny/*`` names ``latest`` beside the run it points to) or a
    copy of a run named before it. A copy is the same run: the same manifest, down to the second it
    was created, the revision and the machine; pooling it would count its trials twice. A copy
    whose trials differ from the original's (it went on apart) is refused: which one counts is
    the user's choice."""
    runs: list[Run] = []
    notes: list[str] = []
    for run_dir in run_dirs:
        named = next((r for r in runs if r.root.resolve() == Path(run_dir).resolve()), None)
        if named is not None:
            notes.append(f"{run_dir} is the run folder {named.root}: counted once")
            continue
        run = Run.load(run_dir)
        if run.repeated:
            notes.append(repeated_note(run))
        copied = next((r for r in runs if r.manifest.created is not None and r.manifest == run.manifest), None)
        if copied is None:
            runs.append(run)
            continue
        same = f"the same manifest as {copied.root}, created {copied.manifest.created}"
        if copied.trials != run.trials:
            raise RunFormatError(f"{run_dir}: a copy of the run in {copied.root} ({same}) with other trials: report one of them")
        notes.append(f"{run_dir} is a copy of the run in {copied.root} ({same}): counted once")
    return runs, notes


def repeated_note(run: Run) -> str:
    """The line of a run whose trials.jsonl holds a trial more than once (two drivers wrote it)."""
    counts: dict[tuple[Any, Any], int] = {}
    for key in run.repeated:
        counts[key] = counts.get(key, 1) + 1
    which = ", ".join(f"{system} trial {trial} ({n} records)" for (system, trial), n in counts.items())
    return f"{run.root / 'trials.jsonl'}: {which}: the first record of each is counted (two drivers wrote this folder)"


def make_report(run_dirs: list[Path], out: Path | None = None, study: Study | None = None, study_title: str = "") -> Report:
    """Load every run once (``distinct_runs``; ``RunFormatError`` on a damaged folder, before
    anything is written) and write the report under ``out`` (default ``run_dirs[0]/report``). ``study(runs, out)`` (e.g.
    ``reports.sweep.write_scaling``) adds its files and plots, shown first on the page."""
    runs, left_out = distinct_runs(run_dirs)
    out = Path(out) if out is not None else Path(run_dirs[0]) / "report"
    out.mkdir(parents=True, exist_ok=True)
    files = write_tables(runs, out) + write_trial_table(runs, out)
    plots_dir = out / "plots"
    several = len(runs) > 1
    keys: dict[str, int] = {}
    sections = []
    for run in runs:
        key = run_key(run)
        keys[key] = keys.get(key, 0) + 1
        if keys[key] > 1:
            key = f"{key}-{keys[key]}"
        config_file = f"config-{key}.yaml" if several else "config.yaml"
        (out / config_file).write_text(yaml.safe_dump(run.manifest.config, sort_keys=False), encoding="utf-8")
        files.append(out / config_file)
        section = RunSection(run, key, config_file=config_file, command=reproduce_command(run, config_file, out))
        section.plots = run_plots(run, plots_dir / key if several else plots_dir, combined=not several)
        section.failures = failure_plots(run, (plots_dir / key if several else plots_dir) / "failures")
        sections.append(section)
    combined: list[PlotResult] = []
    if several:
        groups = groups_of(runs)
        combined = [plot_planning(groups, plots_dir), plot_efficiency(groups, plots_dir)]
    for plot in [p for s in sections for p in s.plots] + combined:
        files += plot.files
    study_plots = study(runs, out) if study is not None else []
    for plot in study_plots:
        files += plot.files
    report = Report(out, sections, combined, files, study_plots, study_title, left_out)
    write_html(report)
    report.files.append(report.html)
    return report
