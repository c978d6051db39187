"""A figure of a scenario: ground-truth map, obstacles by height, navigation-time changes (red,
hatched), the mapping route and the trials (their GT shortest paths with the changes in place)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib import cm, colors  # noqa: E402
from matplotlib.patches import Polygon as PolygonPatch  # noqa: E402

from scenarios.scenario import Scenario  # noqa: E402
from scenarios.world import rectangle  # noqa: E402


def draw_world(ax: plt.Axes, scenario: Scenario, wall_shade: float = 0.18) -> None:
    world = scenario.world
    xmin, ymin, xmax, ymax = world.bounds
    image = np.where(world.structure_free, 1.0, wall_shade)
    ax.imshow(image, origin="lower", extent=(xmin, xmax, ymin, ymax), cmap="gray", vmin=0, vmax=1, interpolation="nearest")
    norm = colors.Normalize(vmin=0.0, vmax=world.wall_height)
    cmap = matplotlib.colormaps["viridis"]
    for ob in world.obstacles:
        poly = rectangle(ob.center, ob.size, ob.yaw)
        ax.add_patch(
            PolygonPatch(
                np.asarray(poly.exterior.coords),
                closed=True,
                facecolor=cmap(norm(ob.height)),
                edgecolor="black",
                linewidth=0.4,
                zorder=3,
            )
        )
    if world.obstacles:
        sm = cm.ScalarMappable(norm=norm, cmap=cmap)
        bar = plt.colorbar(sm, ax=ax, fraction=0.025, pad=0.01)
        bar.set_label("obstacle height (m)")
    for k, change in enumerate(scenario.spec.world.changes):  # boxes that appear only when navigating
        poly = rectangle(change.center, change.size, change.yaw)
        ax.add_patch(
            PolygonPatch(
                np.asarray(poly.exterior.coords),
                closed=True,
                facecolor=(0.85, 0.1, 0.1, 0.25),
                edgecolor=(0.85, 0.1, 0.1),
                hatch="xxx",
                linewidth=1.2,
                zorder=3.5,
                label="change (navigation stage only)" if k == 0 else None,
            )
        )


def render(scenario: Scenario, output: Path, show_route: bool = True, show_trials: bool = True, dpi: int = 200) -> Path:
    world = scenario.world
    xmin, ymin, xmax, ymax = world.bounds
    width = 10.0
    height = max(3.0, width * (ymax - ymin) / max(xmax - xmin, 1e-6))
    fig, ax = plt.subplots(figsize=(width, min(height, 14.0)))
    draw_world(ax, scenario)
    if show_route and len(scenario.route) > 1:
        ax.plot(
            scenario.route[:, 0],
            scenario.route[:, 1],
            color="tab:orange",
            linewidth=0.8,
            alpha=0.7,
            zorder=4,
            label=f"mapping route ({scenario.route_length_m:.0f} m)",
        )
    if show_trials and scenario.trials:
        tab = matplotlib.colormaps["tab20"]
        for trial in scenario.trials:
            colour = tab(trial.index % 20)
            path = trial.shortest_path
            ax.plot(path[:, 0], path[:, 1], linestyle="--", linewidth=0.9, color=colour, zorder=5)
            x, y, yaw = trial.start
            ax.annotate(
                "",
                xy=(x + 0.9 * np.cos(yaw), y + 0.9 * np.sin(yaw)),
                xytext=(x, y),
                arrowprops={"arrowstyle": "-|>", "color": colour, "lw": 1.2},
                zorder=6,
            )
            ax.plot([x], [y], "o", color=colour, markersize=3.5, zorder=6)
            ax.plot(
                [trial.goal[0]],
                [trial.goal[1]],
                "*",
                color=colour,
                markersize=8,
                markeredgecolor="black",
                markeredgewidth=0.4,
                zorder=6,
            )
            ax.text(trial.goal[0], trial.goal[1] + 0.5, str(trial.index), fontsize=6, ha="center", zorder=7)
        ax.plot([], [], "o", color="gray", markersize=4, label="trial start (arrow: heading)")
        ax.plot([], [], "*", color="gray", markersize=8, label="trial goal")
        ax.plot([], [], "--", color="gray", label="GT shortest path")
    # scale bar of 5 m in the lower-left corner
    bar = 5.0 if (xmax - xmin) > 12 else 1.0
    ax.plot([xmin + 0.8, xmin + 0.8 + bar], [ymin + 0.5] * 2, color="black", linewidth=2.5, zorder=8)
    ax.text(xmin + 0.8 + bar / 2, ymin + 0.7, f"{bar:.0f} m", ha="center", va="bottom", fontsize=7, zorder=8)
    summary = scenario.summary()
    mean = summary["trial_distance_mean_m"]
    ax.set_title(
        f"{scenario.name}: "
        + (f"{summary['corridor_length_m']:.0f} m of corridor, " if summary["corridor_length_m"] else "")
        + f"{summary['free_area_m2']:.0f} m² free, "
        f"{len(scenario.trials)} trials"
        + (f" (mean {mean:.1f} m)" if mean else "")
        + (f", {summary['changes']} change(s) at navigation time" if summary["changes"] else ""),
        fontsize=10,
    )
    return save_map_figure(fig, ax, scenario, output, dpi, legend_columns=4)


def save_map_figure(fig: plt.Figure, ax: plt.Axes, scenario: Scenario, output: Path, dpi: int, legend_columns: int) -> Path:
    """Metric axes over the world's bounds, the legend under the map, and the PNG written."""
    xmin, ymin, xmax, ymax = scenario.world.bounds
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.set_xlim(xmin, xmax)
    ax.set_ylim(ymin, ymax)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.07), ncol=legend_columns, fontsize=7, frameon=False)
    fig.tight_layout()
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(output, dpi=dpi)
    plt.close(fig)
    return output
