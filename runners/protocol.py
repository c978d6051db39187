"""One protocol for every compared system: what each is told at a trial's start, when it may say
"reached", and the two benchmark settings (DESIGN.md, "The NavigationSystem protocol").

* Initial pose, two protocols (``initial_pose``). ``perturbed`` (default): a system whose entry
  ``wants_initial_pose`` gets the trial's start in the map frame perturbed by a seeded error, as a
  person setting it by hand would: uniform in ``±initial_pose_error_xy`` metres along x and y and
  ``±initial_pose_error_yaw_deg`` degrees (default ±0.5 m, ±10°; 0 gives the exact start). It must
  correct the error by its own registration (NavTopo takes it as a prior for its start-up). The
  error of trial i depends on (seed, trial) only, so it is the same with any number of workers, on
  resume, and for every system. Systems without the flag get nothing. ``none`` (kidnapped): no
  system gets a pose; each localizes globally on its own map and confirms it over motion.
* Stop tolerance. Every system that declares ``reached`` by its own estimate uses one tolerance
  (``stop_tolerance``, 0.25 m as nav2's default, so a map up to 0.25 m off the world frame still
  stops within the STOP rule); the runner's STOP rule (success) stays ``goal_tolerance`` (0.5 m) on
  the true pose.
* Goals. ``map`` (default): every system gets the goal as a point in the map frame, the frame of
  the mapping run's first pose; a system without a global frame converts it with its own estimate
  (NavTopo: its locations' poses relaxed over the graph), and bears that estimate's error.
  ``native``: a system that names places by where it made them (``set_goal_anchored``: NavTopo's
  ``(v_goal, T_goal)``, the paper's goal form) gets the goal relative to the true pose of the
  location nearest to it in sight, as a person would pick it on the graph; the others still get a
  map-frame point. Precise odometry makes the two the same.
* Settings. ``precise`` is the paper's: exact odometry, no lidar range noise. ``noisy``: odometry
  random walks of 2 % and 0.5°/m, lidar range noise 1 cm. A run under a setting overrides the
  scenario file's odometry noise and range noise; without one, the file's own values hold and the
  manifest names the setting they amount to (``precise``, ``noisy`` or ``custom``).
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from navkit import geometry as se2
from navkit.types import STOP_TOLERANCE_M
from runners.systems import GroundTruth, SystemContext, SystemEntry
from scenarios import Scenario
from scenarios.schema import GOAL_TOLERANCE_M, OdometryNoiseSpec

if TYPE_CHECKING:
    from runners.sim import Simulator

INITIAL_POSE_SALT = 0x1A17  # keeps the initial-pose stream apart from the sensor noise streams
INITIAL_POSES = ("perturbed", "none")
TEXT_FIELDS = ("goals", "initial_pose")


@dataclass(frozen=True)
class TrialProtocol:
    initial_pose_error_xy: float = 0.5  # m, uniform in [-e, e] along x and along y
    initial_pose_error_yaw_deg: float = 10.0  # degrees, uniform in [-e, e]
    stop_tolerance: float = STOP_TOLERANCE_M  # m, systems that say "reached" by their own estimate
    goal_tolerance: float = GOAL_TOLERANCE_M  # m, the runner's STOP rule on the true pose
    goals: str = "map"  # "map": map-frame points for all; "native": location-relative for graph systems
    initial_pose: str = "perturbed"  # INITIAL_POSES: "perturbed" (the start with the error) or "none" (kidnapped)

    def as_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any] | None) -> TrialProtocol:
        """The protocol a manifest recorded; a manifest from before the protocol existed had exact
        initial poses and the followers' 0.5 m tolerance."""
        if not data:
            return cls(initial_pose_error_xy=0.0, initial_pose_error_yaw_deg=0.0, stop_tolerance=0.5)
        known = {f.name for f in dataclasses.fields(cls)}
        fields: dict[str, Any] = {k: (str(v) if k in TEXT_FIELDS else float(v)) for k, v in data.items() if k in known}
        return cls(**fields)

    @property
    def gives_pose(self) -> bool:
        """Whether systems that take an initial pose get one (``perturbed``), or none does (``none``)."""
        return self.initial_pose == "perturbed"

    def initial_pose_error(self, seed: int, trial: int) -> NDArray[np.float64]:
        """(3,) [dx, dy, dyaw] of trial ``trial``: the error added to the true start (map frame)."""
        rng = np.random.default_rng([int(seed), INITIAL_POSE_SALT, int(trial)])
        dx, dy = rng.uniform(-1.0, 1.0, 2) * self.initial_pose_error_xy
        dyaw = rng.uniform(-1.0, 1.0) * np.radians(self.initial_pose_error_yaw_deg)
        return np.array([dx, dy, dyaw])

    def given_initial_pose(self, true_start_in_map: NDArray, seed: int, trial: int) -> NDArray[np.float64]:
        """The initial pose a system is given: the true start (map frame) moved by the error,
        x and y in the map frame, yaw added."""
        error = self.initial_pose_error(seed, trial)
        pose = np.asarray(true_start_in_map, dtype=np.float64) + error
        pose[2] = se2.wrap_angle(pose[2])
        return pose


def context_for(
    entry: SystemEntry, scenario: Scenario, sim: Simulator | None, protocol: TrialProtocol | None = None
) -> SystemContext:
    """What a system is told: the robot, the sensor, the stop tolerance; ground truth only if the
    entry is privileged (the oracle), with the world of the stage the simulator runs."""
    protocol = protocol or TrialProtocol()
    truth = None
    if entry.privileged:
        world = scenario.world
        if sim is not None and sim.with_changes:
            world = scenario.navigation_world
        truth = GroundTruth(world=world, world_from_map=scenario.route_start, true_pose=(lambda: sim.true_pose) if sim else None)
    return SystemContext(
        robot=scenario.spec.robot, sensor=scenario.spec.sensor, stop_tolerance=protocol.stop_tolerance, ground_truth=truth
    )


@dataclass(frozen=True)
class Setting:
    name: str
    odometry_noise: OdometryNoiseSpec | None
    range_noise: float


SETTINGS: dict[str, Setting] = {
    "precise": Setting("precise", None, 0.0),
    "noisy": Setting("noisy", OdometryNoiseSpec(translation=0.02, rotation_deg_per_m=0.5), 0.01),
    # the drift sweep's strong level: odometry 2.5x the noisy setting's, the same lidar
    "strong": Setting("strong", OdometryNoiseSpec(translation=0.05, rotation_deg_per_m=1.25), 0.01),
}


def setting_of(scenario: Scenario) -> str:
    """The name of the setting a scenario's own sensor and odometry amount to."""
    spec = scenario.spec
    for setting in SETTINGS.values():
        if spec.odometry.noise == setting.odometry_noise and spec.sensor.range_noise == setting.range_noise:
            return setting.name
    return "custom"


def apply_setting(scenario: Scenario, name: str | None) -> Scenario:
    """The scenario under a setting (its odometry noise and lidar range noise replaced); ``None``
    keeps the file's own. The world, route and trials are shared, not rebuilt."""
    if name is None:
        return scenario
    if name not in SETTINGS:
        raise ValueError(f"unknown setting {name!r} (choose from {', '.join(SETTINGS)})")
    setting = SETTINGS[name]
    spec = scenario.spec
    new_spec = spec.model_copy(
        update={
            "odometry": spec.odometry.model_copy(update={"noise": setting.odometry_noise}),
            "sensor": spec.sensor.model_copy(update={"range_noise": setting.range_noise}),
        }
    )
    clone = copy.copy(scenario)  # shares the world, route, trials and cached rasters
    clone.spec = new_spec
    return clone
