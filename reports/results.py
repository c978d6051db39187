"""A results folder as typed data: the one place where reports read a run's files.

``Run.load(dir)`` reads the contract's files (docs/DESIGN.md, "Contracts: the command line and
the results folder") into the records the runner wrote them with (``reports.records``):
``Manifest``, ``MappingReport`` and ``NavigationReport`` per system, ``TrialRecord`` per line of
``trials.jsonl``, ``SystemSummary`` per system of ``summary.json``; and the run's ``GroundTruth``
(``ground_truth/``) when the run stored it. Files a run may lack (an older run's
``ground_truth/``, a system's navigation report) load as ``None`` and are listed in
``Run.missing``; reports skip what needs them, with a note.

This module imports nothing of the runners, the scenarios or the systems.
"""

from __future__ import annotations

from functools import cached_property
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import yaml
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from reports.records import (
    MEMORY_PARTS,
    Manifest,
    MappingReport,
    NavigationReport,
    Record,
    RunFormatError,
    SystemSummary,
    TrialRecord,
    read_json,
    read_trials,
    validate,
)

R = TypeVar("R", bound=Record)

__all__ = [  # the records, read here, are the reports' names too
    "MEMORY_PARTS",
    "GroundTruth",
    "Manifest",
    "MappingReport",
    "NavigationReport",
    "Run",
    "RunFormatError",
    "SystemSummary",
    "TrialRecord",
    "read_png",
    "read_trials",
    "read_tum",
]


class Raster(Record):
    """``ground_truth/raster.yaml``: the GT raster's placement and cell values."""

    image: str = "raster.png"
    resolution: float
    origin: list[float]
    map_frame: list[float]  # [x, y, yaw] of the map frame in the scenario frame (radians)
    values: dict[str, int] = Field(default_factory=lambda: {"free": 255, "change": 160, "obstacle": 64, "wall": 0})
    robot_radius: float | None = None


class GroundTruthTrial(Record):
    trial: int
    start: list[float]  # [x, y, yaw_deg]
    goal: list[float]
    shortest_m: float
    shortest_path: list[list[float]]
    narrowest_gap_m: float | None = None  # None: a run from before gaps were measured
    narrowest_gap_at: list[float] | None = None  # [x, y] of the narrowest gap; None: wide open (or not measured)
    narrow: bool = False


class Route(Record):
    start: list[float]  # [x, y, yaw_deg]
    length_m: float
    polyline: list[list[float]]


class GroundTruth(BaseModel):
    """``ground_truth/``: the GT raster (image order: row 0 is the top), trials and route."""

    model_config = ConfigDict(arbitrary_types_allowed=True)

    raster: Raster
    image: NDArray[np.uint8] | None = None
    trials: dict[int, GroundTruthTrial] = Field(default_factory=dict)
    trial_margin_m: float | None = None  # the margin the trials keep (trials.json ``margin_m``)
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


def _report(model: type[R], path: Path, missing: list[str]) -> R | None:
    """A system's report, or None (and its file named in ``missing``) if the run has none."""
    if path.is_file():
        return model.read(path)
    missing.append(f"{path.parent.name}/{path.name}")
    return None


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
        self.repeated: list[tuple[Any, Any]] = []  # (system, trial) of records after their trial's first

    @classmethod
    def load(cls, root: Path | str, require_summary: bool = True) -> Run:
        root = Path(root)
        missing: list[str] = []
        manifest_path = root / "manifest.json"
        if not root.exists():
            raise RunFormatError(f"{root}: no such folder")
        if not manifest_path.is_file():
            raise RunFormatError(f"{root}: not a run folder (manifest.json missing)")
        manifest = validate(Manifest, read_json(manifest_path), manifest_path)
        summary_path = root / "summary.json"
        summary: dict[str, SystemSummary] = {}
        if summary_path.is_file():
            data = read_json(summary_path)
            if not isinstance(data, dict):
                raise RunFormatError(f"{summary_path}: expected an object keyed by system")
            summary = {name: validate(SystemSummary, value, summary_path, name) for name, value in data.items()}
        elif require_summary:
            raise RunFormatError(f"{root}: not a finished run folder (summary.json missing): `run --resume {root}` finishes it")
        else:
            missing.append("summary.json")
        trials_path = root / "trials.jsonl"
        repeated: list[tuple[Any, Any]] = []
        trials = read_trials(trials_path, repeated=repeated)
        trials.sort(key=lambda r: (r.system, r.trial))
        mapping = {name: _report(MappingReport, root / "mapping" / f"{name}.json", missing) for name in manifest.systems}
        navigation = {name: _report(NavigationReport, root / "navigation" / f"{name}.json", missing) for name in manifest.systems}
        ground_truth = cls._load_ground_truth(root / "ground_truth", missing)
        run = cls(root, manifest, summary, trials, mapping, navigation, ground_truth, missing)
        run.repeated = repeated
        return run

    @staticmethod
    def _load_ground_truth(folder: Path, missing: list[str]) -> GroundTruth | None:
        raster_yaml = folder / "raster.yaml"
        if not raster_yaml.is_file():
            missing.append("ground_truth/")
            return None
        try:
            raster = validate(Raster, yaml.safe_load(raster_yaml.read_text(encoding="utf-8")), raster_yaml)
        except (yaml.YAMLError, OSError, UnicodeDecodeError) as exc:
            raise RunFormatError(f"{raster_yaml}: not valid YAML ({exc})".replace("\n", " ")) from None
        image = None
        image_path = folder / raster.image
        if image_path.is_file():
            image = read_png(image_path)
        else:
            missing.append(f"ground_truth/{raster.image}")
        trials: dict[int, GroundTruthTrial] = {}
        margin = None
        trials_path = folder / "trials.json"
        if trials_path.is_file():
            data = read_json(trials_path)
            if not isinstance(data, dict) or not isinstance(data.get("trials", []), list):
                raise RunFormatError(f"{trials_path}: expected an object with a list of trials")
            for entry in data.get("trials", []):
                trial = validate(GroundTruthTrial, entry, trials_path)
                trials[trial.trial] = trial
            margin = data.get("margin_m")
            if margin is not None and (isinstance(margin, bool) or not isinstance(margin, (int, float))):
                raise RunFormatError(f"{trials_path}: margin_m: expected a number (got {margin!r})")
        else:
            missing.append("ground_truth/trials.json")
        route = None
        route_path = folder / "route.json"
        if route_path.is_file():
            route = validate(Route, read_json(route_path), route_path)
        else:
            missing.append("ground_truth/route.json")
        return GroundTruth(raster=raster, image=image, trials=trials, trial_margin_m=margin, route=route)

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
