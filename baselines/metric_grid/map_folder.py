"""The metric baseline's saved map folder: what is written, what is checked when it is read.

A folder holds the navigation map as a ROS map_server map (``map.yaml`` + ``map.png``,
``occupancy.GridMap``), the pose graph it was traced from (``pose_graph.json`` + ``pose_graph.npz``,
``pose_graph.PoseGraph``: mapping state, kept for re-optimising later) and the manifest
``metric_grid.json`` (format, file names, the grid's frame and shape, counts, the resolved config).
Every file is written whole or not at all (``navkit.files.atomic_write``).

Loading reads the grid only, after checking the manifest; the map_server map is checked by its one
reader (``navkit.raster.read_map_server``). A folder that cannot be used fails with
``MetricMapError``, one line naming the file (and the key of a bad YAML value).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

from navkit.errors import FileProblem
from navkit.files import atomic_write
from navkit.raster import MapFileError

from .occupancy import GridMap
from .pose_graph import PoseGraph

FORMAT = "navtopo-metric-grid/1"
MAP_YAML = "map.yaml"
MANIFEST = "metric_grid.json"


class MetricMapError(FileProblem, ValueError):
    """A saved metric map that cannot be loaded: ``file: key: reason`` (``file: reason`` without a
    key); an input refused (exit code 2), and a ``ValueError`` for callers that catch that."""


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
    """The navigation map of a saved folder; ``MetricMapError`` names the first file that fails
    (the manifest here, the map_server map by ``navkit.raster.read_map_server``'s checks)."""
    manifest_path = directory / MANIFEST
    try:
        manifest = json.loads(manifest_path.read_text())
    except FileNotFoundError:
        raise MetricMapError(manifest_path, "", "missing (not a metric_grid map folder)") from None
    except (OSError, ValueError) as exc:
        raise MetricMapError(manifest_path, "", f"unreadable: {exc}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
        raise MetricMapError(manifest_path, "", f"format is not {FORMAT}")
    yaml_path = directory / str(manifest.get("map", MAP_YAML))
    try:
        return GridMap.load(yaml_path)
    except MapFileError as exc:
        raise MetricMapError(exc.file, exc.key, exc.reason) from None
    except Exception as exc:  # noqa: BLE001 - whatever else reading the map raises (an unreadable file)
        raise MetricMapError(yaml_path, "", f"cannot read the map: {type(exc).__name__}: {exc}") from None


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
