"""NavTopo's graph over the ground-truth map: each location's walls at its vertex, and the edges.

Reads a results folder (``maps/navtopo`` and the manifest) and the scenario it names for the GT
map. Vertices are drawn at their stored odometry poses carried into the scenario frame by the
mapping run's start pose, which is their true place only when odometry was precise (the plot
says which); the walls of each location are its grid's occupied cells at that vertex.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from navtopo import geometry as se2  # noqa: E402
from navtopo.graph import TopologicalGraph  # noqa: E402
from navtopo.local_grid import OCCUPIED, GridConfig, cell_to_xy  # noqa: E402
from scenarios import load_scenario  # noqa: E402
from scenarios.render import draw_world, save_map_figure  # noqa: E402


def plot_graph(run_dir: Path, output: Path, dpi: int = 200) -> Path:
    run_dir = Path(run_dir)
    manifest = json.loads((run_dir / "manifest.json").read_text())
    scenario = load_scenario(manifest["scenario"]["file"], with_trials=False)
    graph, extra = TopologicalGraph.load(run_dir / "maps" / "navtopo")
    grid_config = GridConfig.model_validate(extra.get("navtopo_config", {}).get("grid", {}))
    mapping = json.loads((run_dir / "mapping" / "navtopo.json").read_text())
    start = scenario.route_start
    poses = np.array([se2.compose(start, v.pose_hint) for v in graph.vertices]).reshape(-1, 3)

    xmin, ymin, xmax, ymax = scenario.world.bounds
    fig, ax = plt.subplots(figsize=(10, max(3.0, min(14.0, 10 * (ymax - ymin) / max(xmax - xmin, 1e-6)))))
    draw_world(ax, scenario, wall_shade=0.8)
    colours = matplotlib.colormaps["tab20"]
    for i, (vertex, pose) in enumerate(zip(graph.vertices, poses, strict=True)):
        cells = np.argwhere(vertex.grid.cells == OCCUPIED) + [vertex.grid.row0, vertex.grid.col0]
        if len(cells):
            walls = se2.transform_points(pose, cell_to_xy(cells, grid_config))
            ax.scatter(walls[:, 0], walls[:, 1], s=0.8, color=colours(i % 20), alpha=0.7, linewidths=0, zorder=3)
    for u, v, _ in graph.edges():
        ax.plot(poses[[u, v], 0], poses[[u, v], 1], color="tab:red", linewidth=1.2, zorder=4)
    ax.scatter(
        poses[:, 0],
        poses[:, 1],
        s=18,
        color="tab:red",
        edgecolors="black",
        linewidths=0.4,
        zorder=5,
        label="locations (vertices)",
    )
    ax.plot([], [], color="tab:red", label="edges")
    ax.scatter([], [], s=4, color="gray", label="walls of each location's grid")
    noise = scenario.spec.odometry.noise
    error = mapping.get("edge_error", {}).get("translation_m", {})
    ax.set_title(
        f"NavTopo graph on {scenario.name}: {len(graph)} locations, {graph.edge_count} edges, "
        f"{graph.nbytes / 1e6:.2f} MB; edge error median {error.get('median', float('nan')):.3f} m"
        + ("" if noise is None else " (vertices at odometry poses: noisy)"),
        fontsize=9,
    )
    return save_map_figure(fig, ax, scenario, output, dpi, legend_columns=3)
