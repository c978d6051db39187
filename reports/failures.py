"""The failed trials of each run, one row each, and a crop of where each ended.

A row says what a reader asks first of a failure: which system and trial, the reason and the stage
it failed in (``navkit.types.FailureStage``: start-up, localization, graph, local plan, follower),
the one line the system or the runner gave (``detail``), how far from the goal it ended, after how
many metres and seconds, and which other systems failed the same trial (a trial every system fails
points at the scene; one only a system fails, at the system). Each row has a crop of the last
metres: the true trajectory over the ground truth, and over the system's own map placed in the
scenario frame (a graph's locations at their true poses, a grid by its map frame), so that a wall
the map lacks or a location off its place shows. Written in ``table.md`` (the rows) and in
``report.html`` (rows and crops, under each run).
"""

from __future__ import annotations

import html
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from numpy.typing import NDArray

from reports.plots import (
    MapFormatError,
    PlotResult,
    draw_graph_layout,
    draw_grid_layer,
    draw_ground_truth,
    graph_layout,
    grid_layer,
    save,
)
from reports.results import Run, TrialRecord

TAIL_M = 10.0  # m of trajectory a crop shows before the end
CROP_MIN_M = 3.0  # half the side of a crop at least, m
CLOSE_UP_M = 1.2  # half the side of the close-up round the end, m: a touched wall or a post shows


@dataclass
class FailureRow:
    """One failed trial of one system."""

    system: str
    trial: int
    reason: str
    stage: str | None
    detail: str | None
    left_m: float | None  # the true distance from where it ended to the goal
    travelled_m: float | None
    sim_time_s: float | None
    also_failed: list[str] = field(default_factory=list)  # other systems that failed this trial
    succeeded: list[str] = field(default_factory=list)  # other systems that reached the goal of this trial

    @property
    def key(self) -> str:
        return f"failure_{self.system}_{self.trial}"


def failure_rows(run: Run) -> list[FailureRow]:
    """The run's failed trials, by system then trial."""
    by_trial: dict[int, list[TrialRecord]] = {}
    for record in run.trials:
        by_trial.setdefault(record.trial, []).append(record)
    rows = []
    for record in sorted(run.trials, key=lambda r: (run.systems.index(r.system) if r.system in run.systems else 99, r.trial)):
        if record.success:
            continue
        others = [r for r in by_trial[record.trial] if r.system != record.system]
        rows.append(
            FailureRow(
                system=record.system,
                trial=record.trial,
                reason=record.reason or "failed",
                stage=record.failure_stage,
                detail=record.detail,
                left_m=None if record.final_distance_m is None else float(record.final_distance_m),
                travelled_m=None if record.travelled_m is None else float(record.travelled_m),
                sim_time_s=None if record.sim_time_s is None else float(record.sim_time_s),
                also_failed=[r.system for r in others if not r.success],
                succeeded=[r.system for r in others if r.success],
            )
        )
    return rows


HEADERS = ["system", "trial", "reason", "stage", "left (m)", "driven (m)", "time (s)", "others", "detail"]


def cells(row: FailureRow) -> list[str]:
    def number(value: float | None, digits: int) -> str:
        return "–" if value is None else f"{value:.{digits}f}"

    others = [f"{s} failed" for s in row.also_failed] + [f"{s} ok" for s in row.succeeded]
    return [
        row.system,
        str(row.trial),
        row.reason,
        row.stage or "–",
        number(row.left_m, 2),
        number(row.travelled_m, 1),
        number(row.sim_time_s, 1),
        ", ".join(others) or "–",
        " ".join((row.detail or "–").split()),
    ]


def markdown(runs: list[Run]) -> str:
    """The failures of every run, a table each ("none" for a run without)."""
    text = "## Failed trials\n\n"
    for run in runs:
        rows = failure_rows(run)
        text += f"### {run.label}\n\n"
        if not rows:
            text += "None.\n\n"
            continue
        text += "| " + " | ".join(HEADERS) + " |\n|" + "|".join("---" for _ in HEADERS) + "|\n"
        for row in rows:
            text += "| " + " | ".join(c.replace("|", "\\|") for c in cells(row)) + " |\n"
        text += "\n"
    return text


def rows_html(rows: list[FailureRow]) -> str:
    """The rows as an HTML table (report.html, under each run)."""
    if not rows:
        return "<p>No trial failed.</p>"
    e = html.escape
    head = "".join(f"<th>{e(h)}</th>" for h in HEADERS)
    body = "".join(f'<tr id="{e(row.key)}">' + "".join(f"<td>{e(c)}</td>" for c in cells(row)) + "</tr>" for row in rows)
    return f'<table class="results failures"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


# ---------------------------------------------------------------------------------------------
# the crop of each failure


def tail(path: NDArray[np.float64], metres: float) -> NDArray[np.float64]:
    """The last ``metres`` of a trajectory (K, 2)."""
    if len(path) < 2:
        return path
    steps = np.hypot(*np.diff(path, axis=0).T)
    from_end = np.concatenate([np.cumsum(steps[::-1])[::-1], [0.0]])
    return path[from_end <= metres]


def crop_bounds(points: NDArray[np.float64], end: NDArray[np.float64]) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax): a square round the end holding ``points``, at least ``CROP_MIN_M`` each side."""
    half = max(CROP_MIN_M, float(np.abs(points - end).max()) + 1.0) if len(points) else CROP_MIN_M
    return end[0] - half, end[0] + half, end[1] - half, end[1] + half


def plot_failure(run: Run, row: FailureRow, folder: Path) -> PlotResult:
    """Where a failed trial ended: a close-up of the end over the ground truth with the robot's
    footprint there, and its last ``TAIL_M`` metres over the ground truth and over the system's own
    map, the true shortest path dashed, the end marked."""
    result = PlotResult(row.key, f"{row.system}, trial {row.trial}: {row.reason}")
    trajectory = run.trajectory(row.system, row.trial)
    if trajectory is None or not len(trajectory):
        result.note = f"{row.system} trial {row.trial}: no trajectory (trajectories/{row.system}/trial-{row.trial}.tum missing)"
        return result
    path = trajectory[:, 1:3]
    last = tail(path, TAIL_M)
    end = path[-1]
    bounds = crop_bounds(last, end)
    gt = run.ground_truth
    kind = run.map_kind(row.system)
    radius = gt.raster.robot_radius if gt is not None else None
    panels = [("where it ended (ground truth)", "close"), ("its last metres (ground truth)", "gt")]
    panels += [(f"{row.system}'s own map", kind)] if kind in ("graph", "grid") else []
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.4), squeeze=False)
    notes = []
    for ax, (title, what) in zip(axes[0], panels, strict=True):
        if what in ("gt", "close") and gt is not None and gt.image is not None:
            draw_ground_truth(ax, gt)
        elif what == "gt":
            notes.append("no GT map in this run")
        elif what == "close":
            pass
        else:
            if gt is not None and gt.image is not None:
                draw_ground_truth(ax, gt, light=True)
            try:
                if what == "graph":
                    draw_graph_layout(ax, graph_layout(run, row.system))
                else:
                    draw_grid_layer(ax, grid_layer(run, row.system))
            except MapFormatError as exc:
                notes.append(str(exc))
        reference = gt.trials.get(row.trial) if gt is not None else None
        if reference is not None:
            shortest = np.asarray(reference.shortest_path)
            ax.plot(shortest[:, 0], shortest[:, 1], linestyle=(0, (2, 2)), color="0.35", linewidth=0.9, zorder=4)
        ax.plot(last[:, 0], last[:, 1], color="tab:orange", linewidth=1.6, zorder=5)
        ax.plot([end[0]], [end[1]], marker="X", color="red", markeredgecolor="black", markersize=10, zorder=7)
        record = next((r for r in run.trials_of(row.system) if r.trial == row.trial), None)
        if record is not None and record.goal is not None:
            ax.plot([record.goal[0]], [record.goal[1]], "*", color="gold", markeredgecolor="black", markersize=12, zorder=6)
        near = bounds if what != "close" else (end[0] - CLOSE_UP_M, end[0] + CLOSE_UP_M, end[1] - CLOSE_UP_M, end[1] + CLOSE_UP_M)
        if what == "close" and radius:
            ax.add_patch(plt.Circle((end[0], end[1]), radius, fill=False, color="red", linewidth=1.2, zorder=8))
        ax.set_xlim(near[0], near[1])
        ax.set_ylim(near[2], near[3])
        ax.set_aspect("equal")
        ax.set_title(title, fontsize=9)
        ax.tick_params(labelsize=7)
    fig.suptitle(f"{row.system}, trial {row.trial}: {row.reason}" + (f" ({row.stage})" if row.stage else ""), fontsize=10)
    fig.tight_layout()
    result.files = save(fig, folder, row.key)
    result.caption = (
        f"where it ended (X; the circle: the robot's footprint there), and the last {TAIL_M:g} m of the true "
        "trajectory (orange), the goal (star) and the true shortest path (dashed), over the ground truth and over "
        "the system's own map in the scenario frame"
    )
    result.note = "; ".join(notes)
    return result


def failure_plots(run: Run, folder: Path) -> list[PlotResult]:
    """A crop per failed trial of ``run``, under ``folder``."""
    return [plot_failure(run, row, folder) for row in failure_rows(run)]
