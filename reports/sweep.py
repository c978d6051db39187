"""The sweeps' studies from their run folders alone: scaling and drift.

Scaling: planning time and every memory part against the environment size (the scenario's
corridor length in each manifest), log-log, with fitted growth exponents (``figure ≈ c · length^k``,
least squares on the logarithms). Each run contributes one point per system: planning over every
call (median) and the first plan of each trial (median) from its trials; the memory breakdown
(map, localization, derived, model, total: the largest at any trial), RSS growth and the saved
map's bytes on disk from its summary.

Drift: one scenario under growing odometry noise (one run per level): success, efficiency and map
quality (wall precision against the GT raster; a graph's edge error) per level, and the paper's
Figure 1 from the noisiest run: the metric grid over the GT map beside the graph of locations.
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

from navkit.raster import GridFrame
from reports.plots import (  # noqa: E402
    MapFormatError,
    PlotResult,
    colour,
    draw_graph_layout,
    draw_grid_layer,
    graph_layout,
    grid_layer,
    map_bounds,
    save,
    setup_map_axes,
)
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
    (out / "scaling.md").write_text(scaling_markdown(runs), encoding="utf-8")
    (out / "scaling.csv").write_text(scaling_csv(runs), encoding="utf-8")
    return [plot_scaling(runs, out / "plots")]


# ---------------------------------------------------------------------------------------------
# drift: one scenario under growing odometry noise

WALL_TOLERANCE_M = 0.25  # a map's wall cell this close to a GT wall or obstacle is in its place


def wall_precision(run: Run, system: str) -> float | None:
    """Share of a saved map's wall cells (scenario frame) within ``WALL_TOLERANCE_M`` of a GT wall or
    obstacle cell: corridors mapped twice under drift put walls in free space and lower it. A grid
    is placed by the map frame, so drift shows; a graph's locations at their true anchors, so this
    measures each location's own grid (a graph has no global frame to drift). None without the GT
    raster or a drawable map."""
    gt = run.ground_truth
    if gt is None or gt.image is None:
        return None
    try:
        kind = run.map_kind(system)
        if kind == "grid":
            layer = grid_layer(run, system)
            points = layer.centres(layer.occupied)
        elif kind == "graph":
            walls = graph_layout(run, system).walls
            points = np.concatenate(walls) if walls else np.zeros((0, 2))
        else:
            return None
    except MapFormatError:
        return None
    if not len(points):
        return None
    from scipy.ndimage import distance_transform_edt

    resolution = gt.raster.resolution
    distance = distance_transform_edt(~gt.mask("wall", "obstacle")) * resolution  # to the nearest GT wall cell
    x0, _, y0, _ = gt.extent
    h, w = gt.image.shape
    rows_up, cols = GridFrame(np.array([x0, y0]), resolution).to_cell(points).T
    rows = h - 1 - rows_up  # the GT image's row 0 is the top
    inside = (rows >= 0) & (rows < h) & (cols >= 0) & (cols < w)
    near = np.zeros(len(points), dtype=bool)  # outside the raster: beyond every wall, misplaced
    near[inside] = distance[rows[inside], cols[inside]] <= WALL_TOLERANCE_M + 1e-9
    return float(near.mean())


@dataclass
class DriftPoint:
    level: str
    system: str
    success_rate: float | None
    efficiency: float | None
    wall_precision: float | None
    edge_error_median_m: float | None
    trials: int


def drift_data(runs: list[Run]) -> list[DriftPoint]:
    """One point per (run, system), in the order of the runs (levels as given to the sweep)."""
    out = []
    for run in runs:
        for row in measured_rows([run]):
            mapping = run.mapping.get(row.system)
            edge = mapping.edge_error.translation_m.median if mapping is not None and mapping.edge_error else None
            out.append(
                DriftPoint(
                    run.setting, row.system, row.success_rate, row.efficiency, wall_precision(run, row.system), edge, row.trials
                )
            )
    return out


def _fmt(value: float | None, digits: int = 3) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def drift_markdown(runs: list[Run]) -> str:
    lines = [
        "# Drift: success, efficiency and map quality per odometry-noise level",
        "",
        "| level | system | trials | success rate | efficiency | wall precision | edge error median (m) |",
        "|---|---|---|---|---|---|---|",
    ]
    for p in drift_data(runs):
        lines.append(
            f"| {p.level} | {p.system} | {p.trials} | {_fmt(p.success_rate, 2)} | {_fmt(p.efficiency)} | "
            f"{_fmt(p.wall_precision)} | {_fmt(p.edge_error_median_m)} |"
        )
    lines += [
        "",
        f"- wall precision: share of the saved map's wall cells within {WALL_TOLERANCE_M} m of a GT wall or obstacle "
        "(a grid placed by the map frame, so drift shows; a graph's locations at their true anchors: each location's own grid).",
        "- edge error: a graph's edges against the true relative poses (mapping report).",
    ]
    return "\n".join(lines) + "\n"


def drift_csv(runs: list[Run]) -> str:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    fields = ["level", "system", "trials", "success_rate", "efficiency", "wall_precision", "edge_error_median_m"]
    writer.writerow(fields)
    for p in drift_data(runs):
        writer.writerow(["" if getattr(p, f) is None else getattr(p, f) for f in fields])
    return buffer.getvalue()


def plot_drift(runs: list[Run], folder: Path, name: str = "drift") -> PlotResult:
    result = PlotResult(name, "Drift: success, efficiency and map quality per odometry-noise level")
    points = drift_data(runs)
    if not points:
        result.note = "no runs"
        return result
    levels = list(dict.fromkeys(p.level for p in points))
    systems = list(dict.fromkeys(p.system for p in points))
    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    panels = [("success_rate", "success rate"), ("efficiency", "efficiency (successes)"), ("wall_precision", "wall precision")]
    for ax, (key, title) in zip(axes, panels, strict=True):
        for k, system in enumerate(systems):
            ys = [next((getattr(p, key) for p in points if p.level == level and p.system == system), None) for level in levels]
            xs = [i for i, y in enumerate(ys) if y is not None]
            if xs:
                ax.plot(xs, [ys[i] for i in xs], marker=MARKERS[k % len(MARKERS)], color=colour(system, systems), label=system)
        ax.set_xticks(range(len(levels)), levels)
        ax.set_ylim(-0.05, 1.05)
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.25)
    axes[0].set_xlabel("odometry noise")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    result.caption = (
        f"levels as run (runners/protocol.py settings); wall precision: share of map wall cells within {WALL_TOLERANCE_M} m "
        "of a GT wall (a graph's locations at their true anchors)"
    )
    result.files = save(fig, folder, name)
    return result


def plot_figure1(runs: list[Run], folder: Path, name: str = "figure1") -> PlotResult:
    """The paper's Figure 1 made real, from the noisiest run: the metric grid built under drift over
    the GT map (placed by the map frame, so doubled corridors show) beside the graph of locations."""
    result = PlotResult(name, "Figure 1: the metric grid under drift beside the graph of locations")
    if not runs:
        result.note = "no runs"
        return result
    run = runs[-1]
    grid = next((s for s in run.systems if run.map_kind(s) == "grid"), None)
    graph = next((s for s in run.systems if run.map_kind(s) == "graph"), None)
    if grid is None or graph is None or run.ground_truth is None:
        result.note = f"{run.label}: needs a grid map, a graph map and ground_truth/"
        return result
    try:
        layer, layout = grid_layer(run, grid), graph_layout(run, graph)
    except MapFormatError as exc:
        result.note = str(exc)
        return result
    x0, x1, y0, y1 = map_bounds(run.ground_truth, run)
    fig, axes = plt.subplots(1, 2, figsize=(14, min(12.0, max(4.0, 7 * (y1 - y0) / max(x1 - x0, 1e-6) + 1.5))))
    for ax in axes:
        setup_map_axes(ax, run.ground_truth, run)
    draw_grid_layer(axes[0], layer)
    draw_graph_layout(axes[1], layout)
    axes[0].set_title(f"{grid}: the global grid built with {run.setting} odometry, over the GT map", fontsize=9)
    axes[1].set_title(f"{graph}: locations at the true poses where they were made, edges, each location's walls", fontsize=9)
    for ax in axes:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3, fontsize=7, frameon=False)
    fig.tight_layout()
    result.caption = f"{run.label}: where drift bends a global map, a graph of locations keeps each place's own frame"
    result.files = save(fig, folder, name)
    return result


def write_drift(runs: list[Run], out: Path) -> list[PlotResult]:
    """drift.md, drift.csv and the plots (PNG, SVG) under ``out``; returns the plots for the page."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "drift.md").write_text(drift_markdown(runs), encoding="utf-8")
    (out / "drift.csv").write_text(drift_csv(runs), encoding="utf-8")
    return [plot_drift(runs, out / "plots"), plot_figure1(runs, out / "plots")]
