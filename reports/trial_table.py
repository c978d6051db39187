"""The trials of each run, one line each: how long and how narrow their ground-truth shortest path
is, and how each system fared. Written as ``trials.md`` beside Table 1 and as a table under each
run in ``report.html``; Table 1's notes say each scenario's narrowest gap.

Narrowest gap (``narrowest_gap_m``, ``scenarios.gaps``): the room the trial's GT shortest path
leaves the robot beyond its radius, on each side, in the narrowest passage it goes through (a
door of free width w: w / 2 - radius); 1.0 means 1 m or more. A trial marked *narrow* is below
the scenario's margin and was run because its file allows it (``allow_narrow``). A run from
before gaps were measured shows "–".
"""

from __future__ import annotations

import html
from dataclasses import dataclass, field
from pathlib import Path

from reports.results import Run, TrialRecord

GAP_CAP_M = 1.0  # scenarios.schema.GAP_CAP_M: a gap this wide is reported as "1 m or more"

GAP_NOTE = (
    "Narrowest gap: the room a trial's ground-truth shortest path leaves the robot beyond its radius, on each "
    "side, in the narrowest passage it goes through (a door w wide: w / 2 - radius); ≥ 1 m is wide open. "
    "*narrow*: below the scenario's margin, run because the scenario file allows it (allow_narrow)."
)


@dataclass
class TrialLine:
    """One trial of one run: its reference path's figures and each system's outcome."""

    trial: int
    shortest_m: float | None = None
    narrowest_gap_m: float | None = None
    narrow: bool = False
    outcomes: dict[str, str] = field(default_factory=dict)  # system -> "ok 0.934" or the failure reason


def outcome(record: TrialRecord | None) -> str:
    if record is None:
        return "–"
    if record.success:
        return "ok" if record.efficiency is None else f"ok {record.efficiency:.3f}"
    return record.reason or "failed"


def trial_lines(run: Run) -> list[TrialLine]:
    """The run's trials in order: those of its ground truth and those recorded."""
    truth = run.ground_truth.trials if run.ground_truth is not None else {}
    records = {(r.system, r.trial): r for r in run.trials}
    lines = []
    for index in sorted(set(truth) | {r.trial for r in run.trials}):
        own = [records[(s, index)] for s in run.systems if (s, index) in records]
        gt = truth.get(index)
        gaps = ([gt.narrowest_gap_m] if gt is not None else []) + [r.narrowest_gap_m for r in own]
        lengths = ([gt.shortest_m] if gt is not None else []) + [r.shortest_m for r in own]
        lines.append(
            TrialLine(
                trial=index,
                shortest_m=next((v for v in lengths if v is not None), None),
                narrowest_gap_m=next((v for v in gaps if v is not None), None),
                narrow=(gt is not None and gt.narrow) or any(r.narrow for r in own),
                outcomes={s: outcome(records.get((s, index))) for s in run.systems},
            )
        )
    return lines


def gap_text(line: TrialLine) -> str:
    if line.narrowest_gap_m is None:
        return "–"
    text = "≥ 1" if line.narrowest_gap_m >= GAP_CAP_M - 1e-6 else f"{line.narrowest_gap_m:.3f}"
    return text + (" *narrow*" if line.narrow else "")


def cells(line: TrialLine, systems: list[str]) -> list[str]:
    length = "–" if line.shortest_m is None else f"{line.shortest_m:.2f}"
    return [str(line.trial), length, gap_text(line), *(line.outcomes.get(s, "–") for s in systems)]


def headers(systems: list[str]) -> list[str]:
    return ["trial", "shortest (m)", "narrowest gap (m)", *systems]


def markdown(runs: list[Run]) -> str:
    text = "# Trials: the reference path of each, and each system's outcome (ok: efficiency)\n\n"
    for run in runs:
        head = headers(run.systems)
        text += f"## {run.label}\n\n| " + " | ".join(head) + " |\n|" + "|".join("---" for _ in head) + "|\n"
        for line in trial_lines(run):
            text += "| " + " | ".join(c.replace("|", "\\|") for c in cells(line, run.systems)) + " |\n"
        text += "\n"
    return text + f"- {GAP_NOTE}\n"


def table_html(run: Run) -> str:
    """The run's trials as an HTML table (report.html, under the run's plots)."""
    e = html.escape
    head = "".join(f"<th>{e(h)}</th>" for h in headers(run.systems))
    body = []
    for line in trial_lines(run):
        tds = "".join(f"<td>{e(c.replace('*', ''))}</td>" for c in cells(line, run.systems))
        body.append(f'<tr class="{"narrow" if line.narrow else "trial"}">{tds}</tr>')
    return f'<table class="results trials"><thead><tr>{head}</tr></thead><tbody>{"".join(body)}</tbody></table>'


def gap_notes(runs: list[Run]) -> list[str]:
    """Per scenario, the narrowest gap any of its trials passes, and the trials run marked narrow."""
    notes = []
    by_scenario: dict[str, list[tuple[Run, TrialLine]]] = {}
    for run in runs:
        by_scenario.setdefault(run.scenario, []).extend((run, line) for line in trial_lines(run))
    for scenario, lines in by_scenario.items():
        measured = [(run, line) for run, line in lines if line.narrowest_gap_m is not None]
        if not measured:
            continue
        run, least = min(measured, key=lambda item: item[1].narrowest_gap_m or 0.0)
        margins = {m for r, _ in measured if r.ground_truth is not None and (m := r.ground_truth.trial_margin_m) is not None}
        margin = f"; the trials' margin: {', '.join(f'{m:g}' for m in sorted(margins))} m" if margins else ""
        narrow = sorted({line.trial for _, line in measured if line.narrow})
        marked = "none narrower."
        if narrow:
            marked = f"**{len(narrow)} trial(s) narrower, run marked narrow**: {', '.join(map(str, narrow))}."
        notes.append(
            f"{scenario}: the narrowest gap of its trials leaves the robot {gap_text(least).replace(' *narrow*', '')} m "
            f"beyond its radius on each side (trial {least.trial}){margin}; {marked}"
        )
    return notes


def write_trial_table(runs: list[Run], out: Path) -> list[Path]:
    """``trials.md`` of ``runs`` under ``out``."""
    path = out / "trials.md"
    path.write_text(markdown(runs), encoding="utf-8")
    return [path]
