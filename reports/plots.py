"""The report's plots (PNG and SVG), drawn from results folders only (``reports.results.Run``).

* ``map_<system>``: a system's saved map over the GT map: a graph folder (``graph.json``,
  NavTopo's format) as its locations, each location's walls and its edges; a map_server map
  (``map.yaml``) as its occupied and free cells. Both are placed in the scenario frame: graph
  locations at the true poses where they were made (``anchors`` of the mapping report) when the
  run recorded them, else at their odometry hints composed with the map frame's pose; a grid by
  the map frame's pose (``ground_truth/raster.yaml``).
* ``trajectories_<system>``: every trial's true path over the GT map, failures marked.
* ``planning``: planning-time distributions on a log axis (all calls, and each trial's first
  plan), with the failed-trial count under each system (as Planner Arena draws them).
* ``efficiency``: each trial's efficiency per system (failures at 0, marked).
* ``map_growth``: map bytes along the mapping route.

A plot whose files are missing is skipped with a note (``PlotResult.note``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.transforms import Affine2D  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from navkit.errors import BenchError  # noqa: E402
from navkit.geometry import compose, transform_points  # noqa: E402
from navkit.raster import FREE, OCCUPIED, GridFrame, MapFileError, read_map_server  # noqa: E402
from reports.results import GroundTruth, Run, RunFormatError, TrialRecord, read_png  # noqa: E402

DPI = 150
# deterministic SVG: no date, fixed ids (a report made twice, or from a copied folder, is the same)
SVG_METADATA = {"Date": None}
plt.rcParams["svg.hashsalt"] = "navtopo-bench"
SYSTEM_COLOURS = {"navtopo": "tab:red", "metric_grid": "tab:blue", "oracle": "tab:green"}
FALLBACK_COLOURS = ["tab:purple", "tab:orange", "tab:brown", "tab:pink", "tab:olive", "tab:cyan", "tab:gray"]


@dataclass
class PlotResult:
    """One plot: ``name`` (file stem), a title and caption for the report, the files written, or
    ``note`` saying why it was skipped."""

    name: str
    title: str
    caption: str = ""
    files: list[Path] = field(default_factory=list)
    note: str = ""

    @property
    def png(self) -> Path | None:
        return next((f for f in self.files if f.suffix == ".png"), None)


def colour(system: str, systems: list[str]) -> str:
    if system in SYSTEM_COLOURS:
        return SYSTEM_COLOURS[system]
    others = [s for s in systems if s not in SYSTEM_COLOURS]
    return FALLBACK_COLOURS[others.index(system) % len(FALLBACK_COLOURS)] if system in others else "black"


def save(fig: plt.Figure, folder: Path, name: str) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    png, svg = folder / f"{name}.png", folder / f"{name}.svg"
    fig.savefig(png, dpi=DPI, metadata={"Software": None})
    fig.savefig(svg, metadata=SVG_METADATA)
    plt.close(fig)
    return [png, svg]


# ---------------------------------------------------------------------------------------------
# the GT map underneath


def draw_ground_truth(ax: plt.Axes, gt: GroundTruth, light: bool = False) -> None:
    """The GT raster: free white, walls dark, obstacles grey, navigation-time changes red."""
    assert gt.image is not None
    rgb = np.ones((*gt.image.shape, 3))
    shades = {"wall": 0.55 if light else 0.3, "obstacle": 0.75 if light else 0.6}
    for name, shade in shades.items():
        rgb[gt.mask(name)] = shade
    rgb[gt.mask("change")] = (0.95, 0.6, 0.6)
    ax.imshow(rgb, origin="upper", extent=gt.extent, interpolation="nearest", zorder=0)


def map_axes(gt: GroundTruth | None, run: Run, width: float = 10.0) -> tuple[plt.Figure, plt.Axes]:
    x0, x1, y0, y1 = map_bounds(gt, run)
    height = min(14.0, max(3.5, width * (y1 - y0) / max(x1 - x0, 1e-6) + 1.2))
    fig, ax = plt.subplots(figsize=(width, height))
    setup_map_axes(ax, gt, run)
    return fig, ax


def map_bounds(gt: GroundTruth | None, run: Run) -> tuple[float, float, float, float]:
    """(xmin, xmax, ymin, ymax): the GT raster's extent, else the scenario's bounds."""
    bounds = run.manifest.scenario.bounds_m
    if gt is not None and gt.image is not None:
        return gt.extent
    if bounds:
        return bounds[0], bounds[2], bounds[1], bounds[3]
    return 0.0, 1.0, 0.0, 1.0


def setup_map_axes(ax: plt.Axes, gt: GroundTruth | None, run: Run) -> None:
    x0, x1, y0, y1 = map_bounds(gt, run)
    if gt is not None and gt.image is not None:
        draw_ground_truth(ax, gt)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def finish_map(fig: plt.Figure, ax: plt.Axes, columns: int = 4) -> None:
    handles, _ = ax.get_legend_handles_labels()
    if handles:
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.08), ncol=columns, fontsize=7, frameon=False)
    fig.tight_layout()


def _finish_map_plot(
    result: PlotResult, fig: plt.Figure, ax: plt.Axes, columns: int, folder: Path, gt: GroundTruth | None, caption: str
) -> PlotResult:
    """Legend, caption and files of a plot over the GT map; a note when the run has no GT map."""
    finish_map(fig, ax, columns)
    result.caption = caption
    result.files = save(fig, folder, result.name)
    if gt is None:
        result.note = "drawn without the GT map: the run has no ground_truth/ folder"
    return result


def map_frame(run: Run) -> NDArray | None:
    gt = run.ground_truth
    return None if gt is None else np.asarray(gt.raster.map_frame, dtype=np.float64)


# ---------------------------------------------------------------------------------------------
# a graph map (graph.json, NavTopo's format)


class MapFormatError(BenchError):
    """A saved map a plot cannot read; ``str(error)`` names the file and the reason."""

    exit_code = 2  # an input refused


@dataclass
class GraphLayout:
    """A saved graph placed in the scenario frame: ``poses`` (V, 3) [x, y, yaw] per location,
    ``edges`` as (u, v) index pairs, ``walls[i]`` (N_i, 2) the occupied cells of location i's grid
    (cell centres), and ``placed_by``: ``anchor`` (the true poses where the locations were made)
    or ``hint`` (odometry poses composed with the map frame's pose)."""

    poses: NDArray[np.float64]
    edges: list[tuple[int, int]]
    walls: list[NDArray[np.float64]]
    placed_by: str


def graph_layout(run: Run, system: str) -> GraphLayout:
    """Read ``maps/<system>/graph.json`` and its grids; raises ``MapFormatError``.

    A location's grid is square, ``size`` cells of ``resolution`` m, centred on the location and
    axis-aligned with it; cell (row, col) of the full grid has its centre at
    ``((col - size/2 + 0.5) * res, (row - size/2 + 0.5) * res)`` (``navkit.raster.GridFrame.centred``);
    a saved grid is cropped at ``row0``, ``col0``."""
    map_dir = run.map_dir(system)
    index = map_dir / "graph.json"
    try:
        graph = json.loads(index.read_text())
        vertices = list(graph.get("vertices", []))
        edges = [(int(e[0]), int(e[1])) for e in graph.get("edges", [])]
        hints = np.asarray([v["pose_hint"] for v in vertices], dtype=np.float64).reshape(-1, 3)
        stamps = [round(float(v.get("stamp", -1.0)), 6) for v in vertices]
    except (OSError, ValueError, KeyError, TypeError, AttributeError, IndexError) as exc:
        raise MapFormatError(f"{index}: not a graph map ({type(exc).__name__}: {exc})".replace("\n", " ")) from None
    if any(not (0 <= u < len(vertices) and 0 <= v < len(vertices)) for u, v in edges):
        raise MapFormatError(f"{index}: an edge names a location that is not in the graph")
    mapping = run.mapping.get(system)
    anchors = {}
    if mapping is not None and mapping.anchors:
        anchors = {round(float(a[0]), 6): np.asarray(a[1:4], dtype=np.float64) for a in mapping.anchors}
    frame = map_frame(run)
    if anchors and all(stamp in anchors for stamp in stamps):
        poses, placed_by = np.asarray([anchors[s] for s in stamps], dtype=np.float64).reshape(-1, 3), "anchor"
    elif frame is not None:
        poses, placed_by = np.asarray([compose(frame, h) for h in hints], dtype=np.float64).reshape(-1, 3), "hint"
    else:
        raise MapFormatError(
            f"{index}: neither true anchors (mapping/{system}.json) nor the map frame's pose "
            "(ground_truth/raster.yaml) to place the locations"
        )
    grid_config = (graph.get("navtopo_config") or {}).get("grid") or {}
    walls = []
    for v, pose in zip(vertices, poses, strict=True):
        entry = v.get("grid") or {}
        png = map_dir / str(entry.get("file", ""))
        if not entry or not png.is_file() or png.stat().st_size == 0:
            walls.append(np.zeros((0, 2)))
            continue
        try:
            cells = read_png(png)
        except RunFormatError as exc:
            raise MapFormatError(str(exc)) from None
        size = int(entry.get("size", max(cells.shape)))
        resolution = float(grid_config.get("resolution") or 2.0 * float(grid_config.get("radius", 15.0)) / size)
        grid_frame = GridFrame.centred(size, resolution).shifted(int(entry.get("row0", 0)), int(entry.get("col0", 0)))
        walls.append(transform_points(pose, grid_frame.centres(cells == OCCUPIED)))
    return GraphLayout(poses, edges, walls, placed_by)


def draw_graph_layout(ax: plt.Axes, layout: GraphLayout) -> None:
    """Each location's walls (one colour per location), the edges and the locations, with legend entries."""
    poses = layout.poses
    tab = matplotlib.colormaps["tab20"]
    for i, walls in enumerate(layout.walls):
        if len(walls):
            ax.scatter(walls[:, 0], walls[:, 1], s=0.8, color=tab(i % 20), alpha=0.8, linewidths=0, zorder=3, rasterized=True)
    for u, v in layout.edges:
        ax.plot(poses[[u, v], 0], poses[[u, v], 1], color="tab:red", linewidth=1.1, zorder=4)
    ax.scatter(poses[:, 0], poses[:, 1], s=16, color="tab:red", edgecolors="black", linewidths=0.4, zorder=5)
    ax.plot([], [], "o", color="tab:red", markeredgecolor="black", label=f"locations ({len(poses)})")
    ax.plot([], [], color="tab:red", label=f"edges ({len(layout.edges)})")
    ax.scatter([], [], s=6, color="gray", label="walls in each location's grid (one colour per location)")


def plot_graph_map(run: Run, system: str, folder: Path, name: str | None = None) -> PlotResult:
    result = PlotResult(name or f"map_{system}", f"{system}: the topological graph over the GT map")
    try:
        layout = graph_layout(run, system)
    except MapFormatError as exc:
        result.note = str(exc)
        return result
    gt = run.ground_truth
    mapping = run.mapping.get(system)
    poses = layout.poses
    fig, ax = map_axes(gt, run)
    draw_graph_layout(ax, layout)
    where = (
        "locations at the true poses where they were made"
        if layout.placed_by == "anchor"
        else "locations at their odometry poses composed with the map frame"
        + ("" if run.manifest.odometry_noise is None else " (noisy odometry: drifted)")
    )
    size_text = f"{mapping.map_bytes / 1e6:.2f} MB" if mapping is not None and mapping.map_bytes else ""
    error = mapping.edge_error.translation_m.median if mapping is not None and mapping.edge_error else None
    ax.set_title(
        f"{system} on {run.scenario} ({run.setting}): {len(poses)} locations, {len(layout.edges)} edges"
        + (f", {size_text}" if size_text else "")
        + (f"; edge error median {error:.3f} m" if error is not None else ""),
        fontsize=9,
    )
    caption = where + "; " + ("GT map underneath" if gt is not None else "no GT map in this run (ground_truth/ missing)")
    return _finish_map_plot(result, fig, ax, 3, folder, gt, caption)


# ---------------------------------------------------------------------------------------------
# a grid map (map_server map.yaml + image)


@dataclass
class GridLayer:
    """A saved map_server grid: ``cells`` (H, W) UNKNOWN / FREE / OCCUPIED, row 0 the lowest y,
    placed in the map frame by ``frame``; ``placement`` carries map-frame points into the scenario
    frame (the map frame's pose)."""

    cells: NDArray[np.uint8]
    frame: GridFrame
    placement: Affine2D

    @property
    def occupied(self) -> NDArray[np.bool_]:
        return self.cells == OCCUPIED

    @property
    def free(self) -> NDArray[np.bool_]:
        return self.cells == FREE

    @property
    def resolution(self) -> float:
        return self.frame.resolution

    def centres(self, mask: NDArray[np.bool_]) -> NDArray[np.float64]:
        """(N, 2) scenario-frame centres of the cells set in ``mask`` (rows as ``cells``)."""
        return np.asarray(self.placement.transform(self.frame.centres(mask)), dtype=np.float64).reshape(-1, 2)


def grid_layer(run: Run, system: str) -> GridLayer:
    """Read ``maps/<system>/map.yaml`` and its image (``navkit.raster``); raises ``MapFormatError``."""
    frame = map_frame(run)
    if frame is None:
        raise MapFormatError(f"{system}: the grid lies in the map frame, whose pose needs ground_truth/raster.yaml (missing)")
    meta_path = run.map_dir(system) / "map.yaml"
    try:
        ros_map = read_map_server(meta_path)
    except MapFileError as exc:
        raise MapFormatError(f"{meta_path}: not a readable map_server map ({exc.reason})".replace("\n", " ")) from None
    return GridLayer(ros_map.cells, ros_map.frame, Affine2D().rotate(frame[2]).translate(frame[0], frame[1]))


def draw_grid_layer(ax: plt.Axes, layer: GridLayer) -> None:
    """Occupied and free cells, placed in the scenario frame, with legend entries."""
    rgba = np.zeros((*layer.cells.shape, 4))
    rgba[layer.free] = (0.35, 0.6, 0.95, 0.35)
    rgba[layer.occupied] = (0.05, 0.2, 0.75, 0.95)
    xmin, ymin, xmax, ymax = layer.frame.extent(layer.cells.shape)
    ax.imshow(
        rgba,
        origin="lower",
        extent=(xmin, xmax, ymin, ymax),
        interpolation="nearest",
        transform=layer.placement + ax.transData,
        zorder=2,
    )
    ax.plot([], [], "s", color=(0.05, 0.2, 0.75), label="occupied cells")
    ax.plot([], [], "s", color=(0.35, 0.6, 0.95, 0.5), label="free cells")


def plot_grid_map(run: Run, system: str, folder: Path) -> PlotResult:
    result = PlotResult(f"map_{system}", f"{system}: the occupancy grid over the GT map")
    try:
        layer = grid_layer(run, system)
    except MapFormatError as exc:
        result.note = str(exc)
        return result
    h, w = layer.cells.shape
    fig, ax = map_axes(run.ground_truth, run)
    draw_grid_layer(ax, layer)
    mapping = run.mapping.get(system)
    extra = f", {mapping.map_bytes / 1e6:.2f} MB" if mapping is not None and mapping.map_bytes else ""
    ax.set_title(f"{system} on {run.scenario} ({run.setting}): {w}×{h} cells of {layer.resolution:g} m{extra}", fontsize=9)
    finish_map(fig, ax, 2)
    result.caption = "the saved grid (map_server PNG + YAML, map frame) placed by the map frame's pose"
    result.files = save(fig, folder, result.name)
    return result


# ---------------------------------------------------------------------------------------------
# trajectories


def plot_trajectories(run: Run, system: str, folder: Path) -> PlotResult:
    result = PlotResult(f"trajectories_{system}", f"{system}: every trial's path")
    records = run.trials_of(system)
    paths = {r.trial: run.trajectory(system, r.trial) for r in records}
    if not any(p is not None for p in paths.values()):
        result.note = f"{system}: no trajectories (trajectories/{system}/ missing)"
        return result
    gt = run.ground_truth
    fig, ax = map_axes(gt, run)
    tab = matplotlib.colormaps["tab20"]
    for r in records:
        c = tab(r.trial % 20)
        gt_trial = gt.trials.get(r.trial) if gt is not None else None
        if gt_trial is not None:
            reference = np.asarray(gt_trial.shortest_path)
            ax.plot(reference[:, 0], reference[:, 1], linestyle=(0, (2, 2)), color="0.45", linewidth=0.7, zorder=2)
        path = paths.get(r.trial)
        if path is not None:
            ax.plot(path[:, 1], path[:, 2], color=c, linewidth=1.1 if r.success else 1.4, alpha=0.9, zorder=3)
            end = path[-1, 1:3]
            if not r.success:
                ax.plot([end[0]], [end[1]], marker="X", color="red", markeredgecolor="black", markersize=9, zorder=6)
                ax.annotate(
                    f"{r.trial}: {r.reason}",
                    (end[0], end[1]),
                    xytext=(4, 4),
                    textcoords="offset points",
                    fontsize=6,
                    color="darkred",
                    zorder=7,
                )
        if r.start is not None:
            ax.plot(
                [r.start[0]], [r.start[1]], "o", color=c, markersize=3.5, markeredgecolor="black", markeredgewidth=0.3, zorder=5
            )
        if r.goal is not None:
            ax.plot([r.goal[0]], [r.goal[1]], "*", color=c, markersize=8, markeredgecolor="black", markeredgewidth=0.4, zorder=5)
    failed = sum(1 for r in records if not r.success)
    ax.plot([], [], "o", color="gray", markersize=4, label="start")
    ax.plot([], [], "*", color="gray", markersize=8, label="goal")
    ax.plot([], [], color="gray", label="true path (one colour per trial)")
    if gt is not None and gt.trials:
        ax.plot([], [], linestyle=(0, (2, 2)), color="0.45", label="GT shortest path")
    if failed:
        ax.plot([], [], "X", color="red", markeredgecolor="black", markersize=8, label="failed: where it ended (reason)")
    ax.set_title(
        f"{system} on {run.scenario} ({run.setting}): {len(records) - failed}/{len(records)} trials succeeded", fontsize=9
    )
    caption = "true trajectories (scenario frame) of every trial" + (
        "" if gt is not None else "; no GT map in this run (ground_truth/ missing)"
    )
    return _finish_map_plot(result, fig, ax, 5, folder, gt, caption)


# ---------------------------------------------------------------------------------------------
# distributions over groups of trials (one group = one system of one run, or pooled runs)


@dataclass
class Group:
    label: str  # tick label (system, and for several runs the scenario and setting)
    system: str
    records: list[TrialRecord]
    scene: str = ""  # "<scenario> · <setting>": groups of one scene share their trials


def groups_of(runs: list[Run]) -> list[Group]:
    """One group per (scenario, setting, system), seeds pooled, in the order of appearance."""
    keyed: dict[tuple[str, str, str], list[TrialRecord]] = {}
    for run in runs:
        for system in run.systems:
            keyed.setdefault((run.scenario, run.setting, system), []).extend(run.trials_of(system))
    several = len({(k[0], k[1]) for k in keyed}) > 1
    return [
        Group(
            label=f"{system}\n{scenario} · {setting}" if several else system,
            system=system,
            records=records,
            scene=f"{scenario} · {setting}",
        )
        for (scenario, setting, system), records in keyed.items()
    ]


def plot_planning(groups: list[Group], folder: Path, name: str = "planning") -> PlotResult:
    result = PlotResult(name, "Planning time (log scale)")
    if not any(r.planning_ms_samples or r.first_plan_ms is not None for g in groups for r in g.records):
        result.note = "no planning times recorded"
        return result
    systems = list(dict.fromkeys(g.system for g in groups))
    fig, axes = plt.subplots(1, 2, figsize=(max(8.0, 1.6 * len(groups) * 2 + 2), 4.8), sharey=True)
    panels = [
        ("every planning call", lambda r: list(r.planning_ms_samples)),
        ("first plan of each trial", lambda r: [r.first_plan_ms] if r.first_plan_ms is not None else []),
    ]
    for ax, (title, pick) in zip(axes, panels, strict=True):
        data, labels = [], []
        for g in groups:
            values = [max(v, 1e-3) for r in g.records for v in pick(r)]
            data.append(values if values else [np.nan])
            failed = sum(1 for r in g.records if not r.success)
            labels.append(f"{g.label}\n{len(values)} values\n{failed}/{len(g.records)} failed")
        parts = ax.boxplot(
            data,
            whis=(5, 95),
            widths=0.55,
            patch_artist=True,
            flierprops={"marker": ".", "markersize": 2, "alpha": 0.4},
            medianprops={"color": "black"},
        )
        for patch, g in zip(parts["boxes"], groups, strict=True):
            patch.set_facecolor(colour(g.system, systems))
            patch.set_alpha(0.55)
        ax.set_yscale("log")
        ax.set_xticks(range(1, len(groups) + 1), labels, fontsize=7)
        ax.set_title(title, fontsize=9)
        ax.grid(axis="y", which="both", alpha=0.25)
    axes[0].set_ylabel("planning time (ms, log)")
    fig.suptitle("Planning time: boxes span the quartiles, whiskers 5–95 %; failed trials counted under each system", fontsize=9)
    fig.tight_layout()
    result.caption = "left: every planning call of every trial; right: each trial's first full start-to-goal plan"
    result.files = save(fig, folder, name)
    return result


def plot_efficiency(groups: list[Group], folder: Path, name: str = "efficiency") -> PlotResult:
    result = PlotResult(name, "Efficiency per trial")
    if not any(g.records for g in groups):
        result.note = "no trials recorded"
        return result
    systems = list(dict.fromkeys(g.system for g in groups))
    scenes = list(dict.fromkeys(g.scene for g in groups))  # a panel each: trial k of two scenes are unrelated
    most = max(len({r.trial for g in groups if g.scene == scene for r in g.records}) for scene in scenes)
    width_in = max(7.0, 0.35 * most * max(1, len(systems) / 3) + 3)
    fig, axes = plt.subplots(len(scenes), 1, figsize=(width_in, 3.4 * len(scenes) + 0.8), squeeze=False)
    markers = ["o", "s", "^", "D", "v", "P", "h"]
    for ax, scene in zip(axes[:, 0], scenes, strict=True):
        members = [g for g in groups if g.scene == scene]
        trials = sorted({r.trial for g in members for r in g.records})
        width = 0.8 / max(len(members), 1)
        for k, g in enumerate(members):
            c = colour(g.system, systems)
            offset = (k - (len(members) - 1) / 2) * width
            ok = [r for r in g.records if r.success and r.efficiency is not None]
            bad = [r for r in g.records if not r.success]
            mean = f"{np.mean([r.efficiency for r in ok]):.3f}" if ok else "–"
            ax.scatter(
                [r.trial + offset for r in ok],
                [r.efficiency or 0.0 for r in ok],  # none is None (ok)
                color=c,
                marker=markers[systems.index(g.system) % len(markers)],
                s=22,
                edgecolors="black",
                linewidths=0.3,
                zorder=3,
                label=f"{g.system} (mean {mean}, {len(ok)}/{len(g.records)} ok)",
            )
            if bad:
                ax.scatter([r.trial + offset for r in bad], [0.0] * len(bad), color=c, marker="x", s=30, zorder=3)
        ax.scatter([], [], color="gray", marker="x", label="failed trial (at 0)")
        ax.set_xticks(trials)
        ax.set_xlabel("trial" if len(scenes) == 1 else f"trial of {scene}")
        ax.set_ylabel("efficiency = shortest / travelled")
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.25)
        if len(scenes) > 1:
            ax.set_title(scene, fontsize=9)
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, fontsize=7, frameon=False)
    fig.tight_layout()
    result.caption = "each trial's efficiency (successful trials); failed trials marked × at 0" + (
        "; a panel per scene and setting" if len(scenes) > 1 else ""
    )
    result.files = save(fig, folder, name)
    return result


def plot_growth(run: Run, folder: Path) -> PlotResult:
    result = PlotResult("map_growth", "Map bytes along the mapping route")
    series = {s: m.growth for s, m in run.mapping.items() if m is not None and m.growth}
    if not series:
        result.note = "no mapping reports with map growth (mapping/<system>.json)"
        return result
    fig, ax = plt.subplots(figsize=(8, 4))
    for system, growth in series.items():
        g = np.asarray(growth, dtype=np.float64)
        ax.plot(g[:, 0], g[:, 1] / 1e6, color=colour(system, run.systems), linewidth=1.5, label=system)
    ax.set_xlabel("distance along the mapping route (m)")
    ax.set_ylabel("map (MB, exact bytes)")
    ax.set_title(f"Map size while mapping {run.scenario} ({run.setting})", fontsize=9)
    ax.grid(alpha=0.25)
    ax.legend(fontsize=8)
    fig.tight_layout()
    result.caption = "each system's map_bytes every 10 m of the mapping route (mapping/<system>.json: growth)"
    result.files = save(fig, folder, result.name)
    return result


# ---------------------------------------------------------------------------------------------


def run_plots(run: Run, folder: Path, combined: bool = True) -> list[PlotResult]:
    """Every plot of one run, written under ``folder``; ``combined=False`` leaves out the planning
    and efficiency plots (a report of several runs draws them once, over all runs)."""
    out: list[PlotResult] = []
    for system in run.systems:
        kind = run.map_kind(system)
        if kind == "graph":
            out.append(plot_graph_map(run, system, folder))
        elif kind == "grid":
            out.append(plot_grid_map(run, system, folder))
    for system in run.systems:
        out.append(plot_trajectories(run, system, folder))
    if combined:
        groups = groups_of([run])
        out.append(plot_planning(groups, folder))
        out.append(plot_efficiency(groups, folder))
    out.append(plot_growth(run, folder))
    return out
