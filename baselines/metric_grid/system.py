"""MetricGrid: the NavigationSystem of the metric SLAM baseline (DESIGN.md, issue 5).

The pipeline the paper compares NavTopo with (RTAB-MAP + Theta*), from well-kept parts. It
composes the parts of this package and owns no algorithm but the small navigation loop:

mapping      odometry (``navkit.odometry.LidarOdometry``: wheel, or kiss-icp seeded by the wheels) ->
             keyframes and verified loop closures (``pose_graph.PoseGraph``, gtsam) -> at the end,
             batch optimisation and the global 0.1 m log-odds grid traced from every keyframe at
             its optimised pose (``occupancy.OccupancyGrid``); saved as a ROS map_server map
             (``map.png`` + ``map.yaml``) beside the pose graph and ``metric_grid.json``.
navigation   as a Nav2 user runs it: the map is loaded and an initial pose given in the map
             frame, set by hand (off by up to the protocol's ±0.5 m, ±10°); the robot finds its
             pose on the map by a correlative search around it, or over the whole map when
             nothing there fits (``localization.Relocalizer``), turning in place until it does;
             then odometry composed onto it (the ``map -> odom`` transform) is corrected by
             scan-to-map registration at every scan (``localization.ScanToMap``); Theta*
             (``navkit.grid_search``, the compiled kernel NavTopo's local planner uses) on the
             map's free cells eroded by the robot radius plus a margin, unknown cells blocked;
             replanning at a fixed rate and when newly seen obstacles block the path (they stay
             blocked until the lidar sees through them, ``navkit.obstacles``); the shared
             ``PathFollower`` drives and stops at the protocol's stop tolerance.

Memory (``memory()``, the runner's breakdown): ``map`` is the trinary grid as loaded,
``localization`` the distance field of the scan-to-map fit and the relocalizer's score field,
``derived`` the eroded planning masks; the mapping state (keyframe scans, kiss-icp local map, pose
graph, log-odds grid) comes as separate keys of ``mapping_stats()``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from navkit import geometry as se2
from navkit import grid_search
from navkit.follower import FollowerConfig, PathFollower
from navkit.grid_planning import plan_path
from navkit.obstacles import ObstacleMemory
from navkit.odometry import LidarOdometry, OdometryConfig
from navkit.raster import FREE, OCCUPIED, GridFrame
from navkit.scan import CEILING_HEIGHT, FLOOR_HEIGHT, obstacle_points
from navkit.types import Command, MemoryBreakdown, NavStatus, Observation, Status

from .localization import RelocalizationConfig, Relocalizer, ScanToMap, ScanToMapConfig
from .occupancy import GridMap, OccupancyConfig, OccupancyGrid
from .pose_graph import PoseGraph, PoseGraphConfig
from .scan2d import keyframe_scan, voxel_filter_2d

FORMAT = "navtopo-metric-grid/1"
MAP_YAML = "map.yaml"
MANIFEST = "metric_grid.json"


# ---------------------------------------------------------------------------------------------
# configuration


class ScanConfig(BaseModel):
    """The height band whose returns are obstacles: the shared rule (``navkit.scan``)."""

    model_config = ConfigDict(extra="forbid")

    floor_height: float = Field(FLOOR_HEIGHT, description="m above the floor; lower returns are floor")
    ceiling_height: float = Field(CEILING_HEIGHT, description="m above the floor; higher returns are ceiling")


class PlanningConfig(BaseModel):
    """Theta* on the global grid, and when to plan again."""

    model_config = ConfigDict(extra="forbid")

    inflation_margin: float = Field(
        0.1,
        ge=0,
        description="m beyond the robot radius (and half a cell, so the clearance holds to the cell boundary) "
        "that paths keep from mapped walls; the follower deviates a little at corners",
    )
    unknown_fallback: bool = Field(True, description="with no path through known free cells, count unknown as free")
    snap_radius: float = Field(1.0, ge=0, description="m; a start or goal in the inflated zone moves to the nearest free cell")
    replan_period: float = Field(2.0, gt=0, description="s of simulated time between replans")
    block_check_distance: float = Field(5.0, gt=0, description="m of the path ahead checked against new obstacles")
    block_clearance: float = Field(0.05, ge=0, description="m beyond the robot radius; nearer new obstacles block")
    new_obstacle_distance: float = Field(0.25, gt=0, description="m from every mapped wall: an obstacle the map lacks")
    new_obstacle_range: float = Field(6.0, gt=0, description="m; only nearer returns can be new obstacles")


#: Overrides for the benchmark's noisy setting (wheel odometry with 2 % and 0.5°/m random walks,
#: lidar range noise 1 cm), chosen on generated scenes (benchmarks/tune_metric_mapping.py, trees
#: seeds 101-103 and a ring building; BENCHMARKS.md, "Tuning"): noisy wheels fail on every generated
#: scene (wall recall 0.33-0.85, the map turned up to 2.5°), so kiss-icp seeded by the wheels; of the
#: odometry-factor sigmas tried, yaw 0.1° + 0.1°/m with the default xy sigmas had the best worst case
#: over the four noisy scenes (trees 0.969 mean / 0.919 worst, ring 0.904 wall recall). Since
#: session 11 the lidar odometry refines kiss-icp point-to-line (``navkit.odometry``), for both
#: systems: on the same trees wall recall 0.991 mean / 0.986 worst, ATE 0.086 -> 0.021 m mean.
NOISY_ODOMETRY: dict[str, Any] = {
    "odometry": {"source": "lidar"},
    "pose_graph": {"odometry_sigma_yaw_deg": 0.1, "odometry_sigma_yaw_deg_per_m": 0.1},
}

#: Overrides for the benchmark's precise setting (exact wheel odometry): odometry factors as tight
#: as the odometry (0.002 m + 0.002/m, 0.02° + 0.02°/m), chosen on generated scenes
#: (benchmarks/tune_metric_mapping.py, candidate ``wheel-precise``; BENCHMARKS.md, "The metric
#: baseline's precise recipe"). With the default factors (0.02 m + 0.02/m, 0.5° + 0.5°/m) the few
#: loop closures a few tenths of a degree off bent exact odometry by 0.03-0.08 m RMS (ATE) on the
#: generated trees and ring, and by up to 0.28 m over an 800 m route: stops 0.51-0.52 m from goals.
#: Tight factors keep the loops (they still close, and agree) and the ATE at 0.002-0.007 m.
PRECISE_ODOMETRY: dict[str, Any] = {
    "pose_graph": {
        "odometry_sigma_xy": 0.002,
        "odometry_sigma_xy_per_m": 0.002,
        "odometry_sigma_yaw_deg": 0.02,
        "odometry_sigma_yaw_deg_per_m": 0.02,
    },
}

#: What the runner applies for a benchmark setting, as a user configures a robot for its odometry.
#: The drift sweep's strong setting uses the noisy setting's configuration (not tuned for it).
SETTING_OVERRIDES: dict[str, dict[str, Any]] = {
    "precise": PRECISE_ODOMETRY,
    "noisy": NOISY_ODOMETRY,
    "strong": NOISY_ODOMETRY,
}


class MetricGridConfig(BaseModel):
    """Every parameter of the metric baseline; defaults are for the benchmark's precise odometry.

    * ``odometry.source: wheel``: with precise wheel odometry the keyframes get the true relative
      poses, the best map on every generated scene tried (BENCHMARKS.md, "Tuning"); under the
      precise setting the runner also applies ``SETTING_OVERRIDES["precise"]`` (``PRECISE_ODOMETRY``:
      odometry factors as tight as the odometry, so that loop closures cannot bend it). With noisy
      wheel odometry (2 %, 0.5°/m) the runner applies ``SETTING_OVERRIDES["noisy"]``
      (``NOISY_ODOMETRY``: kiss-icp seeded by the wheels, tighter yaw factors, loop closures on
      top). The same odometry tracks the pose during navigation.
    * ``localization.enabled: true``: scan-to-map registration, as a deployed robot localises on its
      map (AMCL in Nav2, RTAB-MAP's localisation mode). With noisy odometry it is what makes trials
      succeed (tracking error 0.17 m median -> 5 mm on ``tiny``); with precise odometry it costs a
      few centimetres where the map itself is off (a 0.1 m grid knows a wall to half a cell).
    * ``follower.goal_tolerance``: the protocol's stop tolerance (0.35 m, the same for every system
      that stops by its own estimate), so a few centimetres of tracking error cannot put the robot
      beyond the runner's 0.5 m.

    ``odometry.max_range`` and ``occupancy.max_range`` follow the sensor, the follower's speed limits
    follow the robot: they are filled in from the context in ``create``/``load``, in one place.
    """

    model_config = ConfigDict(extra="forbid")

    odometry: OdometryConfig = OdometryConfig(source="wheel")
    pose_graph: PoseGraphConfig = PoseGraphConfig()
    occupancy: OccupancyConfig = OccupancyConfig()
    scan: ScanConfig = ScanConfig()
    online_grid: bool = Field(True, description="keep a grid up to date while mapping (for the growth figures)")
    localization: ScanToMapConfig = ScanToMapConfig()
    relocalization: RelocalizationConfig = RelocalizationConfig()
    planning: PlanningConfig = PlanningConfig()
    follower: FollowerConfig = FollowerConfig()

    @classmethod
    def for_noisy_odometry(cls) -> MetricGridConfig:
        """The defaults with ``NOISY_ODOMETRY`` applied."""
        return cls.model_validate(NOISY_ODOMETRY)


def _for_context(config: MetricGridConfig, context: Any) -> MetricGridConfig:
    """The config with the sensor's range, the robot's speed limits and the stop tolerance filled in."""
    if context is None:
        return config
    sensor = context.sensor
    return config.model_copy(
        update={
            "odometry": config.odometry.model_copy(update={"max_range": float(sensor.max_range)}),
            "occupancy": config.occupancy.model_copy(update={"max_range": float(sensor.max_range)}),
            "follower": config.follower.for_robot(context),
        }
    )


class MapLoadError(ValueError):
    """A saved metric map that cannot be loaded; the message names the file."""


# ---------------------------------------------------------------------------------------------
# the system


class MetricGrid:
    """kiss-icp + gtsam pose graph + global 0.1 m occupancy grid + Theta* (the metric baseline)."""

    def __init__(self, config: MetricGridConfig, context: Any = None) -> None:
        self.config = _for_context(config, context)
        self.robot_radius = float(context.robot.radius) if context is not None else 0.3
        self.band = self.config.scan
        self.status = NavStatus()
        # mapping state
        self.odometry: LidarOdometry | None = None
        self.pose_graph: PoseGraph | None = None
        self.online_grid: OccupancyGrid | None = None
        self.grid: OccupancyGrid | None = None  # the final log-odds grid (finish_mapping)
        self.grid_map: GridMap | None = None  # the navigation map
        self.scans = 0
        # navigation state
        self.localizer: ScanToMap | None = None
        self.relocalizer: Relocalizer | None = None
        self.follower = PathFollower(self.config.follower)
        self.planning_ms: list[float] = []
        self.counters = dict.fromkeys(
            [
                "plans",
                "replans_blocked",
                "plans_failed",
                "fallback_plans",
                "fits",
                "fits_rejected",
                "relocalizations",
                "global_searches",
                "relocalizations_failed",
            ],
            0,
        )
        self._localized = False
        self._localize_started: float | None = None
        self._rejections = 0
        self._initial_pose: NDArray[np.float64] | None = None
        self._pose: NDArray[np.float64] | None = None
        self._nav_odometry: LidarOdometry | None = None
        self._map_from_odom: NDArray[np.float64] | None = None
        self._goal: NDArray[np.float64] | None = None
        self._last_plan_stamp = -np.inf
        self.obstacles = ObstacleMemory()  # returns the map lacks, map frame, until seen through
        self._latest_new_obstacles = np.zeros((0, 2))

    @staticmethod
    def warm_up() -> None:
        """Load the compiled planner, the distance transforms and kiss-icp before anything is timed.

        The kiss-icp built here has one thread, kiss-icp's default in ``OdometryConfig``: the first
        ``KissICP`` of a process fixes the thread count for the process."""
        free = np.ones((16, 16), bool)
        grid_search.theta_star(grid_search.inflate_free(free, 0.2, 0.1), (8, 8), (10, 10))
        grid_search.nearest_free(free, (3, 3), 2)
        angles = np.linspace(0, 2 * np.pi, 360, endpoint=False)
        ring = np.stack([4 * np.cos(angles), 3 * np.sin(angles), np.full(360, 1.0)], 1).astype(np.float32)
        odometry = LidarOdometry(OdometryConfig(source="lidar", max_num_threads=1))
        odometry.update(ring, np.zeros(3))
        points, ranges = keyframe_scan(ring)
        OccupancyGrid.from_keyframes(np.zeros((1, 3)), [(points, ranges)])

    # -- mapping ----------------------------------------------------------------------------------

    @classmethod
    def create(cls, config: MetricGridConfig, context: Any = None) -> MetricGrid:
        system = cls(config, context)
        system.odometry = LidarOdometry(system.config.odometry)
        system.pose_graph = PoseGraph(system.config.pose_graph)
        if system.config.online_grid:
            system.online_grid = OccupancyGrid(system.config.occupancy)
        return system

    def observe(self, obs: Observation) -> None:
        """One scan of the mapping run: odometry, keyframe and loop closures, the online grid."""
        assert self.odometry is not None and self.pose_graph is not None, "observe() needs create()"
        odom_pose = self.odometry.update(obs.points, obs.odom)
        self.scans += 1
        if not self.pose_graph.needs_keyframe(odom_pose):
            self.pose_graph.add_scan(odom_pose, None)
            return
        points, ranges = keyframe_scan(obs.points, self.band, voxel=self.config.pose_graph.voxel_size)
        self.pose_graph.add_scan(odom_pose, points, ranges)
        if self.online_grid is not None:
            self.online_grid.integrate(self.pose_graph.poses()[-1], points, ranges)

    def finish_mapping(self) -> None:
        """Optimise the pose graph and trace the global grid from every keyframe at its pose."""
        assert self.pose_graph is not None, "finish_mapping() needs a mapping run"
        poses = self.pose_graph.optimize()
        scans = [(kf.points, kf.free_ranges) for kf in self.pose_graph.keyframes]
        self.grid = OccupancyGrid.from_keyframes(poses, scans, self.config.occupancy)
        self.grid_map = self.grid.to_map()
        self.online_grid = None  # superseded by the optimised grid

    def save(self, directory: Path) -> None:
        """``map.png`` + ``map.yaml`` (map_server), ``pose_graph.{json,npz}``, ``metric_grid.json``."""
        if self.grid_map is None:
            self.finish_mapping()
        assert self.grid_map is not None and self.pose_graph is not None
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        self.grid_map.save(directory / MAP_YAML)
        self.pose_graph.save(directory)
        manifest = {
            "format": FORMAT,
            "map": MAP_YAML,
            "map_image": Path(MAP_YAML).with_suffix(".png").name,
            "pose_graph": ["pose_graph.json", "pose_graph.npz"],
            "resolution": self.grid_map.resolution,
            "origin": [float(v) for v in self.grid_map.origin],
            "shape": list(self.grid_map.cells.shape),
            "keyframes": len(self.pose_graph.keyframes),
            "loop_closures": len(self.pose_graph.loops),
            "scans": self.scans,
            "config": self.config.model_dump(mode="json"),
        }
        (directory / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")

    def mapping_stats(self) -> dict[str, Any]:
        """Navigation map bytes, and the mapping state split by part (all exact ``nbytes`` sums)."""
        graph = self.pose_graph
        grid = self.grid if self.grid is not None else self.online_grid
        if self.grid_map is not None:
            map_bytes = self.grid_map.nbytes
        else:
            map_bytes = grid.to_map().nbytes if grid is not None and grid.logodds.size else 0
        keyframe_bytes = sum(int(kf.points.nbytes + kf.free_ranges.nbytes) for kf in graph.keyframes) if graph else 0
        state = {
            "keyframe_scan_bytes": keyframe_bytes,
            "kiss_icp_map_bytes": self.odometry.nbytes if self.odometry is not None else 0,
            "pose_graph_bytes": (graph.nbytes - keyframe_bytes) if graph else 0,
            "log_odds_grid_bytes": grid.nbytes if grid is not None else 0,
        }
        stats: dict[str, Any] = {"map_bytes": int(map_bytes), **state, "mapping_state_bytes": int(sum(state.values()))}
        if graph is not None:
            stats.update(keyframes=len(graph.keyframes), loop_closures=len(graph.loops), loop_attempts=graph.loop_attempts)
        stats["odometry_source"] = self.config.odometry.source
        if self.grid_map is not None:
            stats["grid_shape"] = list(self.grid_map.cells.shape)
        return stats

    # -- loading ----------------------------------------------------------------------------------

    @classmethod
    def load(cls, directory: Path, config: MetricGridConfig, context: Any = None) -> MetricGrid:
        """The navigation map of a saved folder (the grid only: the pose graph stays on disk)."""
        directory = Path(directory)
        manifest_path = directory / MANIFEST
        try:
            manifest = json.loads(manifest_path.read_text())
        except FileNotFoundError:
            raise MapLoadError(f"{manifest_path}: missing (not a metric_grid map folder)") from None
        except (OSError, ValueError) as exc:
            raise MapLoadError(f"{manifest_path}: unreadable: {exc}") from None
        if not isinstance(manifest, dict) or manifest.get("format") != FORMAT:
            raise MapLoadError(f"{manifest_path}: format is not {FORMAT}")
        yaml_path = directory / str(manifest.get("map", MAP_YAML))
        try:
            meta = yaml.safe_load(yaml_path.read_text())
        except FileNotFoundError:
            raise MapLoadError(f"{yaml_path}: missing") from None
        except (OSError, ValueError, yaml.YAMLError) as exc:
            raise MapLoadError(f"{yaml_path}: unreadable: {str(exc).splitlines()[0]}") from None
        if not isinstance(meta, dict) or "image" not in meta:
            raise MapLoadError(f"{yaml_path}: not a map_server map (no 'image' key)")
        image_path = yaml_path.parent / str(meta["image"])
        if not image_path.is_file():
            raise MapLoadError(f"{image_path}: missing (named by {yaml_path.name})")
        try:
            grid_map = GridMap.load(yaml_path)
        except MapLoadError:
            raise
        except Exception as exc:  # a truncated or corrupt image, or bad YAML values
            raise MapLoadError(f"{image_path}: cannot read the map image: {type(exc).__name__}: {exc}") from None
        if grid_map.cells.size == 0 or not grid_map.resolution > 0:
            raise MapLoadError(f"{yaml_path}: empty map or non-positive resolution")
        system = cls(config, context)
        system._prepare_navigation(grid_map)
        return system

    def _prepare_navigation(self, grid_map: GridMap) -> None:
        """Planning grids (eroded once here) and the localizer's distance field."""
        self.grid_map = grid_map
        cfg = self.config.planning
        res = grid_map.resolution
        self._known_free = grid_map.cells == FREE
        self._not_occupied = grid_map.cells != OCCUPIED
        wide = self.robot_radius + res / 2 + cfg.inflation_margin
        tight = self.robot_radius + res / 2
        self._radii = (wide, tight)
        # (base free mask, radius) in the order they are tried; eroded masks cached per pair
        self._attempts: list[tuple[str, float]] = [("known", wide), ("known", tight)]
        if cfg.unknown_fallback:
            self._attempts += [("unknown", wide), ("unknown", tight)]
        self._eroded: dict[tuple[str, float], NDArray[np.bool_]] = {
            key: grid_search.inflate_free(self._base(key[0]), key[1], res) for key in self._attempts
        }
        # the distance field serves both the localizer and the new-obstacle test
        self.localizer = ScanToMap(grid_map, self.config.localization)
        self.relocalizer = Relocalizer(grid_map, self.localizer, self.robot_radius, self.config.relocalization)

    def _base(self, kind: str) -> NDArray[np.bool_]:
        return self._known_free if kind == "known" else self._not_occupied

    # -- navigation -------------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the previous trial: pose, odometry, goal, path, new obstacles, counters."""
        self._initial_pose = None
        self._pose = None
        self._map_from_odom = None
        self._nav_odometry = None
        self._localized = False
        self._localize_started: float | None = None
        self._rejections = 0
        self._goal = None
        self.status = NavStatus()
        self.planning_ms = []
        self.follower.clear()
        self._last_plan_stamp = -np.inf
        self.obstacles.clear()
        self._latest_new_obstacles = np.zeros((0, 2))
        self.counters = dict.fromkeys(self.counters, 0)

    def set_initial_pose(self, pose: ArrayLike) -> None:
        """The robot's pose (3,) in the map frame, as a Nav2 user sets it (by hand: it may be off by
        the protocol's error); odometry restarts here and the pose is searched for around it."""
        self._initial_pose = np.asarray(pose, dtype=np.float64).copy()
        self._pose = self._initial_pose.copy()
        self._map_from_odom = None
        self._nav_odometry = None
        self._localized = False
        self._localize_started = None

    def set_goal(self, goal: ArrayLike) -> None:
        """A new goal (2,) in the map frame; the path is planned at the next ``step``."""
        if self.grid_map is None:
            raise RuntimeError("set_goal() needs a loaded map (MetricGrid.load)")
        self._goal = np.asarray(goal, dtype=np.float64).reshape(-1)[:2].copy()
        self.status = NavStatus()
        self.planning_ms = []
        self.follower.clear()
        self._last_plan_stamp = -np.inf
        self.obstacles.clear()

    def step(self, obs: Observation) -> Command:
        if self._goal is None:
            raise RuntimeError("step() before set_goal()")
        if self.status.state != Status.ACTIVE:
            return Command()
        points = voxel_filter_2d(obstacle_points(obs.points, self.band), self.config.localization.voxel)
        pose = self._track(obs, points)
        if pose is None:  # no pose found on the map yet: turn in place to see more, for a while
            relocalization = self.config.relocalization
            if obs.stamp - (self._localize_started or 0.0) > relocalization.timeout:
                self.status = NavStatus(Status.FAILED, "not_localized")
                return Command()
            return Command(0.0, relocalization.turn_rate)
        self._remember_new_obstacles(pose, points)
        due = not self.follower.has_path or obs.stamp - self._last_plan_stamp >= self.config.planning.replan_period
        blocked = not due and self._path_blocked(pose)
        if due or blocked:
            self.counters["replans_blocked"] += int(blocked)
            self._last_plan_stamp = obs.stamp
            path = self._timed_plan(pose[:2], self._goal)
            if path is not None:
                self.follower.set_path(path)
            elif not self.follower.has_path:
                self.status = NavStatus(Status.FAILED, "no_path")
                return Command()
        command = self.follower.command(pose)
        if self.follower.reached:
            self.status = NavStatus(Status.REACHED)
            return Command()
        return command

    def _track(self, obs: Observation, points: NDArray) -> NDArray[np.float64] | None:
        """Map-frame pose: odometry composed onto the initial pose, corrected by the map fit; None
        while the pose has not been found on the map (``Relocalizer``)."""
        if self._initial_pose is None:
            if self._pose is None:
                raise RuntimeError("the metric baseline needs set_initial_pose() before the first step")
            self.set_initial_pose(self._pose)  # carry on from the last tracked pose
            self._localized = True
        if self._nav_odometry is None:
            self._nav_odometry = LidarOdometry(self.config.odometry)
        odom_pose = self._nav_odometry.update(obs.points, obs.odom)
        if self._map_from_odom is None:
            assert self._initial_pose is not None
            self._map_from_odom = se2.compose(self._initial_pose, se2.inverse(odom_pose))
        pose = se2.compose(self._map_from_odom, odom_pose)
        loc = self.config.localization
        near = points[np.hypot(points[:, 0], points[:, 1]) <= loc.max_range]
        if not self._localized:
            if self._localize_started is None:
                self._localize_started = obs.stamp
            found = self._relocalize(near, pose, everywhere=True)
            self._pose = pose
            if found is None:
                return None
            pose, self._localized = found, True
            self._map_from_odom = se2.compose(pose, se2.inverse(odom_pose))
        elif loc.enabled and self.localizer is not None and self._nav_odometry.scans % loc.every_scans == 0:
            fit = self.localizer.fit(near, pose)
            if fit is None:
                self.counters["fits_rejected"] += 1
                self._rejections += 1
                if self._rejections >= self.config.relocalization.lost_after:  # lost: search the window again
                    found = self._relocalize(near, pose, everywhere=False)
                    self._rejections = 0
                    if found is not None:
                        fit = (found, 1.0)
            if fit is not None:
                self.counters["fits"] += 1
                self._rejections = 0
                pose = fit[0]
                self._map_from_odom = se2.compose(pose, se2.inverse(odom_pose))
        self._pose = pose
        return pose

    def _relocalize(self, points: NDArray, guess: NDArray, everywhere: bool) -> NDArray[np.float64] | None:
        """The pose of the scan on the map: the window around ``guess``, then (if allowed) all of it."""
        config = self.config.relocalization
        if not config.enabled or self.relocalizer is None:
            return guess
        self.counters["relocalizations"] += 1
        found = self.relocalizer.around(points, guess)
        if found is None and everywhere and config.global_search:
            self.counters["global_searches"] += 1
            found = self.relocalizer.everywhere(points)
        if found is None:
            self.counters["relocalizations_failed"] += 1
            return None
        return found[0]

    def _remember_new_obstacles(self, pose: NDArray, points: NDArray) -> None:
        """Mark the returns that the map does not explain (far from every mapped wall); clear the
        marked ones this scan sees through (``navkit.obstacles.ObstacleMemory``)."""
        cfg = self.config.planning
        self._latest_new_obstacles = np.zeros((0, 2))
        if self.localizer is None:
            return
        near = points[np.hypot(points[:, 0], points[:, 1]) <= cfg.new_obstacle_range]
        if len(near):
            world = se2.transform_points(pose, near.astype(np.float64))
            self._latest_new_obstacles = world[self.localizer.sample(world)[0] > cfg.new_obstacle_distance]
        self.obstacles.update(pose, points, self._latest_new_obstacles, cfg.new_obstacle_range)

    def _recent_obstacles(self) -> NDArray[np.float64]:
        return self.obstacles.points

    def _path_blocked(self, pose: NDArray) -> bool:
        """Do newly seen obstacles of the latest scan come within the robot radius of the path ahead?"""
        cfg = self.config.planning
        clearance = self.robot_radius + cfg.block_clearance
        return self.follower.path_ahead_blocked(self._latest_new_obstacles, pose, clearance, cfg.block_check_distance)

    def _timed_plan(self, start_xy: NDArray, goal_xy: NDArray) -> NDArray[np.float64] | None:
        t0 = time.perf_counter()
        path = self.plan(start_xy, goal_xy)
        self.planning_ms.append((time.perf_counter() - t0) * 1e3)
        self.counters["plans"] += 1
        self.counters["plans_failed"] += int(path is None)
        return path

    def plan(self, start_xy: ArrayLike, goal_xy: ArrayLike) -> NDArray[np.float64] | None:
        """(K, 2) map-frame path from start to goal (both (2,)), or None.

        Theta* on the known free cells eroded by radius + margin; then the radius alone; then, if
        allowed, with unknown cells counted as free (``navkit.grid_planning.plan_path``). Newly
        seen obstacles are blocked in all.
        """
        assert self.grid_map is not None
        grid = self.grid_map
        snap = int(np.ceil(self.config.planning.snap_radius / grid.resolution))
        obstacles = self._recent_obstacles()
        blocked = None
        if len(obstacles):
            obstacle_cells = GridFrame(grid.origin, grid.resolution).to_cell(obstacles)
            rows, cols = obstacle_cells[:, 0], obstacle_cells[:, 1]
            height, width = grid.cells.shape
            inside = (rows >= 0) & (rows < height) & (cols >= 0) & (cols < width)
            blocked = np.zeros(grid.cells.shape, bool)
            blocked[rows[inside], cols[inside]] = True

        def mask(level: int) -> NDArray[np.bool_]:
            kind, radius = self._attempts[level]
            if blocked is None:
                return self._eroded[(kind, radius)]
            return grid_search.inflate_free(self._base(kind) & ~blocked, radius, grid.resolution)

        frame = GridFrame(grid.origin, grid.resolution)
        planned = plan_path(mask, frame, start_xy, goal_xy, snap, levels=len(self._attempts))
        if planned is None:
            return None
        self.counters["fallback_plans"] += int(planned.level > 0)
        return planned.points

    def stats(self) -> dict[str, Any]:
        return {
            "planning_ms": list(self.planning_ms),
            "map_bytes": int(self.grid_map.nbytes) if self.grid_map is not None else 0,
            "counters": dict(self.counters),
        }

    def memory(self) -> MemoryBreakdown:
        """map: the trinary grid; localization: the signed distance field and the relocalizer's
        score field; derived: the eroded planning masks. While mapping (no grid yet), the online
        grid's trinary map; the mapping state is in ``mapping_stats``."""
        if self.grid_map is None:
            return MemoryBreakdown(map=int(self.mapping_stats()["map_bytes"]))
        localization = (self.localizer.nbytes if self.localizer is not None else 0) + (
            self.relocalizer.nbytes if self.relocalizer is not None else 0
        )
        derived = sum(int(mask.nbytes) for mask in getattr(self, "_eroded", {}).values()) + self.obstacles.nbytes
        return MemoryBreakdown(map=int(self.grid_map.nbytes), localization=localization, derived=derived)

    @staticmethod
    def disk_usage(directory: Path) -> dict[str, int]:
        """The saved map's bytes per memory part: the map_server map and the manifest are the map;
        the pose graph (keyframe scans, for re-optimising later) is mapping state, of no part."""
        directory = Path(directory)
        files = [directory / MAP_YAML, directory / MANIFEST]
        try:
            image = yaml.safe_load((directory / MAP_YAML).read_text()).get("image")
            files.append(directory / str(image))
        except (OSError, AttributeError, yaml.YAMLError):
            pass
        return {"map": sum(f.stat().st_size for f in files if f.is_file())}

    def pose_estimate(self) -> NDArray[np.float64] | None:
        return None if self._pose is None else self._pose.copy()
