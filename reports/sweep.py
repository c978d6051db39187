"""The scaling study, from its run folders alone: planning time and every memory part against the
environment size (the scenario's corridor length in each manifest), log-log, with fitted growth
exponents (``figure ≈ c · length^k``, least squares on the logarithms).

Each run contributes one point per system: planning over every call (median) and the first plan
of each trial (median) from its trials; the memory breakdown (map, localization, derived, model,
total: the largest at any trial), RSS growth and the saved map's bytes on disk from its summary.
"""

from __future__ import annotations

import csv
import io
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from reports.plots import PlotResult, colour, save  # noqa: E402
from reports.results import MEMORY_PARTS, Run  # noqa: E402
from reports.tables import Row, measured_rows  # noqa: E402

TIME_SERIES = {"planning_ms": "planning, every call (median)", "first_plan_ms": "first plan (median)"}
MEMORY_SERIES = {"total": "memory total", **{p: f"memory: {p}" for p in MEMORY_PARTS}, "rss": "RSS growth", "disk": "map on disk"}
LINESTYLES = ["-", "--", ":", "-.", (0, (5, 1, 1, 1)), (0, (1, 3)), (0, (8, 2))]
MARKERS = ["o", "s", "^", "D", "v", "P", "X"]


@dataclass
class Fit:
    exponent: float
    coefficient: float
    points: int


def fit_exponent(xs: list[float], ys: list[float | None]) -> Fit | None:
    """Least squares of log y on log x over the positive points; None below two distinct sizes."""
    pairs = [(x, y) for x, y in zip(xs, ys, strict=True) if x and y is not None and x > 0 and y > 0]
    if len({x for x, _ in pairs}) < 2:
        return None
    lx, ly = np.log([p[0] for p in pairs]), np.log([p[1] for p in pairs])
    k, log_c = np.polyfit(lx, ly, 1)
    return Fit(float(k), float(np.exp(log_c)), len(pairs))


def _value(row: Row, series: str) -> float | None:
    if series == "planning_ms":
        return row.planning_ms_median
    if series == "first_plan_ms":
        return row.first_plan_ms_median
    if series == "rss":
        return row.rss_bytes
    if series == "disk":
        return row.disk_bytes
    value = row.memory.get(series)
    return None if value is None else float(value)


@dataclass
class ScalingData:
    """``points[system][series]``: [(corridor length m, value), ...] sorted by length (ms or bytes)."""

    points: dict[str, dict[str, list[tuple[float, float | None]]]]

    def fit(self, system: str, series: str) -> Fit | None:
        pts = self.points[system][series]
        return fit_exponent([x for x, _ in pts], [y for _, y in pts])


def scaling_data(runs: list[Run]) -> ScalingData:
    points: dict[str, dict[str, list[tuple[float, float | None]]]] = {}
    for run in runs:
        size = run.manifest.scenario.corridor_length_m
        if size is None:
            continue
        for row in measured_rows([run]):
            per = points.setdefault(row.system, {s: [] for s in (*TIME_SERIES, *MEMORY_SERIES)})
            for series in per:
                per[series].append((float(size), _value(row, series)))
    for per in points.values():
        for series in per:
            per[series].sort(key=lambda p: p[0])
    return ScalingData(points)


def _label(name: str, fit: Fit | None) -> str:
    return f"{name}: k = {_k(fit)}" if fit is not None else f"{name}: no fit"


def _k(fit: Fit) -> str:
    return f"{fit.exponent + 0.0:.2f}".replace("-0.00", "0.00")


def plot_scaling(runs: list[Run], folder: Path, name: str = "scaling") -> PlotResult:
    result = PlotResult(name, "Scaling: planning time and memory against environment size (log-log)")
    data = scaling_data(runs)
    if len({x for per in data.points.values() for pts in per.values() for x, _ in pts}) < 2:
        result.note = "fewer than two environment sizes (manifest scenario.corridor_length_m) among the runs"
        return result
    systems = list(data.points)
    fig, (ax_time, ax_memory) = plt.subplots(1, 2, figsize=(14, 5.5))
    for system in systems:
        c = colour(system, systems)
        for k, (series, title) in enumerate(TIME_SERIES.items()):
            pts = [(x, y) for x, y in data.points[system][series] if y]
            if pts:
                ax_time.plot(
                    *zip(*pts, strict=True),
                    marker=MARKERS[k],
                    color=c,
                    linestyle=LINESTYLES[k],
                    label=f"{system} · " + _label(title, data.fit(system, series)),
                )
        for k, (series, title) in enumerate(MEMORY_SERIES.items()):
            pts = [(x, y / 1e6) for x, y in data.points[system][series] if y]
            if pts:
                ax_memory.plot(
                    *zip(*pts, strict=True),
                    marker=MARKERS[k % len(MARKERS)],
                    markersize=4,
                    color=c,
                    linestyle=LINESTYLES[k % len(LINESTYLES)],
                    label=f"{system} · " + _label(title, data.fit(system, series)),
                )
    for ax, ylabel in ((ax_time, "planning time (ms)"), (ax_memory, "MB")):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("environment size: total corridor length (m)")
        ax.set_ylabel(ylabel)
        ax.grid(which="both", alpha=0.25)
        ax.legend(fontsize=6, loc="upper left", bbox_to_anchor=(0.0, -0.13), ncol=2, frameon=False)
    ax_time.set_title("planning time", fontsize=9)
    ax_memory.set_title("memory parts (zero parts left out)", fontsize=9)
    fig.suptitle("Growth with environment size: figure ≈ c · length^k (k fitted on the logarithms)", fontsize=10)
    fig.tight_layout()
    result.caption = "one point per run and system; k: the fitted growth exponent (1 = linear in the corridor length)"
    result.files = save(fig, folder, name)
    return result


def scaling_csv(runs: list[Run]) -> str:
    """Every point and fit: system, series, unit, each size's value, exponent, coefficient."""
    data = scaling_data(runs)
    sizes = sorted({x for per in data.points.values() for pts in per.values() for x, _ in pts})
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(["system", "series", "unit", *(f"{s:g}m" for s in sizes), "exponent", "coefficient", "points"])
    for system, per in data.points.items():
        for series, pts in per.items():
            values = dict(pts)
            fit = data.fit(system, series)
            unit = "ms" if series in TIME_SERIES else "bytes"
            writer.writerow(
                [system, series, unit]
                + ["" if values.get(s) is None else f"{values[s]:.6g}" for s in sizes]
                + (["", "", "0"] if fit is None else [f"{fit.exponent:.4f}", f"{fit.coefficient:.6g}", str(fit.points)])
            )
    return buffer.getvalue()


def scaling_markdown(runs: list[Run]) -> str:
    data = scaling_data(runs)
    lines = [
        "# Scaling: growth exponents k (figure ≈ c · corridor length^k)",
        "",
        "| system | " + " | ".join([*TIME_SERIES.values(), *MEMORY_SERIES.values()]) + " |",
        "|---" * (1 + len(TIME_SERIES) + len(MEMORY_SERIES)) + "|",
    ]
    for system in data.points:
        fits = [data.fit(system, s) for s in (*TIME_SERIES, *MEMORY_SERIES)]
        lines.append(f"| {system} | " + " | ".join("–" if f is None else _k(f) for f in fits) + " |")
    return "\n".join(lines) + "\n"


def write_scaling(runs: list[Run], out: Path) -> list[PlotResult]:
    """scaling.md, scaling.csv and the plot (PNG, SVG) under ``out``; returns the plot for the page."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "scaling.md").write_text(scaling_markdown(runs))
    (out / "scaling.csv").write_text(scaling_csv(runs))
    return [plot_scaling(runs, out / "plots")]
