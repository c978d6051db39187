"""The scenario file format, version 1 (see docs/DESIGN.md, "Scenario files").

Every key is validated; a bad file yields one ``ScenarioError`` whose message names the file,
the key and the reason, e.g. ``bad.yaml: world.corridors.0.width: must be > 0 (got -1.0)``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from navkit.errors import FileProblem
from scenarios.strict_yaml import YamlProblem, load_file

FORMAT = "navtopo-scenario/1"

# numbers are numbers: no strings or booleans coerced, no NaN or infinity
Number = Annotated[float, Field(strict=True, allow_inf_nan=False)]
Positive = Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0)]
NonNegative = Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0)]
Integer = Annotated[int, Field(strict=True)]
Flag = Annotated[bool, Field(strict=True)]
XY = tuple[Number, Number]
MAX_RASTER_CELLS = 60_000_000  # about 7.7 x 7.7 km at 1 m, 390 x 390 m at 0.05 m
# Bounds that keep a scenario that validates runnable (DESIGN.md, "Scenario validation, strictly"):
MAX_RAYS_PER_SCAN = 262_144  # 2^18: an Ouster OS1-128 at 2048 columns; each scan is cast in full every tick
MIN_RATE_HZ, MAX_RATE_HZ = 1.0, 50.0  # the control and sensor tick is 1 / rate_hz (runners/sim.py)
SUBSTEP_S = 0.05  # s, the simulator's collision-checked substep (runners/sim.py)
MAX_ROUTE_M = 100_000.0  # an auto route of 100 km takes a day to drive at 1 m/s
MAX_SENSOR_RANGE_M = 500.0
GOAL_TOLERANCE_M = 0.5  # the STOP rule's radius (runners.protocol): a trial's ends must lie farther apart
# A trial's shortest path must leave the robot this much room beyond its radius on each side in its
# narrowest gap (scenarios.gaps): one cell of the metric baseline's 0.1 m grid, so that a jamb its
# grid draws a cell into a door still leaves the robot through. Gaps are measured up to GAP_CAP_M
# (wider: wide open).
TRIAL_MARGIN_M = 0.1
GAP_CAP_M = 1.0


class ScenarioError(FileProblem):
    """A scenario that cannot be used; ``str(error)`` is the one line to show a user."""


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


class MapCleanSpec(Strict):
    """The map import's rules (``scenarios.map_import``; docs/DESIGN.md, "Map worlds")."""

    # islands of non-free cells smaller than the lidar resolves at resolve_range: made free,
    # grown to that size, or kept as the map draws them
    small_obstacles: Literal["remove", "grow", "keep"] = "remove"
    resolve_range: Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=MAX_SENSOR_RANGE_M)] = 3.0  # m
    close_gaps: Flag = True  # free slits narrower than that size become wall
    fans: Flag = True  # free cells no robot body covers, reaching unknown space, become wall


RAW_MAP = {"small_obstacles": "keep", "close_gaps": False, "fans": False}


class MapSpec(Strict):
    yaml: str  # a ROS map_server YAML file, relative to the scenario file
    # extension of format 1: true (the default rules), false (the raw map) or the rules one by one
    clean: MapCleanSpec = MapCleanSpec()

    @field_validator("clean", mode="before")
    @classmethod
    def _clean(cls, value: Any) -> Any:
        if value is True:
            return {}
        if value is False:
            return RAW_MAP
        if not isinstance(value, dict):
            raise ValueError("must be true, false or a mapping of rules (small_obstacles, resolve_range, close_gaps, fans)")
        return value


class WorldSpec(Strict):
    resolution: Positive = 0.05
    wall_height: Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0.1)] = 2.6
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
    radius: Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0.05, le=5.0)] = 0.3
    max_linear: Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0.05)] = 1.0
    max_angular: Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0.05, le=20.0)] = 1.5

    @model_validator(mode="after")
    def _no_tunnelling(self) -> RobotSpec:
        # collisions are checked at the end of every substep: a robot that moves more than its
        # radius in one could pass through a wall between two checks
        if self.max_linear * SUBSTEP_S > self.radius:
            raise ValueError(
                f"max_linear {self.max_linear} m/s moves the robot {self.max_linear * SUBSTEP_S:.2f} m per "
                f"{SUBSTEP_S} s collision check, more than its radius {self.radius} m (at most {self.radius / SUBSTEP_S:g} m/s)"
            )
        return self


class SensorSpec(Strict):
    channels: Annotated[int, Field(strict=True, ge=1, le=128)] = 16
    vertical_fov: tuple[Number, Number] = (-15.0, 15.0)
    horizontal_resolution: Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=45)] = 1.0
    max_range: Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=MAX_SENSOR_RANGE_M)] = 15.0
    mount_height: Positive = 0.6
    rate_hz: Annotated[float, Field(strict=True, allow_inf_nan=False, ge=MIN_RATE_HZ, le=MAX_RATE_HZ)] = 5.0
    range_noise: NonNegative = 0.0

    @model_validator(mode="after")
    def _fov_and_ray_budget(self) -> SensorSpec:
        low, high = self.vertical_fov
        if not -90.0 <= low <= high <= 90.0:
            raise ValueError(f"vertical_fov must satisfy -90 <= low <= high <= 90 (got {low}, {high})")
        if self.rays > MAX_RAYS_PER_SCAN:
            raise ValueError(
                f"{self.channels} channels x {round(360.0 / self.horizontal_resolution):,} columns "
                f"(horizontal_resolution {self.horizontal_resolution}°) = {self.rays:,} rays a scan, "
                f"more than the {MAX_RAYS_PER_SCAN:,} the simulator casts per tick"
            )
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
    min_length: Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=MAX_ROUTE_M)]


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
    # extension of format 1: run this trial although its shortest path passes a gap narrower than
    # TRIAL_MARGIN_M beyond the robot radius (else it is refused); its record is marked narrow
    allow_narrow: Flag = False


class TrialGenerateSpec(Strict):
    count: Annotated[int, Field(strict=True, ge=1, le=10_000)]
    min_distance: NonNegative = 0.0
    max_distance: Positive | None = None  # extension of format 1: an upper bound on shortest_m
    # extension of format 1: the room a trial's shortest path leaves the robot beyond its radius, on
    # each side, in its narrowest gap (scenarios.gaps); 0 keeps every trial the robot fits through
    margin: Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0, le=GAP_CAP_M)] = TRIAL_MARGIN_M

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
    seed: Annotated[int, Field(strict=True, ge=0, le=2**63 - 1)] = 0
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


def _reason(error: Mapping[str, Any]) -> str:
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
        spec = ScenarioSpec.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(file, *first_problem(exc)) from None
    return check_spec(spec, file)


def first_problem(exc: ValidationError) -> tuple[str, str]:
    """The key and the reason of a validation's first problem, as a user reads them."""
    errors = exc.errors()
    # with a union ('trials'), prefer the branch error that names a real key
    errors.sort(key=lambda e: e["type"] == "list_type" or e["type"] == "model_type")
    return _key(errors[0]["loc"]), _reason(errors[0])


def check_spec(spec: ScenarioSpec, file: str | Path) -> ScenarioSpec:
    """Checks across sections that no single section can make."""
    if spec.sensor.mount_height >= spec.world.wall_height:
        # the lidar would see over every wall (and from above the ceiling): nothing to map
        raise ScenarioError(
            file,
            "sensor.mount_height",
            f"{spec.sensor.mount_height} m is not below world.wall_height {spec.world.wall_height} m: "
            "the lidar would look over the walls" + (" from above the ceiling" if spec.world.ceiling else ""),
        )
    clean = spec.world.map.clean if spec.world.map is not None else None
    uses_range = clean is not None and (clean.small_obstacles != "keep" or clean.close_gaps)
    if clean is not None and uses_range and clean.resolve_range > spec.sensor.max_range:
        raise ScenarioError(
            file,
            "world.map.clean.resolve_range",
            f"{clean.resolve_range} m is beyond sensor.max_range {spec.sensor.max_range} m: the lidar sees nothing there",
        )
    return spec


def read_yaml(path: str | Path, file: str | Path | None = None) -> Any:
    """A user's YAML file (``strict_yaml``: YAML 1.2 numbers, unique keys); ``ScenarioError``
    naming ``file`` (default: ``path``) and the line on any problem."""
    path = Path(path)
    file = path if file is None else file
    try:
        return load_file(path)
    except FileNotFoundError:
        raise ScenarioError(file, "", "no such file") from None
    except IsADirectoryError:
        raise ScenarioError(file, "", "is a folder, not a YAML file") from None
    except OSError as exc:
        raise ScenarioError(file, "", f"cannot read: {exc.strerror or exc}") from None
    except YamlProblem as exc:
        raise ScenarioError(file, f"line {exc.line}" if exc.line is not None else "", exc.reason) from None


def read_spec(path: str | Path) -> ScenarioSpec:
    return parse_spec(read_yaml(path), path)
