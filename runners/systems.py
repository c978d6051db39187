"""The NavigationSystem protocol and the registry of compared systems.

A new method is one class and one ``@register_system`` line. The runner drives every system
through the same calls (DESIGN.md, "The NavigationSystem protocol"):

mapping:     ``create(config, context)`` → ``observe(obs)`` per scan → ``finish_mapping()`` →
             ``save(directory)``; ``mapping_stats()`` for the mapping report
navigation:  ``load(directory, config, context)`` in a fresh process → per trial
             [``set_initial_pose(pose)`` if the entry ``wants_initial_pose``] → ``set_goal(goal)`` →
             ``step(obs)`` per tick until ``status`` is not active; ``stats()`` after each trial

Frames: goals and initial poses are in the map frame, the frame of the mapping run's first
odometry pose. Ground truth reaches a system only if its entry is ``privileged`` (the oracle);
it then comes as ``context.ground_truth``.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict

from navtopo import geometry as se2
from navtopo import grid_search
from navtopo.follower import FollowerConfig, PathFollower
from navtopo.types import Command, NavStatus, Observation, Status
from scenarios.schema import RobotSpec, SensorSpec

__all__ = [
    "Command",
    "GroundTruth",
    "NavStatus",
    "NavigationSystem",
    "Observation",
    "Status",
    "SystemContext",
    "SystemEntry",
    "register_system",
    "registry",
    "get_system",
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


@dataclass
class SystemEntry:
    name: str
    cls: type
    config_model: type[BaseModel]
    privileged: bool = False
    wants_initial_pose: bool = False
    description: str = ""

    def default_config(self) -> BaseModel:
        return self.config_model()

    def create(self, config: BaseModel, context: SystemContext) -> NavigationSystem:
        return self.cls.create(config, context)

    def load(self, directory: Path, config: BaseModel, context: SystemContext) -> NavigationSystem:
        return self.cls.load(directory, config, context)


_REGISTRY: dict[str, SystemEntry] = {}


def register_system(
    name: str, *, config: type[BaseModel], privileged: bool = False, wants_initial_pose: bool = False, description: str = ""
) -> Callable[[type], type]:
    def decorate(cls: type) -> type:
        _REGISTRY[name] = SystemEntry(
            name, cls, config, privileged, wants_initial_pose, description or (cls.__doc__ or "").strip().splitlines()[0]
        )
        return cls

    return decorate


def _load_builtin() -> None:
    """Register the systems of the lower layers: they never import the runner (DESIGN.md), so the
    registry names them here."""
    if "navtopo" not in _REGISTRY:
        from navtopo.system import NavTopo, NavTopoConfig

        register_system(
            "navtopo",
            config=NavTopoConfig,
            description="NavTopo: graph of locations (PRISM-TopoMap), place recognition, scan matching",
        )(NavTopo)
    if "metric_grid" not in _REGISTRY:
        try:
            from baselines.metric_grid.system import MetricGrid, MetricGridConfig
        except ModuleNotFoundError as exc:  # the baseline lands in its own milestone
            if exc.name != "baselines.metric_grid.system":
                raise
        else:
            register_system(
                "metric_grid",
                config=MetricGridConfig,
                wants_initial_pose=True,
                description="kiss-icp + gtsam pose graph + global 0.1 m occupancy grid + Theta*",
            )(MetricGrid)


def registry() -> dict[str, SystemEntry]:
    _load_builtin()
    return dict(_REGISTRY)


def get_system(name: str) -> SystemEntry:
    systems = registry()
    if name not in systems:
        raise KeyError(f"unknown system {name!r} (known: {', '.join(sorted(systems))})")
    return systems[name]


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
        self.passable_tight = self.world.eroded(context.robot.radius)
        self.passable = self.world.eroded(context.robot.radius + config.clearance_margin)
        follower_config = config.follower.model_copy(
            update={"max_linear": context.robot.max_linear, "max_angular": context.robot.max_angular}
        )
        self.follower = PathFollower(follower_config)
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
        return {"map_bytes": int(self.passable.nbytes)}

    # navigation
    def set_goal(self, goal: NDArray[np.float64]) -> None:
        self.goal_world = se2.transform_points(self.truth.world_from_map, np.asarray(goal, float)[None, :2])[0]
        self.status = NavStatus()
        self.planning_ms = []
        self._planned = False

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
                self.status = NavStatus(Status.FAILED, "no_path")
                return Command()
            self.follower.set_path(path)
        command = self.follower.command(pose)
        if self.follower.reached:
            self.status = NavStatus(Status.REACHED)
            return Command()
        return command

    def _plan(self, start_xy: NDArray) -> NDArray[np.float64] | None:
        assert self.goal_world is not None
        w = self.world
        for passable in (self.passable, self.passable_tight):
            start = grid_search.nearest_free(passable, w.to_cell(start_xy), 10)
            goal = grid_search.nearest_free(passable, w.to_cell(self.goal_world), 10)
            if start is None or goal is None:
                continue
            cells = grid_search.theta_star(passable, start, goal)
            if cells is not None:
                return np.vstack([start_xy[None, :], w.to_world(cells[1:-1]), self.goal_world[None, :]])
        return None

    def stats(self) -> dict[str, Any]:
        return {"planning_ms": list(self.planning_ms), "map_bytes": int(self.passable.nbytes)}

    def pose_estimate(self) -> NDArray[np.float64] | None:
        return None
