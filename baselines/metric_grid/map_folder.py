"""The metric baseline's saved map folder: what is written, what is checked when it is read.

A folder holds the navigation map as a ROS map_server map (``map.yaml`` + ``map.png``,
``occupancy.GridMap``), the pose graph it was traced from (``pose_graph.json`` + ``pose_graph.npz``,
``pose_graph.PoseGraph``: mapping state, kept for re-optimising later) and the manifest
``metric_grid.json`` (format, file names, the grid's frame and shape, counts, the resolved config).
Every file is written whole or not at all (``navkit.files.atomic_write``).

Loading reads the grid only, after checking the manifest, the YAML and the image one by one: a
folder that cannot be used fails with ``MetricMapError``, one line naming the file.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

from navkit.errors import FileProblem
from navkit.files import atomic_write

from .occupancy import GridMap
from .pose_graph import PoseGraph

FORMAT = "navtopo-metric-grid/1"
MAP_YAML = "map.yaml"
MANIFEST = "metric_grid.json"


class MetricMapError(FileProblem, ValueError):
    """A saved metric map that cannot be loaded: ``file: reason`` (an input refused, exit code 2;
    a ``ValueError`` too, for callers that catch that)."""

    def __init__(self, file: str | Path, reason: str) -> None:
        super().__init__(file, "", reason)


def save_map_folder(directory: Path, grid_map: GridMap, pose_graph: PoseGraph, scans: int, config: dict[str, Any]) -> None:
    """Write the map, the pose graph and the manifest (``scans``: scans of the mapping run;
    ``config``: the resolved config as JSON values)."""
    directory.mkdir(parents=True, exist_ok=True)
    grid_map.save(directory / MAP_YAML)
    pose_graph.save(directory)
    manifest = {
        "format": FORMAT,
        "map": MAP_YAML,
        "map_image": Path(MAP_YAML).with_suffix(".png").name,
        "pose_graph": ["pose_graph.json", "pose_graph.npz"],
        "resolution": grid_map.resolution,
        "origin": [float(v) for v in grid_map.origin],
        "shape": list(grid_map.cells.shape),
        "keyframes": len(pose_graph.keyframes),
        "loop_closures": len(pose_graph.loops),
        "scans": scans,
        "config": config,
    }
    atomic_write(directory / MANIFEST, json.dumps(manifest, indent=2) + "\n")


def load_grid_map(directory: Path) -> GridMap:
    """The navigation map of a saved folder; ``MetricMapError`` names the first file that fails."""
    manifest_path = directory / MANIFEST
    try:
        manifest = json.loads(manifest_path.read_text())
    except FileNotFoundError:
        raise MetricMapError(manifest_path, "missing (not a metric_grid map folder)") from None
    except (OSError, ValueError) as exc:
        raise MetricMapError(manifest_path, f"unreadable: {exc}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise MetricMapError(manifest_path, f"format is not {FORMAT}")
    yaml_path = directory / str(manifest.get("map", MAP_YAML))
    try:
        meta = yaml.safe_load(yaml_path.read_text())
    except FileNotFoundError:
        raise MetricMapError(yaml_path, "missing") from None
    except (OSError, ValueError, yaml.YAMLError) as exc:
        raise MetricMapError(yaml_path, f"unreadable: {str(exc).splitlines()[0]}") from None
    if not isinstance(meta, dict) or "image" not in meta:
        raise MetricMapError(yaml_path, "not a map_server map (no 'image' key)")
    image_path = yaml_path.parent / str(meta["image"])
    if not image_path.is_file():
        raise MetricMapError(image_path, f"missing (named by {yaml_path.name})")
    try:
        grid_map = GridMap.load(yaml_path)
    except Exception as exc:  # a truncated or corrupt image, or bad YAML values
        raise MetricMapError(image_path, f"cannot read the map image: {type(exc).__name__}: {exc}") from None
    if grid_map.cells.size == 0 or not grid_map.resolution > 0:
        raise MetricMapError(yaml_path, "empty map or non-positive resolution")
    return grid_map


def disk_usage(directory: Path) -> dict[str, int]:
    """The saved map's bytes per memory part: the map_server map and the manifest are the map;
    the pose graph (keyframe scans, for re-optimising later) is mapping state, of no part."""
    files = [directory / MAP_YAML, directory / MANIFEST]
    try:
        image = yaml.safe_load((directory / MAP_YAML).read_text()).get("image")
        files.append(directory / str(image))
    except (OSError, AttributeError, yaml.YAMLError):
        pass
    return {"map": sum(f.stat().st_size for f in files if f.is_file())}
