"""Table 1 of the paper for one or more runs: Markdown, CSV and LaTeX. Reads only results folders.

One row per (scenario, setting, system); runs of the same scenario and setting (seeds) are pooled:
success, efficiency, SPL and planning times over all their trials, memory as the largest of the
runs (the summary's parts are already peaks over trials), mapping ms/scan as the median of the
runs' medians. 95 % bootstrap intervals (``reports.stats``, seeded) where a figure rests on at
least 5 trials. The paper's figures follow on rows marked as the paper's.

Definitions (docs/DESIGN.md, "Measurement definitions"): memory = the breakdown's total (map +
localization + derived + model, exact bytes) and its parts, the saved map on disk, the worker's
RSS growth from before loading the map to after the first plan, and its whole RSS then; planning
time = the first start-to-goal plan of each trial and every planning call (median, p95);
efficiency = shortest / travelled over successful trials, SPL over all trials. Failures are
counted by reason and, within each, by the stage the trial failed in (``failure_stage``:
``no_path 3 (local_plan 2, global_plan 1)``; a run recorded before stages were shows reasons alone).
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from reports import failures
from reports.results import MEMORY_PARTS, Run
from reports.stats import bootstrap, bootstrap_pooled
from reports.trial_table import gap_notes

Interval = tuple[float, float] | None


@dataclass
class Row:
    """One line of Table 1: measured (``source == "measured"``) or quoted from the paper."""

    scenario: str
    setting: str
    system: str
    source: str = "measured"
    pooled: bool = False  # every scene of the table in this setting, pooled (a report of several scenes)
    seeds: list[int] = field(default_factory=list)
    trials: int = 0
    successes: int = 0
    failure_reasons: dict[str, int] = field(default_factory=dict)
    failure_stages_by_reason: dict[str, dict[str, int]] = field(default_factory=dict)  # {reason: {stage: count}}
    success_rate: float | None = None
    success_rate_ci: Interval = None
    efficiency: float | None = None
    efficiency_ci: Interval = None
    efficiency_after_startup: float | None = None  # from where each trial's start-up committed
    startup: dict[str, float | int | None] = field(default_factory=dict)  # right, wrong, seconds and metres (medians)
    spl: float | None = None
    spl_ci: Interval = None
    first_plan_ms_median: float | None = None
    first_plan_ms_median_ci: Interval = None
    first_plan_ms_p95: float | None = None
    planning_ms_median: float | None = None
    planning_ms_median_ci: Interval = None
    planning_ms_p95: float | None = None
    planning_calls: int = 0
    memory: dict[str, int | None] = field(default_factory=dict)  # map, localization, derived, model, total
    disk_bytes: int | None = None
    rss_bytes: int | None = None
    rss_process_bytes: int | None = None
    map_load_ms: float | None = None
    mapping_ms_per_scan_median: float | None = None
    mapping_ms_per_scan_p95: float | None = None
    note: str = ""

    @property
    def paper(self) -> bool:
        return self.source == "paper"


PAPER_SOURCE = "paper: Table 1 (Habitat, 150 m branched corridor)"
PAPER_ROWS = [
    Row(
        scenario="paper",
        setting="paper",
        system="NavTopo (paper)",
        source="paper",
        memory={"total": 57_000_000},
        planning_ms_median=6.0,
        efficiency=0.89,
        note=PAPER_SOURCE,
    ),
    Row(
        scenario="paper",
        setting="paper",
        system="RTAB-MAP + Theta* (paper)",
        source="paper",
        memory={"total": 352_000_000},
        planning_ms_median=830.0,
        efficiency=0.95,
        note=PAPER_SOURCE,
    ),
]


def _median(values: list[float]) -> float | None:
    return float(np.median(values)) if values else None


def _percentile(values: list[float], q: float) -> float | None:
    return float(np.percentile(values, q)) if values else None


def _max(values: list[int | None]) -> int | None:
    kept = [v for v in values if v is not None]
    return max(kept) if kept else None


def measured_rows(runs: list[Run]) -> list[Row]:
    """The measured rows, in the order scenarios, settings and systems first appear in ``runs``; where
    a setting holds several scenes, then a pooled row per system over all of them (``pooled_name``)."""
    groups: dict[tuple[str, str, str], list[Run]] = {}
    for run in runs:
        for system in run.systems:
            groups.setdefault((run.scenario, run.setting, system), []).append(run)
    rows = [_row(scenario, setting, system, members) for (scenario, setting, system), members in groups.items()]
    pools: dict[tuple[str, str], list[Run]] = {}
    for run in runs:
        for system in run.systems:
            pools.setdefault((run.setting, system), []).append(run)
    for (setting, system), members in pools.items():
        scenes = dict.fromkeys(run.scenario for run in members)
        if len(scenes) > 1:
            row = _row(pooled_name(len(scenes)), setting, system, members)
            row.pooled = True
            rows.append(row)
    return rows


def pooled_name(scenes: int) -> str:
    """The scenario cell of a pooled row."""
    return f"all {scenes} scenes"


def _row(scenario: str, setting: str, system: str, runs: list[Run]) -> Row:
    records = [r for run in runs for r in run.trials_of(system)]
    successes = [r for r in records if r.success]
    failures: dict[str, int] = {}
    stages: dict[str, dict[str, int]] = {}
    for r in records:
        if not r.success:
            failures[r.reason or "failed"] = failures.get(r.reason or "failed", 0) + 1
            if r.failure_stage:
                counts = stages.setdefault(r.reason or "failed", {})
                counts[r.failure_stage] = counts.get(r.failure_stage, 0) + 1
    efficiencies = [r.efficiency for r in successes if r.efficiency is not None]
    after = [r.efficiency_after_startup for r in successes if r.efficiency_after_startup is not None]
    startups = [r.startup_localization for r in records if r.startup_localization]
    first = [r.first_plan_ms for r in records if r.first_plan_ms is not None]
    per_trial_calls = [r.planning_ms_samples for r in records if r.planning_ms_samples]
    calls = [v for samples in per_trial_calls for v in samples]
    summaries = [run.summary[system] for run in runs if system in run.summary]
    memory = {part: _max([s.memory.model_dump().get(part) for s in summaries]) for part in (*MEMORY_PARTS, "total")}
    mapping = [run.mapping.get(system) for run in runs]
    scans = [m.ms_per_scan for m in mapping if m is not None and m.ms_per_scan is not None]
    scan_medians = [s.median for s in scans if s.median is not None]
    scan_p95 = [s.p95 for s in scans if s.p95 is not None]
    errors = [m.error for m in mapping if m is not None and m.error]
    return Row(
        scenario=scenario,
        setting=setting,
        system=system,
        seeds=sorted({run.seed for run in runs}),
        trials=len(records),
        successes=len(successes),
        failure_reasons=dict(sorted(failures.items(), key=lambda kv: (-kv[1], kv[0]))),
        failure_stages_by_reason={reason: _by_count(counts) for reason, counts in stages.items()},
        success_rate=len(successes) / len(records) if records else None,
        success_rate_ci=bootstrap([1.0 if r.success else 0.0 for r in records]),
        efficiency=float(np.mean(efficiencies)) if efficiencies else None,
        efficiency_ci=bootstrap(efficiencies),
        efficiency_after_startup=float(np.mean(after)) if after else None,
        startup=(
            {
                "right": sum(1 for s in startups if s.get("right")),
                "wrong": sum(1 for s in startups if not s.get("right")),
                "seconds": _median([s["seconds"] for s in startups if s.get("seconds") is not None]),
                "metres": _median([s["metres"] for s in startups if s.get("metres") is not None]),
            }
            if startups
            else {}
        ),
        spl=float(np.mean([r.spl for r in records])) if records else None,
        spl_ci=bootstrap([r.spl for r in records]),
        first_plan_ms_median=_median(first),
        first_plan_ms_median_ci=bootstrap(first, "median"),
        first_plan_ms_p95=_percentile(first, 95),
        planning_ms_median=_median(calls),
        planning_ms_median_ci=bootstrap_pooled(per_trial_calls, 50.0),
        planning_ms_p95=_percentile(calls, 95),
        planning_calls=len(calls),
        memory=memory,
        disk_bytes=_max([s.memory.disk_bytes for s in summaries]),
        rss_bytes=_max([s.memory.rss_bytes for s in summaries]),
        rss_process_bytes=_max([s.memory.rss_process_bytes for s in summaries]),
        map_load_ms=_median([s.map_load_ms for s in summaries if s.map_load_ms is not None]),
        mapping_ms_per_scan_median=_median(scan_medians),
        mapping_ms_per_scan_p95=_median(scan_p95),
        note=("mapping failed: " + errors[0]) if errors else "",
    )


def _by_count(counts: dict[str, int]) -> dict[str, int]:
    return dict(sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))


def table_rows(runs: list[Run], with_paper: bool = True) -> list[Row]:
    return measured_rows(runs) + (list(PAPER_ROWS) if with_paper else [])


# ---------------------------------------------------------------------------------------------
# formatting


def mb(value: float | None, digits: int = 2) -> str:
    return f"{value / 1e6:.{digits}f}" if value is not None else "–"


def num(value: float | None, digits: int = 3) -> str:
    return f"{value:.{digits}f}" if value is not None else "–"


def ms(value: float | None) -> str:
    if value is None:
        return "–"
    return f"{value:.0f}" if value >= 100 else f"{value:.1f}" if value >= 10 else f"{value:.2f}"


def with_ci(text: str, ci: Interval, fmt) -> str:
    return text if ci is None or text == "–" else f"{text} [{fmt(ci[0])}, {fmt(ci[1])}]"


def failures_text(row: Row) -> str:
    """``no_path 3 (local_plan 2, global_plan 1), collision 1 (follower 1)``: each reason, then the
    stages its trials failed in (where the records name them)."""
    parts = []
    for reason, count in row.failure_reasons.items():
        stages = row.failure_stages_by_reason.get(reason)
        where = f" ({', '.join(f'{stage} {n}' for stage, n in stages.items())})" if stages else ""
        parts.append(f"{reason} {count}{where}")
    return ", ".join(parts) or "none"


def startup_text(row: Row) -> str:
    """``19 right, 0 wrong; 0.0 s, 0.00 m; 0.991``: the start-ups checked against the truth, the
    median seconds and metres driven before each, and the efficiency from where each committed."""
    s = row.startup
    if not s:
        return "–"
    seconds = "–" if s.get("seconds") is None else f"{s['seconds']:.1f} s"
    metres = "–" if s.get("metres") is None else f"{s['metres']:.2f} m"
    return f"{s['right']} right, {s['wrong']} wrong; {seconds}, {metres}; {num(row.efficiency_after_startup)}"


def stage_totals(row: Row) -> dict[str, int]:
    """Failures by stage over every reason, most first."""
    totals: dict[str, int] = {}
    for stages in row.failure_stages_by_reason.values():
        for stage, count in stages.items():
            totals[stage] = totals.get(stage, 0) + count
    return _by_count(totals)


def cells(row: Row) -> dict[str, str]:
    """The human-readable cells of a row (Markdown, HTML, LaTeX)."""
    if row.paper:
        return {
            "scenario": "*the paper*",
            "setting": "Habitat",
            "system": row.system,
            "success": "–",
            "failures": "–",
            "efficiency": num(row.efficiency, 2),
            "startup": "–",
            "spl": "–",
            "first_plan": "–",
            "planning": f"{ms(row.planning_ms_median)}",
            "memory": f"{mb(row.memory.get('total'), 0)}",
            "disk": "–",
            "rss": "–",
            "mapping": "–",
        }
    m = row.memory
    parts = " / ".join(mb(m.get(p)) for p in MEMORY_PARTS)
    rate = f"{row.successes}/{row.trials}"
    if row.success_rate is not None:
        rate += f" ({100 * row.success_rate:.0f} %)"
    if row.success_rate_ci is not None:
        rate += f" [{100 * row.success_rate_ci[0]:.0f}, {100 * row.success_rate_ci[1]:.0f}] %"
    return {
        "scenario": row.scenario,
        "setting": row.setting,
        "system": row.system,
        "success": rate,
        "failures": failures_text(row),
        "efficiency": with_ci(num(row.efficiency), row.efficiency_ci, lambda v: f"{v:.3f}"),
        "startup": startup_text(row),
        "spl": with_ci(num(row.spl), row.spl_ci, lambda v: f"{v:.3f}"),
        "first_plan": with_ci(ms(row.first_plan_ms_median), row.first_plan_ms_median_ci, ms) + f" / {ms(row.first_plan_ms_p95)}",
        "planning": with_ci(ms(row.planning_ms_median), row.planning_ms_median_ci, ms) + f" / {ms(row.planning_ms_p95)}",
        "memory": f"{mb(m.get('total'))} ({parts})",
        "disk": mb(row.disk_bytes),
        "rss": f"{mb(row.rss_bytes)} / {mb(row.rss_process_bytes, 0)}",
        "mapping": f"{ms(row.mapping_ms_per_scan_median)} / {ms(row.mapping_ms_per_scan_p95)}",
    }


HEADERS = {
    "scenario": "scenario",
    "setting": "setting",
    "system": "system",
    "success": "success [95 % CI]",
    "failures": "failures (by stage)",
    "efficiency": "efficiency [95 % CI]",
    "startup": "start-up: right, wrong; median s, m driven; efficiency after it",
    "spl": "SPL [95 % CI]",
    "first_plan": "first plan ms: median [95 % CI] / p95",
    "planning": "planning ms, all calls: median [95 % CI] / p95",
    "memory": "memory MB: total (map / localization / derived / model)",
    "disk": "map on disk MB",
    "rss": "RSS MB: growth / process",
    "mapping": "mapping ms/scan: median / p95",
}


def markdown(rows: list[Row]) -> str:
    keys = list(HEADERS)
    lines = ["| " + " | ".join(HEADERS[k] for k in keys) + " |", "|" + "|".join("---" for _ in keys) + "|"]
    for row in rows:
        c = cells(row)
        lines.append("| " + " | ".join(c[k].replace("|", "\\|") for k in keys) + " |")
    return "\n".join(lines) + "\n"


NOTES = [
    "Measured rows: this benchmark's own figures; runs of one scenario and setting (seeds) pooled.",
    "Intervals: 95 % percentile bootstrap (2000 resamples, fixed seed) where a figure rests on >= 5 trials; "
    "planning over all calls resamples whole trials.",
    "Memory: exact bytes of the data structures a system keeps to navigate, the largest at any trial; "
    "RSS growth: a fresh worker from before loading its map to after its first plan; process: its whole RSS.",
    "Rows marked *the paper* quote Muravyev & Yakovlev's Table 1 (Habitat, their machine; map memory, "
    "planning time, efficiency); they are not measured here.",
]


def markdown_document(rows: list[Row], notes: list[str] | None = None) -> str:
    text = "# Table 1: memory, planning time and efficiency\n\n" + markdown(rows) + "\n"
    for note in NOTES + list(notes or []):
        text += f"- {note.strip()}\n"
    return text


CSV_FIELDS = [
    "scenario",
    "setting",
    "system",
    "source",
    "seeds",
    "trials",
    "successes",
    "success_rate",
    "success_rate_ci_low",
    "success_rate_ci_high",
    "failure_reasons",
    "failure_stages",
    "efficiency",
    "efficiency_ci_low",
    "efficiency_ci_high",
    "spl",
    "spl_ci_low",
    "spl_ci_high",
    "first_plan_ms_median",
    "first_plan_ms_median_ci_low",
    "first_plan_ms_median_ci_high",
    "first_plan_ms_p95",
    "planning_ms_median",
    "planning_ms_median_ci_low",
    "planning_ms_median_ci_high",
    "planning_ms_p95",
    "planning_calls",
    "memory_total_mb",
    *(f"memory_{p}_mb" for p in MEMORY_PARTS),
    "disk_mb",
    "rss_growth_mb",
    "rss_process_mb",
    "map_load_ms",
    "mapping_ms_per_scan_median",
    "mapping_ms_per_scan_p95",
    "note",
    "efficiency_after_startup",
    "startup_right",
    "startup_wrong",
    "startup_seconds_median",
    "startup_metres_median",
]


def _csv_value(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def csv_rows(rows: list[Row]) -> list[dict[str, str]]:
    out = []
    for row in rows:
        record = {
            "scenario": row.scenario,
            "setting": row.setting,
            "system": row.system,
            "source": row.source,
            "seeds": ";".join(str(s) for s in row.seeds),
            "trials": row.trials if not row.paper else None,
            "successes": row.successes if not row.paper else None,
            "success_rate": row.success_rate,
            "failure_reasons": ";".join(f"{k}:{v}" for k, v in row.failure_reasons.items()),
            "failure_stages": ";".join(f"{k}:{v}" for k, v in stage_totals(row).items()),
            "efficiency": row.efficiency,
            "spl": row.spl,
            "first_plan_ms_median": row.first_plan_ms_median,
            "first_plan_ms_p95": row.first_plan_ms_p95,
            "planning_ms_median": row.planning_ms_median,
            "planning_ms_p95": row.planning_ms_p95,
            "planning_calls": row.planning_calls if not row.paper else None,
            "memory_total_mb": None if (total := row.memory.get("total")) is None else total / 1e6,
            "disk_mb": None if row.disk_bytes is None else row.disk_bytes / 1e6,
            "rss_growth_mb": None if row.rss_bytes is None else row.rss_bytes / 1e6,
            "rss_process_mb": None if row.rss_process_bytes is None else row.rss_process_bytes / 1e6,
            "map_load_ms": row.map_load_ms,
            "mapping_ms_per_scan_median": row.mapping_ms_per_scan_median,
            "mapping_ms_per_scan_p95": row.mapping_ms_per_scan_p95,
            "note": row.note,
            "efficiency_after_startup": row.efficiency_after_startup,
            "startup_right": row.startup.get("right"),
            "startup_wrong": row.startup.get("wrong"),
            "startup_seconds_median": row.startup.get("seconds"),
            "startup_metres_median": row.startup.get("metres"),
        }
        for part in MEMORY_PARTS:
            value = row.memory.get(part)
            record[f"memory_{part}_mb"] = None if value is None else value / 1e6
        for name in ("success_rate", "efficiency", "spl", "first_plan_ms_median", "planning_ms_median"):
            ci = getattr(row, f"{name}_ci")
            record[f"{name}_ci_low"], record[f"{name}_ci_high"] = (None, None) if ci is None else ci
        out.append({k: _csv_value(record.get(k)) for k in CSV_FIELDS})
    return out


def to_csv(rows: list[Row]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=CSV_FIELDS, lineterminator="\n")
    writer.writeheader()
    writer.writerows(csv_rows(rows))
    return buffer.getvalue()


def _tex(text: str) -> str:
    for a, b in (
        ("\\", r"\textbackslash{}"),
        ("&", r"\&"),
        ("%", r"\%"),
        ("_", r"\_"),
        ("#", r"\#"),
        ("–", "--"),
        ("·", r"$\cdot$"),
    ):
        text = text.replace(a, b)
    return text


def latex(rows: list[Row]) -> str:
    """A booktabs table (``\\usepackage{booktabs}``): measured rows, then the paper's in italics."""
    keys = ["system", "setting", "success", "efficiency", "spl", "first_plan", "planning", "memory", "rss"]
    heads = {
        "system": "System",
        "setting": "Setting",
        "success": "Success",
        "efficiency": "Efficiency",
        "spl": "SPL",
        "first_plan": "First plan (ms)",
        "planning": "Planning (ms)",
        "memory": "Memory (MB)",
        "rss": "RSS growth (MB)",
    }
    scenarios = list(dict.fromkeys(r.scenario for r in rows if not r.paper))
    lines = [
        r"\begin{table}[t]",
        r"\centering",
        r"\small",
        r"\begin{tabular}{ll" + "r" * (len(keys) - 2) + "}",
        r"\toprule",
        " & ".join(heads[k] for k in keys) + r" \\",
        r"\midrule",
    ]
    for scenario in scenarios:
        if len(scenarios) > 1:
            lines.append(rf"\multicolumn{{{len(keys)}}}{{l}}{{\textit{{{_tex(scenario)}}}}} \\")
        for row in (r for r in rows if r.scenario == scenario and not r.paper):
            lines.append(" & ".join(_tex(v) for v in _latex_cells(row, keys)) + r" \\")
    paper = [r for r in rows if r.paper]
    if paper:
        lines.append(r"\midrule")
        for row in paper:
            lines.append(" & ".join(r"\textit{" + _tex(v) + "}" if v else "" for v in _latex_cells(row, keys)) + r" \\")
    lines += [
        r"\bottomrule",
        r"\end{tabular}",
        r"\caption{Memory, planning time and efficiency"
        + (f" on {_tex(', '.join(scenarios))}" if scenarios else "")
        + r". Success: trials reached; efficiency and SPL: means over trials (efficiency over each system's own "
        r"successes, SPL over every trial, 0 for a failure); planning times: medians (first plan of each trial, and "
        r"every call) and p95, with 95\,\% bootstrap intervals where $\geq 5$ trials; memory: the exact bytes a system "
        r"keeps to navigate, the largest at any trial. Italic rows: the paper's Table~1 (Habitat), not measured here.}",
        r"\label{tab:navtopo-bench}",
        r"\end{table}",
    ]
    return "\n".join(lines) + "\n"


def _latex_cells(row: Row, keys: list[str]) -> list[str]:
    if row.paper:
        c = cells(row)
        return [c["system"], "Habitat", "", c["efficiency"], "", "", c["planning"], c["memory"], ""]
    c = {
        "system": row.system,
        "setting": row.setting,
        "success": f"{row.successes}/{row.trials}",
        "efficiency": with_ci(num(row.efficiency, 2), row.efficiency_ci, lambda v: f"{v:.2f}"),
        "spl": num(row.spl, 2),
        "first_plan": with_ci(ms(row.first_plan_ms_median), row.first_plan_ms_median_ci, ms),
        "planning": f"{ms(row.planning_ms_median)} / {ms(row.planning_ms_p95)}",
        "memory": mb(row.memory.get("total"), 1),
        "rss": mb(row.rss_bytes, 1),
    }
    return [c[k] for k in keys]


# ---------------------------------------------------------------------------------------------
# the comparison with the paper, in words


@dataclass
class Paired:
    """NavTopo against the metric baseline on the trials both ran (one scenario and setting, its
    runs pooled): success two by two, and the per-trial SPL difference NavTopo - metric."""

    trials: int
    both: int  # reached by both
    topo_only: int
    metric_only: int
    neither: int
    spl_difference: float | None  # mean over the trials of NavTopo's SPL - the baseline's
    spl_difference_ci: Interval = None


def paired(runs: list[Run], scenario: str | None, setting: str) -> Paired | None:
    """``Paired`` over the trials of ``scenario`` (None: every scene) in ``setting`` that both NavTopo
    and the metric baseline ran (a trial of a run counted once); None if there is none."""
    pairs = []
    for run in runs:
        if (scenario is not None and run.scenario != scenario) or run.setting != setting:
            continue
        topo = {r.trial: r for r in run.trials_of("navtopo")}
        metric = {r.trial: r for r in run.trials_of("metric_grid")}
        pairs += [(topo[t], metric[t]) for t in sorted(set(topo) & set(metric))]
    if not pairs:
        return None
    differences = [float(a.spl) - float(b.spl) for a, b in pairs]
    return Paired(
        trials=len(pairs),
        both=sum(a.success and b.success for a, b in pairs),
        topo_only=sum(a.success and not b.success for a, b in pairs),
        metric_only=sum(b.success and not a.success for a, b in pairs),
        neither=sum(not a.success and not b.success for a, b in pairs),
        spl_difference=float(np.mean(differences)),
        spl_difference_ci=bootstrap(differences, "mean"),
    )


def _paired_text(p: Paired) -> str:
    """The paired note: success two by two and the SPL difference, and whether it tells the order."""
    ci = p.spl_difference_ci
    interval = f" [{ci[0]:+.3f}, {ci[1]:+.3f}]" if ci is not None else " (no interval: under 5 trials)"
    text = (
        f"Paired over the {p.trials} trials both ran: both reached {p.both}, NavTopo alone {p.topo_only}, the metric "
        f"baseline alone {p.metric_only}, neither {p.neither}; SPL NavTopo - metric {p.spl_difference:+.3f}{interval}. "
    )
    if ci is None or ci[0] <= 0.0 <= ci[1]:
        return text + "The interval holds both orders: this run does not tell them apart. "
    if ci[1] < 0.0:
        return text + "The same order as the paper's (the metric baseline ahead). "
    return text + "**Differs from the paper**: NavTopo ahead, and the interval excludes the paper's order. "


def paper_comparison(rows: list[Row], runs: list[Run] | None = None) -> list[str]:
    """Per scenario and setting holding NavTopo and the metric baseline: does our comparison agree
    in kind with the paper's (NavTopo smaller and faster, the metric baseline more efficient)? The
    efficiency is judged on the trials both ran, paired (``paired``), where ``runs`` are given: the
    means of each system's own successes compare different trials."""
    notes = []
    keyed = {(r.scenario, r.setting, r.system): r for r in rows if not r.paper}
    for scenario, setting in dict.fromkeys((r.scenario, r.setting) for r in rows if not r.paper):
        topo, metric = keyed.get((scenario, setting, "navtopo")), keyed.get((scenario, setting, "metric_grid"))
        if topo is None or metric is None:
            continue
        where = f"{scenario} ({setting})"
        memory_a, memory_b = topo.memory.get("total"), metric.memory.get("total")
        if memory_a and memory_b:
            notes.append(
                f"{where}, memory: NavTopo {memory_a / 1e6:.2f} MB (of which its place-recognition weights "
                f"{mb(topo.memory.get('model'))} MB) vs the metric baseline {memory_b / 1e6:.2f} MB; the paper: 57 vs 352 MB. "
                + _agreement(memory_a < memory_b)
                + "Ours are exact bytes of the structures kept to navigate; the paper does not define its figure so."
            )
        a, b = topo.planning_ms_median, metric.planning_ms_median
        if a and b:
            notes.append(
                f"{where}, planning time (median over all calls): NavTopo {ms(a)} ms vs the metric baseline {ms(b)} ms "
                f"({b / a:.1f}×); the paper: 6 vs 830 ms (138×). " + _agreement(a < b)
            )
        a, b = topo.efficiency, metric.efficiency
        pooled = topo.pooled and metric.pooled
        pair = paired(runs, None if pooled else scenario, setting) if runs is not None else None
        if a is not None and b is not None:
            judged = _paired_text(pair) if pair is not None else _agreement(a < b)
            notes.append(
                f"{where}, efficiency (mean over each system's own successes): NavTopo {a:.3f} vs the metric baseline "
                f"{b:.3f}; the paper: 0.89 vs 0.95 (the metric baseline ahead). Success: {topo.successes}/{topo.trials} "
                f"vs {metric.successes}/{metric.trials}. " + judged
            )
    return notes


def rtabmap_notes(runs: list[Run]) -> list[str]:
    """Per run whose metric baseline mapped (not reused maps): what an RTAB-MAP-style system would
    keep of the same mapping run (``rtabmap_style_bytes`` of ``mapping/metric_grid.json``), apart
    from the baseline's memory: the paper's 352 MB is of that kind."""
    notes = []
    for run in runs:
        mapping = run.mapping.get("metric_grid")
        extra = (mapping.model_extra or {}) if mapping is not None else {}
        kept, raw = extra.get("rtabmap_style_bytes"), extra.get("raw_cloud_bytes")
        if not kept or mapping is None or mapping.maps_from:
            continue
        notes.append(
            f"{run.scenario} ({run.setting}), an RTAB-MAP-style map of the same mapping run: {mb(kept)} MB, its "
            f"{extra.get('keyframes', '?')} keyframes' raw lidar clouds ({mb(raw)} MB, float32 x, y, z), their 2D scans, the "
            "pose graph and the grid (mapping/metric_grid.json, `rtabmap_style_bytes`). What a metric system that keeps its "
            "keyframes' raw data stores, to relate the suite's figures to the paper's 352 MB; not the metric baseline's "
            "memory above, which keeps the grid alone to navigate."
        )
    return notes


def _agreement(same_order: bool) -> str:
    return "The same order as the paper's. " if same_order else "**Differs from the paper**: the order is reversed. "


# ---------------------------------------------------------------------------------------------
# the rich table the CLI prints after a run (runners/cli.py, print_summary)

# in the order the terminal keeps them when it is narrow (``runners.commands.progress.print_summary``)
COLUMNS = [
    ("system", "system"),
    ("success", "success"),
    ("failures", "failures"),
    ("efficiency", "efficiency"),
    ("spl", "SPL"),
    ("first_plan_ms", "first plan median (ms)"),
    ("planning_median_ms", "planning median (ms)"),
    ("planning_p95_ms", "planning p95 (ms)"),
    ("memory_mb", "memory total (MB)"),
    ("map_mb", "map (MB, exact)"),
    ("disk_mb", "map on disk (MB)"),
    ("rss_mb", "RSS growth (MB)"),
    ("mapping_ms_per_scan", "mapping (ms/scan)"),
]


def rows(run_dir: Path) -> list[dict[str, str]]:
    """One run's summary as the strings of ``COLUMNS`` (the CLI's table after a run)."""
    run = Run.load(run_dir)
    out = []
    for name, s in run.summary.items():
        out.append(
            {
                "system": name,
                "success": f"{s.successes}/{s.trials}",
                "failures": ", ".join(f"{reason} {n}" for reason, n in _by_count(s.failure_reasons).items()) or "–",
                "efficiency": num(s.efficiency_mean),
                "spl": num(s.spl_mean),
                "first_plan_ms": num(s.first_plan_ms.median, 2),
                "planning_median_ms": num(s.planning_ms.median, 2),
                "planning_p95_ms": num(s.planning_ms.p95, 2),
                "memory_mb": mb(s.memory.total),
                "map_mb": mb(s.memory.map_bytes),
                "disk_mb": mb(s.memory.disk_bytes),
                "rss_mb": mb(s.memory.rss_bytes),
                "mapping_ms_per_scan": num(s.mapping_ms_per_scan.median if s.mapping_ms_per_scan else None, 2),
            }
        )
    return out


def write_tables(runs: list[Run], out: Path) -> list[Path]:
    """table.md, table.csv and table.tex of ``runs`` (one combined table) under ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    table = table_rows(runs)
    files = [out / "table.md", out / "table.csv", out / "table.tex"]
    document = markdown_document(table, paper_comparison(table, runs) + rtabmap_notes(runs) + gap_notes(runs))
    files[0].write_text(document + "\n" + failures.markdown(runs), encoding="utf-8")
    files[1].write_text(to_csv(table), encoding="utf-8")
    files[2].write_text(latex(table), encoding="utf-8")
    return files
