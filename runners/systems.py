"""The NavigationSystem protocol and the registry of compared systems.

A new method is one class and one ``@register_system`` line. The runner drives every system
through the same calls (DESIGN.md, "The NavigationSystem protocol"):

mapping:     ``create(config, context)`` → ``observe(obs)`` per scan → ``finish_mapping()`` →
             ``save(directory)``; ``mapping_stats()`` for the mapping report
navigation:  ``load(directory, config, context)`` in a fresh process → per trial
             ``reset()`` (optional: forget the previous trial) →
             [``set_initial_pose(pose)`` if the entry ``wants_initial_pose``] → ``set_goal(goal)`` →
             ``step(obs)`` per tick until ``status`` is not active; ``stats()`` after each trial
memory:      ``memory()`` → ``MemoryBreakdown`` (exact bytes now held: map, localization, derived,
             model); ``disk_usage(directory)`` (optional static) → bytes of a saved map per part

Frames: goals and initial poses are in the map frame, the frame of the mapping run's first
odometry pose. Ground truth reaches a system only if its entry is ``privileged`` (the oracle);
it then comes as ``context.ground_truth``. The initial pose a system is given carries the
protocol's seeded error (``runners.protocol``); every system that declares ``reached`` by its
own estimate stops within ``context.stop_tolerance`` of the goal by that estimate.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict

from navkit import geometry as se2
from navkit import grid_search
from navkit.follower import FollowerConfig, PathFollower
from navkit.grid_planning import plan_path
from navkit.raster import GridFrame
from navkit.types import STOP_TOLERANCE_M, Command, FailureStage, MemoryBreakdown, NavStatus, Observation, Status
from scenarios.schema import RobotSpec, SensorSpec

__all__ = [
    "Command",
    "FailureStage",
    "GroundTruth",
    "MemoryBreakdown",
    "NavStatus",
    "NavigationSystem",
    "Observation",
    "Status",
    "SystemContext",
    "SystemEntry",
    "register_system",
    "registry",
    "get_system",
    "import_modules",
]


@dataclass
class GroundTruth:
    """What a privileged system may know: the GT world and the true pose, nothing else is given."""

    world: Any  # scenarios.world.World
    world_from_map: NDArray[np.float64]  # (3,) pose of the map frame in the scenario frame
    true_pose: Callable[[], NDArray[np.float64]] | None = None  # scenario frame, set by the runner


@dataclass
class SystemContext:
    """What every system is told about the robot it runs on (no ground truth)."""

    robot: RobotSpec
    sensor: SensorSpec
    stop_tolerance: float = STOP_TOLERANCE_M  # m: declare "reached" within this of the goal, by the own estimate
    ground_truth: GroundTruth | None = None


@runtime_checkable
class NavigationSystem(Protocol):
    status: NavStatus

    def observe(self, obs: Observation) -> None: ...
    def finish_mapping(self) -> None: ...
    def save(self, directory: Path) -> None: ...
    def set_goal(self, goal: NDArray[np.float64]) -> None: ...
    def step(self, obs: Observation) -> Command: ...
    def stats(self) -> dict[str, Any]: ...
    def mapping_stats(self) -> dict[str, Any]: ...
    def memory(self) -> MemoryBreakdown: ...


@dataclass
class SystemEntry:
    name: str
    cls: type[Any]  # the system's class: create, load (classmethods), optional warm_up and disk_usage
    config_model: type[BaseModel]
    privileged: bool = False
    wants_initial_pose: bool = False
    description: str = ""
    setting_overrides: dict[str, dict[str, Any]] = field(default_factory=dict)  # {setting: config overrides}

    def default_config(self) -> BaseModel:
        return self.config_model()

    def create(self, config: BaseModel, context: SystemContext) -> NavigationSystem:
        return self.cls.create(config, context)

    def load(self, directory: Path, config: BaseModel, context: SystemContext) -> NavigationSystem:
        return self.cls.load(directory, config, context)


_REGISTRY: dict[str, SystemEntry] = {}


def register_system(
    name: str,
    *,
    config: type[BaseModel],
    privileged: bool = False,
    wants_initial_pose: bool = False,
    description: str = "",
    setting_overrides: dict[str, dict[str, Any]] | None = None,
) -> Callable[[type], type]:
    """Register a system class; ``setting_overrides``: config overrides the runner applies under a
    benchmark setting (``runners.protocol.SETTINGS``), as a user configures a robot for its sensors."""

    def decorate(cls: type) -> type:
        summary = description or ((cls.__doc__ or "").strip().splitlines() or [""])[0]
        _REGISTRY[name] = SystemEntry(name, cls, config, privileged, wants_initial_pose, summary, dict(setting_overrides or {}))
        return cls

    return decorate


# Systems of the lower layers: they never import the runner (DESIGN.md), so the registry names them
# here, and imports each only when it is asked for: a worker running the baseline never loads
# NavTopo's torch runtime, so its process RSS is its own.
_BUILTIN: dict[str, tuple[str, str, str, dict[str, Any]]] = {
    "navtopo": (
        "navtopo.system",
        "NavTopo",
        "NavTopoConfig",
        {
            "wants_initial_pose": True,
            "description": "NavTopo: graph of locations (PRISM-TopoMap), place recognition, scan matching",
        },
    ),
    "metric_grid": (
        "baselines.metric_grid.system",
        "MetricGrid",
        "MetricGridConfig",
        {"wants_initial_pose": True, "description": "kiss-icp + gtsam pose graph + global 0.1 m occupancy grid + Theta*"},
    ),
}


def _load_builtin(name: str | None = None) -> None:
    """Register the built-in system ``name`` (all of them when None) by importing its module."""
    import importlib

    for builtin, (module, cls_name, config_name, flags) in _BUILTIN.items():
        if builtin in _REGISTRY or (name is not None and builtin != name):
            continue
        loaded = importlib.import_module(module)
        overrides = getattr(loaded, "SETTING_OVERRIDES", None)
        register_system(builtin, config=getattr(loaded, config_name), setting_overrides=overrides, **flags)(
            getattr(loaded, cls_name)
        )


def registry() -> dict[str, SystemEntry]:
    _load_builtin()
    return dict(_REGISTRY)


def system_names() -> list[str]:
    """Every system's name, without importing any system's module."""
    return sorted(set(_REGISTRY) | set(_BUILTIN))


def get_system(name: str) -> SystemEntry:
    _load_builtin(name)
    if name not in _REGISTRY:
        raise KeyError(f"unknown system {name!r} (known: {', '.join(system_names())})")
    return _REGISTRY[name]


def import_modules(modules: list[str]) -> None:
    """Import the modules that register a job's systems (those registered outside this module,
    e.g. by a test): a worker process knows only the built-in ones."""
    import importlib

    for module in modules:
        importlib.import_module(module)


# ---------------------------------------------------------------------------------------------
# the oracle


class OracleConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    # plan this far beyond the robot radius from walls, so that the follower's small deviations
    # at corners do not touch them (without a path at that margin, the radius alone is used)
    clearance_margin: float = 0.15
    follower: FollowerConfig = FollowerConfig()


@register_system(
    "oracle",
    config=OracleConfig,
    privileged=True,
    description="Theta* on the ground-truth raster + the shared follower: the efficiency upper bound",
)
class Oracle:
    """Theta* on the ground-truth raster eroded by the robot radius, driven by the shared follower."""

    def __init__(self, config: OracleConfig, context: SystemContext) -> None:
        if context.ground_truth is None:
            raise ValueError("the oracle needs ground truth (it is a privileged system)")
        self.config = config
        self.truth = context.ground_truth
        self.world = context.ground_truth.world
        # the raster marks a cell by its centre, so a wall may reach half a cell diagonal into a free
        # cell: the tight level keeps that much beyond the radius (door jambs' corners; BENCHMARKS.md,
        # "Design choices: the oracle's tight level": on a generated ring with 0.8 m doors it collided in
        # 8 of 11 trials without it)
        self.tight = context.robot.radius + self.world.resolution * np.sqrt(0.5)
        self.passable_tight = self.world.eroded(self.tight)
        self.passable = self.world.eroded(context.robot.radius + config.clearance_margin)
        self.prefer = context.robot.radius + config.clearance_margin
        # a path on the tight level is eased toward the margin where there is room (``ease_path``):
        # through a door of the robot's width and a little more it passed a jamb's corner 0.02 m
        # beyond the radius, and the follower's deviation touched it (loop_office_door, trial 1)
        self.clearance = np.minimum(grid_search.clearance_squared(self.world.free), 255).astype(np.uint8)
        self.follower = PathFollower(config.follower.for_robot(context))
        self.status = NavStatus()
        self.goal_world: NDArray[np.float64] | None = None
        self.planning_ms: list[float] = []
        self.scans = 0

    @staticmethod
    def warm_up() -> None:
        """Load the compiled planner before anything is timed or measured."""
        grid_search.theta_star(np.ones((8, 8), bool), (0, 0), (7, 7))

    # mapping: the oracle needs no map of its own
    @classmethod
    def create(cls, config: OracleConfig, context: SystemContext) -> Oracle:
        return cls(config, context)

    def observe(self, obs: Observation) -> None:
        self.scans += 1

    def finish_mapping(self) -> None:
        pass

    def save(self, directory: Path) -> None:
        directory.mkdir(parents=True, exist_ok=True)
        (directory / "oracle.json").write_text(json.dumps({"map": "ground-truth raster of the scenario"}) + "\n")

    @classmethod
    def load(cls, directory: Path, config: OracleConfig, context: SystemContext) -> Oracle:
        if not (directory / "oracle.json").is_file():
            raise FileNotFoundError(f"{directory}: not an oracle map folder (oracle.json missing)")
        return cls(config, context)

    def mapping_stats(self) -> dict[str, Any]:
        return {"map_bytes": self.memory().map}

    def memory(self) -> MemoryBreakdown:
        """The GT raster is the oracle's map; its two eroded copies are derived for planning."""
        derived = self.passable.nbytes + self.passable_tight.nbytes + self.clearance.nbytes
        return MemoryBreakdown(map=int(self.world.free.nbytes), derived=int(derived))

    # navigation
    def reset(self) -> None:
        self.goal_world = None
        self.status = NavStatus()
        self.planning_ms = []
        self._planned = False
        self.follower.clear()

    def set_goal(self, goal: NDArray[np.float64]) -> None:
        self.reset()
        self.goal_world = se2.transform_points(self.truth.world_from_map, np.asarray(goal, float)[None, :2])[0]

    def _pose(self) -> NDArray[np.float64]:
        assert self.truth.true_pose is not None, "the runner sets true_pose for privileged systems"
        return self.truth.true_pose()

    def step(self, obs: Observation) -> Command:
        pose = self._pose()
        if not self._planned:
            self._planned = True
            t0 = time.perf_counter()
            path = self._plan(pose[:2])
            self.planning_ms.append((time.perf_counter() - t0) * 1e3)
            if path is None:
                assert self.goal_world is not None
                where = f"from ({pose[0]:.2f}, {pose[1]:.2f}) to ({self.goal_world[0]:.2f}, {self.goal_world[1]:.2f})"
                detail = f"no path on the ground-truth raster {where} at either clearance"
                self.status = NavStatus(Status.FAILED, "no_path", FailureStage.GLOBAL_PLAN, detail)
                return Command()
            self.follower.set_path(path)
            self.status = NavStatus(detail=f"following a {_length(path):.1f} m path on the ground-truth raster")
        command = self.follower.command(pose)
        if self.follower.reached:
            self.status = NavStatus(Status.REACHED)
            return Command()
        return command

    def _plan(self, start_xy: NDArray) -> NDArray[np.float64] | None:
        assert self.goal_world is not None
        frame = GridFrame(self.world.origin, self.world.resolution)
        planned = plan_path([self.passable], frame, start_xy, self.goal_world, snap_cells=10)
        if planned is None:
            planned = plan_path(
                [self.passable_tight],
                frame,
                start_xy,
                self.goal_world,
                snap_cells=10,
                clearance=self.clearance,
                prefer_m=self.prefer,
                hold_m=self.tight,
            )
        return planned.points if planned is not None else None

    def stats(self) -> dict[str, Any]:
        return {"planning_ms": list(self.planning_ms), "map_bytes": self.memory().map}

    def pose_estimate(self) -> NDArray[np.float64] | None:
        return None


def _length(path: NDArray[np.float64]) -> float:
    return float(np.hypot(*np.diff(path, axis=0).T).sum()) if len(path) > 1 else 0.0
