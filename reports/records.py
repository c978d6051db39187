"""The JSON files of a results folder as typed records: written by the runner, read by the reports.

One model per file of the contract (docs/DESIGN.md, "Contracts: the command line and the results
folder"), as evo's one result container: ``Manifest`` (``manifest.json``), ``TrialRecord`` (a
line of ``trials.jsonl``), ``SystemSummary`` (a system of ``summary.json``), ``MappingReport``
(``mapping/<system>.json``) and ``NavigationReport`` (``navigation/<system>.json``). The runner
builds these objects and writes them (``Record.as_json``); ``reports.results.Run`` reads them back
with the same models.

What a file holds is what its writer gave, nothing more (``Record``):

* keys the model does not name are kept (the contract is extended, never renamed; a system's
  own mapping figures ride along in its mapping report);
* a key the writer did not give is not written, and reads as the model's default: each optional
  figure has its one default here, so that no reader needs ``.get`` fallbacks;
* keys are written in the order they were given (or read), keys set later after them, so that a
  file read and written back is the same text;
* a number is written as given: 1 stays 1, 1.0 stays 1.0 (``Number``).

This module imports nothing of the runners, the scenarios or the systems.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any, Self, TypeVar

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    ModelWrapValidatorHandler,
    PrivateAttr,
    SerializerFunctionWrapHandler,
    ValidationError,
    ValidatorFunctionWrapHandler,
    WrapValidator,
    model_serializer,
    model_validator,
)

from navkit.errors import BenchError
from navkit.types import STOP_TOLERANCE_M

MEMORY_PARTS = ("map", "localization", "derived", "model")


class RunFormatError(BenchError):
    """A results folder that cannot be read; ``str(error)`` is the one line for a user."""

    exit_code = 2  # an input refused


def _as_given(value: Any, handler: ValidatorFunctionWrapHandler) -> Any:
    return value if type(value) is int else handler(value)


#: a real number as its writer gave it: an int stays an int (pydantic would make 1 into 1.0)
Number = Annotated[float, WrapValidator(_as_given)]


class Record(BaseModel):
    """A JSON object of a results folder (see the module's docstring for what is kept as given)."""

    model_config = ConfigDict(extra="allow")
    _keys: tuple[str, ...] = PrivateAttr(default=())  # the keys as given, in their order

    @model_validator(mode="wrap")
    @classmethod
    def _remember_keys(cls, data: Any, handler: ModelWrapValidatorHandler[Self]) -> Self:
        record = handler(data)
        if isinstance(data, dict):
            record._keys = tuple(data)
        return record

    @model_serializer(mode="wrap")
    def _in_given_order(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        data = handler(self)
        ordered = {key: data[key] for key in self._keys if key in data}
        return {**ordered, **{key: value for key, value in data.items() if key not in ordered}}

    def as_json(self) -> dict[str, Any]:
        """The object as its file holds it: the keys given, in their order, then those set since."""
        return self.model_dump(exclude_unset=True)

    def given(self, key: str, default: Any = None) -> Any:
        """The value the writer gave for ``key`` (None included), else ``default`` (not the model's)."""
        return getattr(self, key) if key in self.model_fields_set or key in (self.model_extra or {}) else default

    @classmethod
    def read(cls, path: Path) -> Self:
        """The record in the JSON file ``path``; a ``RunFormatError`` naming the file (and key) if not."""
        return validate(cls, read_json(path), path)


R = TypeVar("R", bound=BaseModel)


def read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:  # UnicodeDecodeError and JSONDecodeError are ValueErrors
        raise RunFormatError(f"{path}: not readable JSON ({exc})") from None


def validate(model: type[R], data: Any, where: Path, prefix: str = "") -> R:
    """``model`` from ``data``; a RunFormatError naming the file, the first bad key and why."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        first = exc.errors()[0]
        key = ".".join(str(p) for p in first["loc"]) or "(top)"
        if prefix:
            key = f"{prefix}: {key}"
        raise RunFormatError(f"{where}: {key}: {first['msg']}") from None


# --- parts -------------------------------------------------------------------------------------


class Stats(Record):
    """median, mean, p95, max and count of a list of durations (ms) or distances (m)."""

    median: Number | None = None
    mean: Number | None = None
    p95: Number | None = None
    max: Number | None = None
    count: int | None = None


class Memory(Record):
    """A memory breakdown (exact bytes; ``navkit.types.MemoryBreakdown``)."""

    map: int | None = None
    localization: int | None = None
    derived: int | None = None
    model: int | None = None
    total: int | None = None


class DiskParts(Record):
    """A saved map's bytes on disk per memory part; ``other``: files of no part."""

    map: int | None = None
    localization: int | None = None
    derived: int | None = None
    model: int | None = None
    other: int | None = None


# --- manifest.json -----------------------------------------------------------------------------


class MapImportInfo(Record):
    """What a map world's import changed (``scenarios.map_import.MapImport``): its rules, then
    pixels of the map: islands below the resolvable size and their pixels removed or grown, slits
    closed, laser-fan pixels made wall, free pixels detached; the world's and the raw map's free
    pixels, and how many differ between them."""

    rules: dict[str, Any] = Field(default_factory=dict)
    islands: int | None = None
    removed_px: int | None = None
    grown_px: int | None = None
    closed_px: int | None = None
    fan_px: int | None = None
    detached_px: int | None = None
    free_px: int | None = None
    raw_free_px: int | None = None
    changed_px: int | None = None


class ScenarioInfo(Record):
    """The scenario's summary (``Scenario.summary``) and its file."""

    name: str
    description: str = ""
    file: str | None = None
    corridor_length_m: Number | None = None
    free_area_m2: Number | None = None
    route_length_m: Number | None = None
    trial_count: int | None = None
    trial_distance_mean_m: Number | None = None
    bounds_m: list[Number] | None = None
    map_import: MapImportInfo | None = None  # a map world's import (absent for shape worlds)


class Protocol(Record):
    """``runners.protocol.TrialProtocol`` as the manifest records it."""

    initial_pose_error_xy: Number = 0.5
    initial_pose_error_yaw_deg: Number = 10.0
    stop_tolerance: Number = STOP_TOLERANCE_M
    goal_tolerance: Number = 0.5
    goals: str = "map"
    initial_pose: str = "perturbed"


class Manifest(Record):
    scenario: ScenarioInfo
    scenario_sha256: str | None = None
    systems: list[str]
    seed: int
    setting: str | None = None
    setting_override: str | None = None
    odometry_noise: dict[str, Any] | None = None
    range_noise: Number | None = None
    protocol: Protocol = Field(default_factory=Protocol)
    trial_count: int | None = None
    config: dict[str, Any] = Field(default_factory=dict)
    versions: dict[str, str | None] = Field(default_factory=dict)
    git_revision: str | None = None
    machine: dict[str, Any] = Field(default_factory=dict)
    created: str | None = None
    maps_from: str | None = None  # the run whose maps this one reused (--maps-from)
    scenario_copy: str | None = None  # the scenario file as the run read it, its maps beside: relative to the run folder

    @property
    def setting_name(self) -> str:
        """The run's setting; a run without one used the scenario file's own noise. A kidnapped start
        (the protocol's ``initial_pose: none``) is named beside it: its rows are not the default's."""
        name = self.setting or ("precise" if self.odometry_noise is None and not self.range_noise else "file")
        return f"{name}, kidnapped" if self.protocol is not None and self.protocol.initial_pose == "none" else name


# --- mapping/<system>.json ---------------------------------------------------------------------


class EdgeError(Record):
    translation_m: Stats = Field(default_factory=Stats)
    rotation_deg: Stats = Field(default_factory=Stats)
    count: int | None = None


class MappingReport(Record):
    """A system's mapping: the runner's figures, then the system's own (``mapping_stats``, kept as
    extra keys). A failed mapping has ``error`` and null sizes."""

    error: str | None = None
    scans: int | None = None
    route_length_m: Number | None = None  # driven
    route_plan_length_m: Number | None = None
    collisions: int | None = None
    ms_per_scan: Stats | None = None  # median, mean, p95, max of the system's observe calls
    map_bytes: int | None = None
    growth: list[tuple[Number, int]] = Field(default_factory=list)  # [metres driven, map bytes]
    memory: Memory | None = None
    map_disk_bytes: int | None = None
    map_disk: DiskParts | None = None
    edge_error: EdgeError | None = None
    unjoined_neighbours: int | None = None
    vertices_second_half: int | None = None
    vertices_second_half_share: Number | None = None
    vertices_second_half_revisited: int | None = None
    anchors: list[list[Number]] | None = None  # [[stamp, x, y, yaw], ...] true poses, scenario frame
    vertices: int | None = None  # a graph system's own figures
    edges: int | None = None
    maps_from: str | None = None  # the run whose report this is a copy of (--maps-from)


# --- navigation/<system>.json ------------------------------------------------------------------


class NavigationReport(Record):
    """A fresh worker's figures: map loading, RSS and the breakdown after the first plan, disk."""

    map_bytes: int | None = None
    map_load_ms: Number | None = None
    rss_bytes: int | None = None  # growth from before the map was loaded to after the first plan
    rss_process_bytes: int | None = None  # the whole worker then
    rss_before_load: int | None = None
    memory: Memory | None = None
    disk_bytes: int | None = None
    disk: DiskParts | None = None


# --- trials.jsonl ------------------------------------------------------------------------------


class TrialRecord(Record):
    system: str
    trial: int
    success: bool
    reason: str = ""
    detail: str | None = None  # one line behind the reason: the runner's (error, crashed, timeout, ...) or the system's
    failure_stage: str | None = None  # where it failed (navkit.types.FailureStage); None: a success, or a run before it
    start: list[Number] | None = None  # [x, y, yaw_deg], scenario frame
    goal: list[Number] | None = None
    shortest_m: Number | None = None
    narrowest_gap_m: Number | None = None  # room beyond the radius on each side in the path's narrowest gap
    narrow: bool = False  # narrower than the scenario's margin, run because the file allows it
    travelled_m: Number | None = None
    efficiency: Number | None = None
    spl: Number = 0.0
    efficiency_to_goal: Number | None = None
    efficiency_after_startup: Number | None = None  # from where it committed to its pose, over the metres after
    efficiency_mapped_world: Number | None = None  # world.changes: against the shortest path in the world as mapped
    collisions: int = 0
    sim_time_s: Number | None = None
    compute_s: Number | None = None
    planning_ms: Stats = Field(default_factory=Stats)
    planning_ms_samples: list[Number] = Field(default_factory=list)
    first_plan_ms: Number | None = None
    tracking_error_m: dict[str, Number | None] | None = None  # median, p95, max, final
    initial_pose_error: list[Number] | None = None  # [dx, dy, dyaw_deg] added to the given start
    memory: Memory | None = None
    final_distance_m: Number | None = None
    seed: int | None = None
    startup_localization: dict[str, Any] | None = None  # the system's first localization, checked against the truth
    goal_conversion_error_m: Number | None = None
    worker: dict[str, Any] | None = None  # where it ran (host, pid, node); None if no worker did


def read_trials(path: Path, skip_unreadable: bool = False, repeated: list[tuple[Any, Any]] | None = None) -> list[TrialRecord]:
    """The finished trials of ``trials.jsonl``: the first record of each (system, trial). A torn
    last line (no newline after it: a run killed while writing) is skipped; any other line that
    is not JSON is an error naming the file and the line, or skipped with ``skip_unreadable``
    (the runner's own reading on resume); a record that is not a trial record is an error.
    ``repeated`` gets the (system, trial) of every record after the first of its trial (two
    drivers wrote the folder: reports flag it)."""
    if not path.is_file():
        return []
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise RunFormatError(f"{path}: not readable ({exc})") from None
    lines = text.split("\n")
    if not text.endswith("\n"):
        lines = lines[:-1]
    first: dict[tuple[Any, Any], dict[str, Any]] = {}  # every line read before any is validated
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            data = json.loads(line)
        except json.JSONDecodeError as exc:
            if skip_unreadable:
                continue
            raise RunFormatError(f"{path}: line {number}: not JSON ({exc.msg})") from None
        if not isinstance(data, dict):
            raise RunFormatError(f"{path}: line {number}: expected a JSON object")
        key = (data.get("system"), data.get("trial"))
        if key in first and repeated is not None:
            repeated.append(key)
        first.setdefault(key, data)
    return [validate(TrialRecord, data, path, f"{system} trial {trial}") for (system, trial), data in first.items()]


# --- summary.json ------------------------------------------------------------------------------


class SummaryMemory(Record):
    map_bytes: int | None = None
    disk_bytes: int | None = None
    rss_bytes: int | None = None
    rss_process_bytes: int | None = None
    loaded_map_bytes: int | None = None
    map: int | None = None
    localization: int | None = None
    derived: int | None = None
    model: int | None = None
    total: int | None = None
    disk: DiskParts | None = None


class SystemSummary(Record):
    trials: int = 0
    successes: int = 0
    success_rate: Number | None = None
    efficiency_mean: Number | None = None
    efficiency_to_goal_mean: Number | None = None
    efficiency_after_startup_mean: Number | None = None
    efficiency_mapped_world_mean: Number | None = None
    spl_mean: Number | None = None
    planning_ms: Stats = Field(default_factory=Stats)
    first_plan_ms: Stats = Field(default_factory=Stats)
    map_load_ms: Number | None = None
    memory: SummaryMemory = Field(default_factory=SummaryMemory)
    tracking_error_m: dict[str, Number | None] | None = None
    startup_localization: dict[str, Any] | None = None
    goal_conversion_error_m: dict[str, Number | None] | None = None
    mapping_ms_per_scan: Stats | None = None
    failure_reasons: dict[str, int] = Field(default_factory=dict)
    failure_stages: dict[str, int] = Field(default_factory=dict)  # failures by stage (records that name one)
