"""MetricGrid: the NavigationSystem of the metric SLAM baseline (DESIGN.md, issue 5).

The pipeline the paper compares NavTopo with (RTAB-MAP + Theta*), from well-kept parts. Like
NavTopo's system module it composes the parts and owns no algorithm itself:

mapping      odometry (``navkit.odometry.LidarOdometry``: wheel, or kiss-icp seeded by the wheels) ->
             keyframes and verified loop closures (``pose_graph.PoseGraph``, gtsam) -> at the end,
             batch optimisation and the global 0.1 m log-odds grid traced from every keyframe at
             its optimised pose (``occupancy.OccupancyGrid``); saved as a ROS map_server map
             (``map.png`` + ``map.yaml``) beside the pose graph and ``metric_grid.json``
             (``map_folder``).
navigation   as a Nav2 user runs it: the map is loaded and an initial pose given in the map
             frame, set by hand (off by up to the protocol's ±0.5 m, ±10°); the pose tracker
             (``tracking.PoseTracker``) finds the pose on the map by a correlative search around
             it, or over the whole map when nothing there fits (``localization.Relocalizer``), the
             robot turning in place until it does; then odometry composed onto it (the
             ``map -> odom`` transform) is corrected by scan-to-map registration at every scan
             (``localization.ScanToMap``). The global planner (``planning.GridPlanner``) runs
             Theta* on the map's free cells eroded by the robot radius plus a margin, unknown
             cells blocked; replanning at a fixed rate and when newly seen obstacles block the
             path (``obstacles.UnmappedObstacles``: they stay blocked until the lidar sees through
             them); the shared ``PathFollower`` drives and stops at the protocol's stop tolerance.

Each tick of ``step``: the scan's obstacle points (the shared band, voxel-filtered), the pose,
the new obstacles, the replanning decision (due, or the path ahead blocked), the follower.

Where it fails (``status.stage``, docs/DESIGN.md "Trial end"): ``startup`` until the pose is found
on the map (``not_localized`` after the relocalization timeout), ``localization`` while the tracker
is lost, ``global_plan`` when no level of the planner has a path (``no_path``; the detail names the
ends, the levels and which end had no passable cell), ``follower`` when it makes no progress
(``stuck``). As a Nav2 configuration recovers (its behaviour tree after a failed plan, or its progress
checker: 0.5 m in 10 s), a goal gets ``planning.recoveries`` recoveries: the remembered obstacles are
forgotten (the costmap cleared) and the path planned again; a ``no_path`` with obstacles remembered,
or no progress, fails only once they are spent. The status's detail says what it is doing.

Memory (``memory()``, the runner's breakdown): ``map`` is the trinary grid as loaded,
``localization`` the distance field of the scan-to-map fit and the relocalizer's score field,
``derived`` the eroded planning masks and the remembered obstacles; the mapping state (keyframe
scans, kiss-icp local map, pose graph, log-odds grid) comes as separate keys of ``mapping_stats()``.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from navkit import grid_search
from navkit.explore import Explorer
from navkit.follower import PathFollower, ProgressCheck
from navkit.geometry import transform_points
from navkit.obstacles import scan_guard
from navkit.odometer import Odometer
from navkit.odometry import LidarOdometry, OdometryConfig
from navkit.passages import PassageCheck, returns_near
from navkit.raster import FREE, OCCUPIED
from navkit.scan import obstacle_points
from navkit.scan_grid import GridConfig
from navkit.types import Command, FailureStage, MemoryBreakdown, NavStatus, Observation, Status

from . import map_folder
from .config import NOISY_ODOMETRY, PRECISE_ODOMETRY, SETTING_OVERRIDES, MetricGridConfig, PlanningConfig, for_context
from .map_folder import MetricMapError, load_grid_map, save_map_folder
from .obstacles import UnmappedObstacles
from .occupancy import GridMap, OccupancyGrid
from .planning import SEARCHES, GridPlanner
from .pose_graph import PoseGraph
from .scan2d import keyframe_scan, voxel_filter_2d
from .tracking import PoseTracker

__all__ = [
    "NOISY_ODOMETRY",
    "PRECISE_ODOMETRY",
    "SETTING_OVERRIDES",
    "MetricGrid",
    "MetricGridConfig",
    "MetricMapError",
]

#: the planner's counters, reported before the tracker's (``tracking.COUNTERS``)
PLAN_COUNTERS = (
    "plans",
    "replans_blocked",
    "plans_failed",
    "fallback_plans",
    "recoveries",
    "passages_centred",
    "passages_blocked",
    "scan_guard_stops",
)


class MetricGrid:
    """kiss-icp + gtsam pose graph + global 0.1 m occupancy grid + Theta* (the metric baseline)."""

    def __init__(self, config: MetricGridConfig, context: Any = None) -> None:
        self.config = for_context(config, context)
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
        self.raw_cloud_bytes = 0  # the keyframes' lidar clouds as received (float32 x, y, z): not kept
        # navigation parts (the planner once a map is loaded)
        cfg = self.config
        self.tracker = PoseTracker(cfg.odometry, cfg.localization, cfg.relocalization, self.robot_radius)
        self.planner: GridPlanner | None = None
        self.obstacles = UnmappedObstacles(cfg.planning)
        self.follower = PathFollower(cfg.follower)
        # a kidnapped start's moves toward open space (NavTopo's start-up's): in the scan's own grid,
        # at the planner's two radii (with the margin and half a cell, then alone and half a cell)
        scan_grid = GridConfig(floor_height=self.band.floor_height, ceiling_height=self.band.ceiling_height)
        tight = self.robot_radius + scan_grid.resolution / 2
        self.explorer = Explorer(
            self.follower,
            scan_grid,
            cfg.relocalization.explore_distance,
            self.robot_radius,
            (tight + cfg.planning.inflation_margin, tight),
            cfg.planning.block_check_distance,
        )
        self._odometer = Odometer()  # of this trial (a kidnapped start's exploring moves run on it)
        self._turned = 0.0  # rad turned this trial while no pose was found
        self.explore_counters = {"explore_moves": 0, "explore_blocked": 0}
        self.passages = PassageCheck(cfg.planning.passages, self.robot_radius)
        self.progress = ProgressCheck(cfg.planning.progress_distance, cfg.planning.progress_time)
        self._recoveries = 0  # this goal's
        self.planning_ms: list[float] = []
        self.plan_counters = dict.fromkeys(PLAN_COUNTERS, 0)
        self._goal: NDArray[np.float64] | None = None
        self._last_plan_stamp = -np.inf

    @property
    def counters(self) -> dict[str, int]:
        """The planner's counters, then the tracker's (a copy)."""
        return {**self.plan_counters, **self.tracker.counters, **self.explore_counters}

    @staticmethod
    def warm_up() -> None:
        """Load the compiled planner, the distance transforms and kiss-icp before anything is timed.

        The kiss-icp built here has one thread, kiss-icp's default in ``OdometryConfig``: the first
        ``KissICP`` of a process fixes the thread count for the process."""
        free = np.ones((16, 16), bool)
        grid_search.theta_star(grid_search.inflate_free(free, 0.2, 0.1), (8, 8), (10, 10))
        grid_search.nearest_free(free, (3, 3), 2)
        # every kernel a plan compiles (search, goal field, descent, easing, thinning, masks round new
        # obstacles): a room with a pillar, planned to one goal three times, then with an obstacle
        cells = np.full((40, 40), FREE, np.uint8)
        cells[[0, -1], :] = cells[:, [0, -1]] = OCCUPIED
        cells[18:22, 18:22] = OCCUPIED
        planner = GridPlanner(GridMap(cells, np.zeros(2), 0.1), 0.3, PlanningConfig())
        start, goal = np.array([0.7, 0.7]), np.array([3.3, 3.3])
        for obstacles in (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2)), np.array([[2.0, 1.0]])):
            planner.plan(start, goal, obstacles)
        for search in SEARCHES.values():  # whichever ``planning.search`` a run's config names
            search(planner.mask(planner.attempts[0]), (7, 7), (33, 33))
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
        self.raw_cloud_bytes += int(obs.points.shape[0]) * 3 * 4
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
        config = self.config.model_dump(mode="json")
        save_map_folder(Path(directory), self.grid_map, self.pose_graph, self.scans, config)

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
        # what an RTAB-MAP-style system would keep of the same run, for relating this suite's figures
        # to the paper's 352 MB (not the baseline's memory, which keeps none of the raw clouds): every
        # keyframe's raw lidar cloud (float32 x, y, z) besides its 2D scan, the pose graph and the grid
        if self.raw_cloud_bytes:
            stats["raw_cloud_bytes"] = self.raw_cloud_bytes
            stats["rtabmap_style_bytes"] = self.raw_cloud_bytes + keyframe_bytes + state["pose_graph_bytes"] + int(map_bytes)
        if graph is not None:
            stats.update(keyframes=len(graph.keyframes), loop_closures=len(graph.loops), loop_attempts=graph.loop_attempts)
        stats["odometry_source"] = self.config.odometry.source
        if self.grid_map is not None:
            stats["grid_shape"] = list(self.grid_map.cells.shape)
        return stats

    # -- loading ----------------------------------------------------------------------------------

    @classmethod
    def load(cls, directory: Path, config: MetricGridConfig, context: Any = None) -> MetricGrid:
        """The navigation map of a saved folder (the grid only: the pose graph stays on disk);
        ``MetricMapError`` names the file of a folder that cannot be used."""
        grid_map = load_grid_map(Path(directory))
        system = cls(config, context)
        system._prepare_navigation(grid_map)
        return system

    def _prepare_navigation(self, grid_map: GridMap) -> None:
        """The planner's masks (eroded once here) and the tracker's distance and score fields."""
        self.grid_map = grid_map
        self.planner = GridPlanner(grid_map, self.robot_radius, self.config.planning)
        self.tracker.use_map(grid_map)

    # -- navigation -------------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the previous trial: pose, odometry, goal, path, new obstacles, counters."""
        self.tracker.reset()
        self._goal = None
        self._start_over()
        self.obstacles.reset()  # the latest scan's new obstacles too
        self.plan_counters = dict.fromkeys(self.plan_counters, 0)
        self.explorer.reset()
        self.explore_counters = dict.fromkeys(self.explore_counters, 0)
        self._odometer, self._turned = Odometer(), 0.0
        if self.planner is not None:
            self.planner.forget()  # cold: the first plan makes its line-of-sight rasters again

    def set_initial_pose(self, pose: ArrayLike) -> None:
        """The robot's pose (3,) in the map frame, as a Nav2 user sets it (by hand: it may be off by
        the protocol's error); odometry restarts here and the pose is searched for around it."""
        self.tracker.set_initial_pose(pose)

    def set_goal(self, goal: ArrayLike) -> None:
        """A new goal (2,) in the map frame; the path is planned at the next ``step``."""
        if self.grid_map is None:
            raise RuntimeError("set_goal() needs a loaded map (MetricGrid.load)")
        self._goal = np.asarray(goal, dtype=np.float64).reshape(-1)[:2].copy()
        self._start_over()

    def _start_over(self) -> None:
        """What a new goal starts without: a status, plans and their times, a path, remembered obstacles."""
        self.status = NavStatus()
        self.planning_ms = []
        self.follower.clear()
        self.passages.clear()
        self._last_plan_stamp = -np.inf
        self.obstacles.clear()
        self.progress.reset()
        self._recoveries = 0

    def step(self, obs: Observation) -> Command:
        if self._goal is None:
            raise RuntimeError("step() before set_goal()")
        if self.status.state != Status.ACTIVE:
            return Command()
        band = obstacle_points(obs.points, self.band)
        points = voxel_filter_2d(band, self.config.localization.voxel)
        turn = abs(float(self._odometer.update(obs.odom)[2]))
        if not self.tracker.localized:
            self._turned += turn
        pose = self.tracker.track(obs, points)
        if pose is None:  # no pose found on the map yet
            return self._searching(obs)
        if self.explorer.move is not None:  # the pose is found: the exploring move ends here
            self.explorer.stop()
            self.follower.clear()
        self._keep_stage()
        self.obstacles.update(pose, points, self.tracker.localizer, rays=band)
        if self.progress.stalled(obs.stamp, obs.odom) and not self._recover():
            detail = (
                f"no {self.config.planning.progress_distance:g} m of progress in {self.config.planning.progress_time:g} s "
                f"after {self._recoveries} recoveries, at ({pose[0]:.2f}, {pose[1]:.2f}) in the map frame"
            )
            self.status = NavStatus(Status.FAILED, "stuck", FailureStage.FOLLOWER, detail)
            return Command()
        due = not self.follower.has_path or obs.stamp - self._last_plan_stamp >= self.config.planning.replan_period
        blocked = not due and self._path_blocked(pose)
        if due or blocked:
            self.plan_counters["replans_blocked"] += int(blocked)
            self._last_plan_stamp = obs.stamp
            path = self._timed_plan(pose[:2], self._goal)
            if path is not None:
                assert self.planner is not None
                self.passages.follow(self.follower, path, self.planner.roomy_at)
                self._describe(self._following(pose, path))
            elif not self.follower.has_path:
                if len(self.obstacles.points) and self._recover():
                    return Command()  # plan again at the next tick, the remembered obstacles forgotten
                assert self.planner is not None
                detail = self.planner.why_no_path(pose[:2], self._goal, self.obstacles.points)
                self.status = NavStatus(Status.FAILED, "no_path", FailureStage.GLOBAL_PLAN, detail)
                return Command()
        if not self._check_passage(obs, pose):
            return Command()  # the passage is shut to the robot: plan again at the next tick
        if self.config.planning.scan_guard and scan_guard(self.follower, self.obstacles.memory, pose, band, self.robot_radius):
            # the scan shows the way ahead too near a return (``navkit.obstacles.scan_guard``)
            self.plan_counters["scan_guard_stops"] += 1
            self.follower.clear()
            self._last_plan_stamp = -np.inf
            return Command()
        command = self.follower.command(pose)
        if self.follower.reached:
            off = float(np.hypot(*(pose[:2] - self._goal)))
            detail = f"its pose estimate ({pose[0]:.2f}, {pose[1]:.2f}) {off:.2f} m from the goal, map frame"
            self.status = NavStatus(Status.REACHED, detail=detail)
            return Command()
        return command

    def _searching(self, obs: Observation) -> Command:
        """No pose found on the map yet: turn in place to see more, for a while; a kidnapped start,
        past its first full turn, moves (``_explore``) or turns to confirm its candidate."""
        limit = self.config.relocalization
        if self.tracker.search_timed_out(obs.stamp):
            if self.tracker.kidnapped:
                detail = f"no pose confirmed on the map in {limit.kidnapped_timeout:g} s: {self._weighed()}"
            else:
                detail = f"no fit on the map {self._searched()} in {limit.timeout:g} s"
            self.status = NavStatus(Status.FAILED, "not_localized", FailureStage.STARTUP, detail)
            return Command()
        self._keep_stage()
        if self.tracker.kidnapped and self._turned >= np.radians(limit.explore_after_deg) and not self.tracker.wants_turning:
            return self._explore(obs)
        return Command(0.0, limit.turn_rate)  # (a candidate found and agreed over the motion: a turn confirms it)

    def _explore(self, obs: Observation) -> Command:
        """A kidnapped start not confirmed by turning in place: moves toward open space for new views
        (``navkit.explore``, as NavTopo's start-up), each ``explore_distance`` long. (Moving toward the
        goal by the unconfirmed candidate instead was tried: on the symmetric loop_office_door the
        views along the way to the goal kept dropping the right candidate as ambiguous, 4 of 8 trials
        not localized; BENCHMARKS.md, "Design choices: the kidnapped baseline explores toward open
        space".)"""
        explorer = self.explorer
        explorer.record(obs.odom)
        if not explorer.under_way(self._odometer.metres):
            explorer.begin(obs.stamp, self._odometer.metres)
        return explorer.step(obs, self.explore_counters)

    def _check_passage(self, obs: Observation, pose: NDArray) -> bool:
        """The narrow passage of the path against the scan's returns (``navkit.passages``): moved to
        their middle, or shut (its returns become remembered obstacles, the path is dropped; False:
        plan again). True: follow on."""

        def near(segment: NDArray, reach: float) -> NDArray[np.float64]:
            points = np.asarray(obstacle_points(obs.points, self.band)[:, :2], dtype=np.float64)
            return returns_near(transform_points(pose, points), segment, reach)

        verdict = self.passages.step(self.follower, obs.stamp, pose, near)
        if verdict.shut is not None:
            self.obstacles.memory.mark(verdict.shut)
            self.plan_counters["passages_blocked"] += 1
            self.follower.clear()
            self._last_plan_stamp = -np.inf
            return False
        self.plan_counters["passages_centred"] += int(verdict.path is not None)
        return True

    def _recover(self) -> bool:
        """One recovery, if this goal has one left (Nav2's behaviour tree after a failed plan or the
        progress checker): forget the remembered obstacles (clear the costmap), drop the path, plan
        again at the next tick. False when none is left."""
        if self._recoveries >= self.config.planning.recoveries:
            return False
        self._recoveries += 1
        self.plan_counters["recoveries"] += 1
        self.obstacles.clear()
        self.follower.clear()
        self._last_plan_stamp = -np.inf
        return True

    # -- what the status says (docs/DESIGN.md, "Trial end") ----------------------------------------------

    def _stage(self) -> FailureStage | None:
        """The stage it is in while active: startup until its pose is found, localization while lost."""
        if not self.tracker.localized:
            return FailureStage.STARTUP
        return FailureStage.LOCALIZATION if self.tracker.lost else None

    def _describe(self, doing: str) -> None:
        """The active status: the stage it is in, and what it is doing (lost: since when)."""
        stage = self._stage()
        if stage == FailureStage.LOCALIZATION:
            doing = f"lost ({self.tracker.rejected_in_row} fits rejected in a row, the window search found nothing); {doing}"
        self.status = NavStatus(stage=stage, detail=doing)

    def _keep_stage(self) -> None:
        """Rewrite the active status when the stage it is in changes (not at every tick)."""
        stage = self._stage()
        if stage == self.status.stage and self.status.detail is not None:
            return
        if stage == FailureStage.STARTUP:
            given = self.tracker.initial_pose
            around = "" if given is None else f" around ({given[0]:.2f}, {given[1]:.2f}, {np.degrees(given[2]):.0f} deg)"
            self._describe(f"searching for its pose on the map{around}, turning in place")
        else:
            self._describe("tracking its pose on the map")

    def _searched(self) -> str:
        """Where the pose has been searched for, and how often."""
        given = self.tracker.initial_pose
        around = "" if given is None else f"around ({given[0]:.2f}, {given[1]:.2f}, {np.degrees(given[2]):.0f} deg) "
        counters = self.tracker.counters
        return f"{around}({counters['relocalizations']} searches, {counters['global_searches']} over the whole map)"

    def _weighed(self) -> str:
        """A kidnapped start's hypotheses as they stand (why none was taken)."""
        tracker = self.tracker
        looks = tracker.counters["global_searches"]
        places = len(tracker.hypotheses)
        if places == 0:
            return f"no place fits the scan after {looks} looks over the whole map"
        if places == 1:
            return f"one place fits after {looks} looks over the whole map, not yet confirmed over the motion"
        return f"{places} places fit about as well after {looks} looks over the whole map (none told apart)"

    def _following(self, pose: NDArray, path: NDArray[np.float64]) -> str:
        assert self._goal is not None
        length = float(np.hypot(*np.diff(path, axis=0).T).sum()) if len(path) > 1 else 0.0
        return (
            f"following a {length:.1f} m path from ({pose[0]:.2f}, {pose[1]:.2f}) to the goal "
            f"({self._goal[0]:.2f}, {self._goal[1]:.2f}), map frame, after {self.plan_counters['plans']} plans"
        )

    def _path_blocked(self, pose: NDArray) -> bool:
        """Do newly seen obstacles of the latest scan come within the robot radius of the path ahead?"""
        cfg = self.config.planning
        clearance = self.robot_radius + cfg.block_clearance
        return self.follower.path_ahead_blocked(self.obstacles.latest, pose, clearance, cfg.block_check_distance)

    def _timed_plan(self, start_xy: NDArray, goal_xy: NDArray) -> NDArray[np.float64] | None:
        t0 = time.perf_counter()
        path = self.plan(start_xy, goal_xy)
        self.planning_ms.append((time.perf_counter() - t0) * 1e3)
        self.plan_counters["plans"] += 1
        self.plan_counters["plans_failed"] += int(path is None)
        return path

    def plan(self, start_xy: ArrayLike, goal_xy: ArrayLike) -> NDArray[np.float64] | None:
        """(K, 2) map-frame path from start to goal (both (2,)), or None (``planning.GridPlanner``:
        the eroded known free cells, then the fallbacks; remembered new obstacles blocked in all)."""
        assert self.planner is not None, "plan() needs a loaded map"
        planned = self.planner.plan(start_xy, goal_xy, self.obstacles.points)
        if planned is None:
            return None
        self.plan_counters["fallback_plans"] += int(planned.level > 0)
        return planned.points

    def stats(self) -> dict[str, Any]:
        tracker = self.tracker
        localizations = []
        if tracker.localized_at is not None and tracker.localized_pose is not None:
            # the pose found on the map at the start (the runner checks it against the truth)
            started = tracker.localize_started if tracker.localize_started is not None else tracker.localized_at
            localizations.append(
                {
                    "started": started,
                    "stamp": tracker.localized_at,
                    "seconds": round(tracker.localized_at - started, 3),
                    "map_pose": [float(v) for v in tracker.localized_pose],
                    "given_pose": not tracker.kidnapped,
                }
            )
        return {
            "planning_ms": list(self.planning_ms),
            "map_bytes": int(self.grid_map.nbytes) if self.grid_map is not None else 0,
            "counters": self.counters,
            "localizations": localizations,
        }

    def memory(self) -> MemoryBreakdown:
        """map: the trinary grid; localization: the signed distance field (int16), the relocalizer's
        likelihood table and where the robot fits (bits); derived: the planning masks (bits), the
        clearance raster, the line-of-sight rasters of the levels searched and the remembered
        obstacles. While mapping
        (no grid yet), the online grid's trinary map; the mapping state is in ``mapping_stats``."""
        if self.grid_map is None:
            return MemoryBreakdown(map=int(self.mapping_stats()["map_bytes"]))
        derived = (self.planner.nbytes if self.planner is not None else 0) + self.obstacles.nbytes
        return MemoryBreakdown(map=int(self.grid_map.nbytes), localization=self.tracker.nbytes, derived=derived)

    @staticmethod
    def disk_usage(directory: Path) -> dict[str, int]:
        """The saved map's bytes per memory part (``map_folder.disk_usage``)."""
        return map_folder.disk_usage(Path(directory))

    def pose_estimate(self) -> NDArray[np.float64] | None:
        return None if self.tracker.pose is None else self.tracker.pose.copy()
