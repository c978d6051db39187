"""A results folder as typed data: the one place where reports read a run's files.

``Run.load(dir)`` reads the contract's files (docs/DESIGN.md, "Contracts: the command line and
the results folder") into pydantic models: ``Manifest``, ``MappingReport`` and
``NavigationReport`` per system, ``TrialRecord`` per line of ``trials.jsonl``, ``SystemSummary``
per system of ``summary.json``, and the run's ``GroundTruth`` (``ground_truth/``) when the run
stored it. Every model allows keys it does not name (the contract is extended, never renamed) and
gives each optional figure one default here, so that no reader needs ``.get`` fallbacks. Files a
run may lack (an older run's ``ground_truth/``, a system's navigation report) load as ``None``
and are listed in ``Run.missing``; reports skip what needs them, with a note.

This module imports nothing of the runners, the scenarios or the systems.
"""

from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError

MEMORY_PARTS = ("map", "localization", "derived", "model")


class RunFormatError(ValueError):
    """A results folder that cannot be read; ``str(error)`` is the one line for a user."""


class Model(BaseModel):
    model_config = ConfigDict(extra="allow", frozen=False)


class Stats(Model):
    """median, mean, p95, max and count of a list of durations (ms) or distances (m)."""

    median: float | None = None
    mean: float | None = None
    p95: float | None = None
    max: float | None = None
    count: int | None = None


class Memory(Model):
    """The memory breakdown (exact bytes)."""

    map: int | None = None
    localization: int | None = None
    derived: int | None = None
    model: int | None = None
    total: int | None = None


class DiskParts(Model):
    map: int | None = None
    localization: int | None = None
    derived: int | None = None
    model: int | None = None
    other: int | None = None


class ScenarioInfo(Model):
    name: str
    description: str = ""
    file: str | None = None
    corridor_length_m: float | None = None
    free_area_m2: float | None = None
    route_length_m: float | None = None
    trial_count: int | None = None
    trial_distance_mean_m: float | None = None
    bounds_m: list[float] | None = None


class Protocol(Model):
    initial_pose_error_xy: float = 0.5
    initial_pose_error_yaw_deg: float = 10.0
    stop_tolerance: float = 0.35
    goal_tolerance: float = 0.5
    goals: str = "map"


class Manifest(Model):
    scenario: ScenarioInfo
    scenario_sha256: str | None = None
    systems: list[str]
    seed: int
    setting: str | None = None
    setting_override: str | None = None
    odometry_noise: dict[str, Any] | None = None
    range_noise: float | None = None
    protocol: Protocol = Field(default_factory=Protocol)
    trial_count: int | None = None
    config: dict[str, Any] = Field(default_factory=dict)
    versions: dict[str, str | None] = Field(default_factory=dict)
    git_revision: str | None = None
    machine: dict[str, Any] = Field(default_factory=dict)
    created: str | None = None
    maps_from: str | None = None

    @property
    def setting_name(self) -> str:
        """The run's setting; a run without one used the scenario file's own noise."""
        return self.setting or ("precise" if self.odometry_noise is None and not self.range_noise else "file")


class EdgeError(Model):
    translation_m: Stats = Field(default_factory=Stats)
    rotation_deg: Stats = Field(default_factory=Stats)
    count: int | None = None


class MappingReport(Model):
    error: str | None = None
    scans: int | None = None
    route_length_m: float | None = None
    ms_per_scan: Stats = Field(default_factory=Stats)
    map_bytes: int | None = None
    map_disk_bytes: int | None = None
    growth: list[tuple[float, int]] = Field(default_factory=list)
    memory: Memory = Field(default_factory=Memory)
    map_disk: DiskParts = Field(default_factory=DiskParts)
    vertices: int | None = None
    edges: int | None = None
    edge_error: EdgeError | None = None
    anchors: list[list[float]] | None = None  # [[stamp, x, y, yaw], ...] true poses, scenario frame
    maps_from: str | None = None


class NavigationReport(Model):
    map_bytes: int | None = None
    map_load_ms: float | None = None
    rss_bytes: int | None = None
    rss_process_bytes: int | None = None
    memory: Memory = Field(default_factory=Memory)
    disk_bytes: int | None = None
    disk: DiskParts = Field(default_factory=DiskParts)


class TrialRecord(Model):
    system: str
    trial: int
    success: bool
    reason: str = ""
    detail: str | None = None  # one line behind reason error / crashed / timeout / out_of_memory
    start: list[float] | None = None  # [x, y, yaw_deg], scenario frame
    goal: list[float] | None = None
    shortest_m: float | None = None
    travelled_m: float | None = None
    efficiency: float | None = None
    spl: float = 0.0
    efficiency_to_goal: float | None = None
    collisions: int = 0
    sim_time_s: float | None = None
    compute_s: float | None = None
    planning_ms: Stats = Field(default_factory=Stats)
    planning_ms_samples: list[float] = Field(default_factory=list)
    first_plan_ms: float | None = None
    tracking_error_m: dict[str, float | None] | None = None
    initial_pose_error: list[float] | None = None
    memory: Memory | None = None
    final_distance_m: float | None = None
    seed: int | None = None
    startup_localization: dict[str, Any] | None = None
    goal_conversion_error_m: float | None = None


class SummaryMemory(Memory):
    map_bytes: int | None = None
    disk_bytes: int | None = None
    rss_bytes: int | None = None
    rss_process_bytes: int | None = None
    loaded_map_bytes: int | None = None
    disk: DiskParts | None = None


class SystemSummary(Model):
    trials: int = 0
    successes: int = 0
    success_rate: float | None = None
    efficiency_mean: float | None = None
    efficiency_to_goal_mean: float | None = None
    spl_mean: float | None = None
    planning_ms: Stats = Field(default_factory=Stats)
    first_plan_ms: Stats = Field(default_factory=Stats)
    map_load_ms: float | None = None
    memory: SummaryMemory = Field(default_factory=SummaryMemory)
    tracking_error_m: dict[str, float | None] | None = None
    startup_localization: dict[str, Any] | None = None
    goal_conversion_error_m: dict[str, float | None] | None = None
    mapping_ms_per_scan: Stats | None = None
    failure_reasons: dict[str, int] = Field(default_factory=dict)


class Raster(Model):
    """``ground_truth/raster.yaml``: the GT raster's placement and cell values."""

    image: str = "raster.png"
    resolution: float
    origin: list[float]
    map_frame: list[float]  # [x, y, yaw] of the map frame in the scenario frame (radians)
    values: dict[str, int] = Field(default_factory=lambda: {"free": 255, "change": 160, "obstacle": 64, "wall": 0})
    robot_radius: float | None = None


class GroundTruthTrial(Model):
    trial: int
    start: list[float]  # [x, y, yaw_deg]
    goal: list[float]
    shortest_m: float
    shortest_path: list[list[float]]


class Route(Model):
    start: list[float]  # [x, y, yaw_deg]
    length_m: float
    polyline: list[list[float]]


class GroundTruth(BaseModel):
    """``ground_truth/``: the GT raster (image order: row 0 is the top), trials and route."""

    model_config = ConfigDict(arbitrary_types_allowed=True)

    raster: Raster
    image: NDArray[np.uint8] | None = None
    trials: dict[int, GroundTruthTrial] = Field(default_factory=dict)
    route: Route | None = None

    @property
    def extent(self) -> tuple[float, float, float, float]:
        """(xmin, xmax, ymin, ymax) of the raster for ``imshow(origin="upper")``."""
        assert self.image is not None
        h, w = self.image.shape
        x0, y0 = self.raster.origin[:2]
        r = self.raster.resolution
        return (x0, x0 + w * r, y0, y0 + h * r)

    def mask(self, *names: str) -> NDArray[np.bool_]:
        """Cells (image order) holding any of the named values."""
        assert self.image is not None
        return np.isin(self.image, [self.raster.values[n] for n in names])


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise RunFormatError(f"{path}: not readable JSON ({exc})") from None


def _validate(model: type[BaseModel], data: Any, where: Path, prefix: str = "") -> Any:
    """``model`` from ``data``; a RunFormatError naming the file, the first bad key and why."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        key = ".".join(str(p) for p in first["loc"]) or "(top)"
        if prefix:
            key = f"{prefix}: {key}"
        raise RunFormatError(f"{where}: {key}: {first['msg']}") from None


def read_trials(path: Path) -> list[dict[str, Any]]:
    """Finished trial records: the first of each (system, trial). A torn last line (no newline
    after it: a run killed while writing) is skipped; any other line that is not a JSON object
    is an error naming the file and the line."""
    if not path.is_file():
        return []
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise RunFormatError(f"{path}: not readable ({exc})") from None
    lines = text.split("\n")
    if not text.endswith("\n"):
        lines = lines[:-1]
    records, seen = [], set()
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            raise RunFormatError(f"{path}: line {number}: not JSON ({exc.msg})") from None
        if not isinstance(record, dict):
            raise RunFormatError(f"{path}: line {number}: expected a JSON object")
        key = (record.get("system"), record.get("trial"))
        if key not in seen:
            seen.add(key)
            records.append(record)
    return records


def read_tum(path: Path) -> NDArray[np.float64] | None:
    """A TUM trajectory as (T, 4) rows of time, x, y, yaw; None if the file is missing or empty."""
    if not path.is_file():
        return None
    try:
        rows = np.loadtxt(path, ndmin=2)
    except ValueError:
        return None
    if rows.size == 0 or rows.shape[1] < 8:
        return None
    yaw = 2.0 * np.arctan2(rows[:, 6], rows[:, 7])
    return np.column_stack([rows[:, 0], rows[:, 1], rows[:, 2], yaw])


class Run:
    """One results folder, read once (``Run.load``)."""

    def __init__(
        self,
        root: Path,
        manifest: Manifest,
        summary: dict[str, SystemSummary],
        trials: list[TrialRecord],
        mapping: dict[str, MappingReport | None],
        navigation: dict[str, NavigationReport | None],
        ground_truth: GroundTruth | None,
        missing: list[str],
    ) -> None:
        self.root = root
        self.manifest = manifest
        self.summary = summary
        self.trials = trials
        self.mapping = mapping
        self.navigation = navigation
        self.ground_truth = ground_truth
        self.missing = missing

    @classmethod
    def load(cls, root: Path | str, require_summary: bool = True) -> Run:
        root = Path(root)
        missing: list[str] = []
        manifest_path = root / "manifest.json"
        if not manifest_path.is_file():
            raise RunFormatError(f"{root}: not a run folder (manifest.json missing)")
        manifest = _validate(Manifest, _read_json(manifest_path), manifest_path)
        summary_path = root / "summary.json"
        summary: dict[str, SystemSummary] = {}
        if summary_path.is_file():
            data = _read_json(summary_path)
            if not isinstance(data, dict):
                raise RunFormatError(f"{summary_path}: expected an object keyed by system")
            summary = {name: _validate(SystemSummary, value, summary_path, name) for name, value in data.items()}
        elif require_summary:
            raise RunFormatError(f"{root}: not a finished run folder (summary.json missing): `run --resume {root}` finishes it")
        else:
            missing.append("summary.json")
        trials_path = root / "trials.jsonl"
        trials = [
            _validate(TrialRecord, r, trials_path, f"{r.get('system')} trial {r.get('trial')}") for r in read_trials(trials_path)
        ]
        trials.sort(key=lambda r: (r.system, r.trial))
        mapping: dict[str, MappingReport | None] = {}
        navigation: dict[str, NavigationReport | None] = {}
        for name in manifest.systems:
            for kind, models, out in (("mapping", MappingReport, mapping), ("navigation", NavigationReport, navigation)):
                path = root / kind / f"{name}.json"
                if path.is_file():
                    out[name] = _validate(models, _read_json(path), path)
                else:
                    out[name] = None
                    missing.append(f"{kind}/{name}.json")
        ground_truth = cls._load_ground_truth(root / "ground_truth", missing)
        return cls(root, manifest, summary, trials, mapping, navigation, ground_truth, missing)

    @staticmethod
    def _load_ground_truth(folder: Path, missing: list[str]) -> GroundTruth | None:
        raster_yaml = folder / "raster.yaml"
        if not raster_yaml.is_file():
            missing.append("ground_truth/")
            return None
        try:
            raster = _validate(Raster, yaml.safe_load(raster_yaml.read_text(encoding="utf-8")), raster_yaml)
        except (yaml.YAMLError, OSError, UnicodeDecodeError) as exc:
            raise RunFormatError(f"{raster_yaml}: not valid YAML ({exc})".replace("\n", " ")) from None
        image = None
        image_path = folder / raster.image
        if image_path.is_file():
            image = read_png(image_path)
        else:
            missing.append(f"ground_truth/{raster.image}")
        trials: dict[int, GroundTruthTrial] = {}
        trials_path = folder / "trials.json"
        if trials_path.is_file():
            data = _read_json(trials_path)
            if not isinstance(data, dict) or not isinstance(data.get("trials", []), list):
                raise RunFormatError(f"{trials_path}: expected an object with a list of trials")
            for entry in data.get("trials", []):
                trial = _validate(GroundTruthTrial, entry, trials_path)
                trials[trial.trial] = trial
        else:
            missing.append("ground_truth/trials.json")
        route = None
        route_path = folder / "route.json"
        if route_path.is_file():
            route = _validate(Route, _read_json(route_path), route_path)
        else:
            missing.append("ground_truth/route.json")
        return GroundTruth(raster=raster, image=image, trials=trials, route=route)

    # --- what the readers ask for ------------------------------------------------------------

    @property
    def systems(self) -> list[str]:
        return list(self.manifest.systems)

    @property
    def scenario(self) -> str:
        return self.manifest.scenario.name

    @property
    def setting(self) -> str:
        return self.manifest.setting_name

    @property
    def seed(self) -> int:
        return self.manifest.seed

    @cached_property
    def label(self) -> str:
        return f"{self.scenario} · {self.setting} · seed {self.seed}"

    def trials_of(self, system: str) -> list[TrialRecord]:
        return [r for r in self.trials if r.system == system]

    def map_dir(self, system: str) -> Path:
        return self.root / "maps" / system

    def map_kind(self, system: str) -> str | None:
        """What the saved map of a system is, from its files: ``graph`` (a NavTopo graph folder),
        ``grid`` (a map_server PNG + YAML), or None (nothing a report draws, e.g. the oracle's)."""
        folder = self.map_dir(system)
        if (folder / "graph.json").is_file():
            return "graph"
        if (folder / "map.yaml").is_file():
            return "grid"
        return None

    def trajectory(self, system: str, trial: int, estimate: bool = False) -> NDArray[np.float64] | None:
        """(T, 4) time, x, y, yaw of a trial's true path (scenario frame), or of the system's estimate."""
        return read_tum(self.root / "trajectories" / system / f"trial-{trial}{'.est' if estimate else ''}.tum")


def read_png(path: Path) -> NDArray[np.uint8]:
    """A single-channel 8-bit PNG as (H, W) uint8 in image order (row 0 = the top)."""
    import matplotlib.image as mpimg

    try:
        image = mpimg.imread(path)
    except (OSError, ValueError, SyntaxError) as exc:
        raise RunFormatError(f"{path}: not a readable PNG ({exc})") from None
    if image.ndim == 3:
        image = image[..., 0]
    if image.dtype != np.uint8:  # matplotlib gives floats in [0, 1] for 8-bit PNGs
        image = np.rint(image * 255.0).astype(np.uint8)
    return image
