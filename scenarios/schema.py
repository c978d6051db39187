"""The scenario file format, version 1 (see docs/DESIGN.md, "Scenario files").

Every key is validated; a bad file yields one ``ScenarioError`` whose message names the file,
the key and the reason, e.g. ``bad.yaml: world.corridors.0.width: must be > 0 (got -1.0)``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

FORMAT = "navtopo-scenario/1"

# numbers are numbers: no strings or booleans coerced, no NaN or infinity
Number = Annotated[float, Field(strict=True, allow_inf_nan=False)]
Positive = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0)]
NonNegative = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0)]
Integer = Annotated[int, Field(strict=True)]
Flag = Annotated[bool, Field(strict=True)]
XY = tuple[Number, Number]
MAX_RASTER_CELLS = 60_000_000  # about 7.7 x 7.7 km at 1 m, 390 x 390 m at 0.05 m


class ScenarioError(Exception):
    """A scenario that cannot be used; ``str(error)`` is the one line to show a user."""

    def __init__(self, file: str | Path, key: str, reason: str) -> None:
        self.file, self.key, self.reason = str(file), key, reason
        super().__init__(f"{file}: {key}: {reason}" if key else f"{file}: {reason}")


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class CorridorSpec(Strict):
    points: list[XY] = Field(min_length=2)
    width: Positive


class RoomSpec(Strict):
    center: XY
    size: tuple[Positive, Positive]
    yaw: Number = 0.0  # degrees


class ObstacleSpec(Strict):
    center: XY
    size: tuple[Positive, Positive]
    height: Positive
    yaw: Number = 0.0  # degrees


class MapSpec(Strict):
    yaml: str  # a ROS map_server YAML file, relative to the scenario file


class WorldSpec(Strict):
    resolution: Positive = 0.05
    wall_height: Positive = 2.6
    ceiling: Flag = True  # extension of format 1: a flat ceiling at wall_height, as indoors
    corridors: list[CorridorSpec] = []
    rooms: list[RoomSpec] = []
    obstacles: list[ObstacleSpec] = []
    # extension of format 1: boxes that appear only in the navigation stage (a closed door, a
    # cart left in a corridor); absent while mapping, obstacles during every trial
    changes: list[ObstacleSpec] = []
    map: MapSpec | None = None

    @model_validator(mode="after")
    def _some_free_space(self) -> WorldSpec:
        if self.map is None and not self.corridors and not self.rooms:
            raise ValueError("needs corridors or rooms, or a map")
        if self.map is not None and (self.corridors or self.rooms):
            raise ValueError("give either a map or corridors/rooms, not both")
        return self


class RobotSpec(Strict):
    radius: Positive = 0.3
    max_linear: Positive = 1.0
    max_angular: Positive = 1.5


class SensorSpec(Strict):
    channels: Annotated[int, Field(strict=True, ge=1, le=128)] = 16
    vertical_fov: tuple[Number, Number] = (-15.0, 15.0)
    horizontal_resolution: Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=45)] = 1.0
    max_range: Positive = 15.0
    mount_height: Positive = 0.6
    rate_hz: Positive = 5.0
    range_noise: NonNegative = 0.0

    @model_validator(mode="after")
    def _fov_and_ray_budget(self) -> SensorSpec:
        low, high = self.vertical_fov
        if not -90.0 <= low <= high <= 90.0:
            raise ValueError(f"vertical_fov must satisfy -90 <= low <= high <= 90 (got {low}, {high})")
        return self

    @property
    def rays(self) -> int:
        return self.channels * round(360.0 / self.horizontal_resolution)


class OdometryNoiseSpec(Strict):
    # random walks per metre travelled (runners/sim.py): after d metres the forward error has
    # std translation * sqrt(d) m and the heading error rotation_deg_per_m * sqrt(d) degrees
    translation: NonNegative
    rotation_deg_per_m: NonNegative


class OdometrySpec(Strict):
    noise: OdometryNoiseSpec | None = None


class AutoRouteSpec(Strict):
    min_length: Positive


class RouteSpec(Strict):
    waypoints: list[XY] | None = Field(default=None, min_length=2)
    auto: AutoRouteSpec | None = None

    @model_validator(mode="after")
    def _one_of(self) -> RouteSpec:
        if (self.waypoints is None) == (self.auto is None):
            raise ValueError("give exactly one of 'waypoints' or 'auto'")
        return self


class TrialSpec(Strict):
    start: tuple[Number, Number, Number]  # x, y, yaw in degrees
    goal: XY


class TrialGenerateSpec(Strict):
    count: Annotated[int, Field(strict=True, ge=1, le=10_000)]
    min_distance: NonNegative = 0.0
    max_distance: Positive | None = None  # extension of format 1: an upper bound on shortest_m

    @model_validator(mode="after")
    def _range(self) -> TrialGenerateSpec:
        if self.max_distance is not None and self.max_distance < self.min_distance:
            raise ValueError("max_distance must be >= min_distance")
        return self


class TrialsGenerate(Strict):
    generate: TrialGenerateSpec


class ScenarioSpec(Strict):
    format: Literal["navtopo-scenario/1"]
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9_.-]+$")
    description: str = ""
    seed: Integer = 0
    world: WorldSpec
    robot: RobotSpec = RobotSpec()
    sensor: SensorSpec = SensorSpec()
    odometry: OdometrySpec = OdometrySpec()
    mapping_route: RouteSpec
    trials: list[TrialSpec] | TrialsGenerate = []


UNION_TAGS = {"list[TrialSpec]", "TrialsGenerate", "MapSpec", "OdometryNoiseSpec", "AutoRouteSpec", "list[tuple[float, float]]"}


def _key(loc: tuple[Any, ...]) -> str:
    # pydantic names the branch of a union in the location ("TrialsGenerate", "list[...]"): drop
    # those tags, never a user's key
    parts = [str(p) for p in loc if not (isinstance(p, str) and (p in UNION_TAGS or p.startswith(("list[", "tuple["))))]
    return ".".join(parts) or "(top level)"


def _reason(error: dict[str, Any]) -> str:
    msg = str(error["msg"])
    msg = msg.removeprefix("Value error, ")
    if error["type"] == "extra_forbidden":
        return "unknown key"
    if error["type"] == "missing":
        loc = error.get("loc", ())
        if loc and isinstance(loc[-1], int):
            return "too few values"
        return "required key is missing"
    value = error.get("input")
    if error["type"] not in ("model_type",) and not isinstance(value, (dict, list)):
        msg = f"{msg} (got {value!r})"
    return msg


def parse_spec(data: Any, file: str | Path) -> ScenarioSpec:
    """Validate already-loaded YAML data; raise ``ScenarioError`` on the first problem."""
    if not isinstance(data, dict):
        raise ScenarioError(file, "", "not a YAML mapping of keys")
    try:
        return ScenarioSpec.model_validate(data)
    except ValidationError as exc:
        errors = exc.errors()
        # with a union ('trials'), prefer the branch error that names a real key
        errors.sort(key=lambda e: e["type"] == "list_type" or e["type"] == "model_type")
        first = errors[0]
        raise ScenarioError(file, _key(first["loc"]), _reason(first)) from None


def read_spec(path: str | Path) -> ScenarioSpec:
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ScenarioError(path, "", "no such file") from None
    except OSError as exc:
        raise ScenarioError(path, "", f"cannot read: {exc.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "(parse)"
        raise ScenarioError(path, where, f"not valid YAML: {getattr(exc, 'problem', exc)}") from None
    return parse_spec(data, path)
