"""NavTopo's navigation on a saved graph: the goal server and stepping (Muravyev & Yakovlev, Secs.
"Path Planning" and "Path Following").

Stepping. Until the start-up localization (``navtopo.startup``) commits to where the robot is, each
tick feeds it the observation and drives toward the goal as its best hypothesis sees it (a
*tentative* drive: a failed plan removes no edge and ends nothing, and what the scan shows on the
way is an obstacle), or, with no hypothesis or none that gets anywhere, lets its ``Explorer`` move
toward open space. From the commitment on, the graph maintainer (``navtopo.mapping``) tracks the
robot and the robot drives toward the goal over the graph.

The goal server receives a goal as ``(v_goal, T_goal)`` — or as a point in the map frame, turned
into that form with the vertices' odometry hints (the vertex whose known free area holds the goal,
nearest by hint) — and the state ``(v_cur, T_cur)`` from the graph maintainer; the goal is reached
when ``v_cur == v_goal`` and ``|T_cur - T_goal| < ε`` (the protocol's stop tolerance). Otherwise
the local planner is given the next target on the global path (``navtopo.planning``).

Failure handling: a local plan that finds no way to the next vertex (a closed door, an obstacle
the map lacks) removes that edge for the rest of the trial and plans again over the graph; no path
over the graph fails with ``no_path``; no progress for ``stuck_time`` seconds removes the edge
being followed, and a second time fails with ``stuck``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from navkit.follower import PathFollower
from navkit.geometry import between, inverse, transform_points
from navkit.obstacles import ObstacleMemory
from navkit.raster import FREE
from navkit.scan import obstacle_points
from navkit.types import Command, NavStatus, Observation, Status
from navtopo.graph import TopologicalGraph
from navtopo.graph_poses import relaxed_poses
from navtopo.local_grid import GridConfig, grid_frame, grid_from_points
from navtopo.mapping import GraphMaintainer
from navtopo.planning import GlobalPlanner, LocalPlanner, UnionGrids, path_positions
from navtopo.scan_matching import prepare
from navtopo.startup import Explorer, Hypothesis, Localization, Startup


class NavigationConfig(BaseModel):
    """Failure handling while navigating."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    stuck_time: float = Field(15.0, gt=0, description="s without 0.1 m of progress: remove the edge, replan; twice: fail")
    block_check_distance: float = Field(4.0, gt=0, description="m of the path ahead checked against new obstacles")
    block_clearance: float = Field(0.05, ge=0, description="m beyond the robot radius; nearer new obstacles block the path")
    replan_before_end: float = Field(1.5, gt=0, description="m: replan when the local path ends this close ahead")


def goal_in_graph(
    graph: TopologicalGraph, goal_xy: NDArray, grid_config: GridConfig, poses: NDArray | None = None
) -> tuple[int, NDArray[np.float64]]:
    """A map-frame goal (2,) as ``(v_goal, T_goal)``: among the vertices whose known free area holds
    the goal, the nearest; if none holds it, the nearest. ``poses`` (V, 3): the vertices' poses in
    the map frame (``navtopo.graph_poses.relaxed_poses``; default: their odometry hints)."""
    goal_xy = np.asarray(goal_xy, dtype=np.float64)[:2]
    if poses is None:
        poses = np.array([vertex.pose_hint for vertex in graph.vertices])
    frame = grid_frame(grid_config)
    best, best_free = None, None
    for v, vertex in enumerate(graph.vertices):
        local = transform_points(inverse(poses[v]), goal_xy[None])[0]
        distance = float(np.hypot(local[0], local[1]))
        row, col = frame.to_cell(local[None])[0] - (vertex.grid.row0, vertex.grid.col0)
        cells = vertex.grid.cells
        free = 0 <= row < cells.shape[0] and 0 <= col < cells.shape[1] and cells[row, col] == FREE
        if best is None or distance < best[0]:
            best = (distance, v, local)
        if free and (best_free is None or distance < best_free[0]):
            best_free = (distance, v, local)
    chosen = best_free if best_free is not None else best
    assert chosen is not None, "an empty graph has no goal vertex"
    return chosen[1], chosen[2]


@dataclass
class Goal:
    vertex: int
    pose: NDArray[np.float64]  # (2,) the goal in v_goal's frame


@dataclass
class Navigator:
    """The goal server and the stepping of one trial (see the module docstring)."""

    graph: TopologicalGraph
    maintainer: GraphMaintainer
    startup: Startup
    explorer: Explorer  # the start-up's moves toward open space
    global_planner: GlobalPlanner
    local: LocalPlanner
    unions: UnionGrids
    follower: PathFollower
    config: NavigationConfig
    robot_radius: float
    status: NavStatus = field(default_factory=NavStatus)
    map_poses: NDArray[np.float64] | None = None  # (V, 3) vertices in the map frame, for map-frame goals
    goal: Goal | None = None
    localized: bool = False
    planning_ms: list[float] = field(default_factory=list)
    first_plan_ms: float | None = None
    localizations: list[Localization] = field(default_factory=list)
    counters: dict[str, int] = field(default_factory=dict)
    _route: list[int] | None = None
    _path_vertex: int | None = None
    _plan_stamp: float = -np.inf
    _target_is_goal: bool = False
    _goal_short: bool = False  # the local path to the goal ends short of it: the robot does not fit there
    obstacles: ObstacleMemory = field(default_factory=ObstacleMemory)  # returns the map lacks, until seen through
    _obstacle_vertex: int | None = None  # the frame of the remembered obstacles
    _progress: tuple[float, NDArray[np.float64]] | None = None
    _stuck_once: bool = False
    _tentative: Hypothesis | None = None  # the start-up hypothesis the robot drives by

    def reset(self) -> None:
        self.status = NavStatus()
        self.goal = None
        self.localized = False
        self.planning_ms = []
        self.first_plan_ms = None
        self.localizations = []
        self.counters = dict.fromkeys(
            [
                "plans",
                "plans_failed",
                "edges_removed",
                "global_replans",
                "reached_by_composition",
                "reached_short",
                "explore_moves",
                "explore_blocked",
                "tentative_blocked",
            ],
            0,
        )
        self.maintainer.forget()
        self.unions.take_build_ms()  # the last trial's
        self.startup.reset()
        self.global_planner.reset()
        self.follower.clear()
        self._route = None
        self._path_vertex = None
        self._plan_stamp = -np.inf
        self._target_is_goal = self._goal_short = False
        self.obstacles.clear()
        self._obstacle_vertex = None
        self._progress = None
        self._stuck_once = False
        self.explorer.reset()
        self._tentative = None

    # -- the goal server ----------------------------------------------------------------------------

    def set_goal(self, goal_xy: NDArray) -> None:
        """A map-frame goal, turned into the paper's form with the vertices' map-frame poses (their
        odometry hints, relaxed against the scan-matched edges: ``navtopo.graph_poses``)."""
        if self.map_poses is None or len(self.map_poses) != len(self.graph):
            self.map_poses = relaxed_poses(self.graph)
        self.startup.map_poses = self.map_poses
        vertex, pose = goal_in_graph(self.graph, goal_xy, self.maintainer.grid_config, self.map_poses)
        self.set_goal_in_graph(vertex, pose)

    def set_goal_in_graph(self, vertex: int, pose: NDArray) -> None:
        """The paper's goal form: ``(v_goal, T_goal)``, T_goal the goal's position in v_goal's frame."""
        self.goal = Goal(int(vertex), np.asarray(pose, dtype=np.float64)[:2].copy())
        self.status = NavStatus()

    # -- stepping -------------------------------------------------------------------------------------

    def step(self, obs: Observation) -> Command:
        if self.goal is None:
            raise RuntimeError("step() before set_goal()")
        if self.status.state != Status.ACTIVE:
            return Command()
        if not self.localized:
            return self._step_unlocalized(obs)
        before = self.maintainer.current
        event = self.maintainer.update(obs.points, obs.odom, obs.stamp, route=self._route, force=self._at_path_end())
        if self.maintainer.current != before or event == "localized":
            self._path_vertex = None  # a new frame: plan again
        current = self.maintainer.current
        assert current is not None, "a localized robot is in a location"
        return self._drive(obs, current, self.maintainer.pose_in_current)

    def _step_unlocalized(self, obs: Observation) -> Command:
        startup, explorer = self.startup, self.explorer
        explorer.record(obs.odom)
        driven = self._tentative if self._tentative in startup.hypotheses else None
        committed = startup.step(obs, driven, self._route if driven is not None else None, force=self._at_path_end())
        if committed is not None:
            return self._commit(obs, committed)
        if startup.timed_out(obs.stamp):
            self.status = NavStatus(Status.FAILED, "not_localized")
            return Command()
        best = startup.best()
        odometer = startup.odometer
        if explorer.under_way(odometer):
            return explorer.step(obs, self.counters)  # an exploring move runs to its end
        if best is not None and not explorer.no_progress(obs.stamp, odometer):
            # drive as the best hypothesis sees it: confirmation on the way
            if best is not self._tentative or explorer.move is not None:
                self._tentative, self._path_vertex, self._route = best, None, None
                explorer.stop()
            return self._drive(obs, best.vertex, best.pose, tentative=True)
        # no hypothesis, or driving by the best one gets nowhere (it may be the wrong one, or two
        # places look alike from here): move toward open space for a new view (no move is under
        # way here: a new one begins)
        self._tentative = None
        explorer.begin(obs.stamp, odometer)
        return explorer.step(obs, self.counters)

    def _commit(self, obs: Observation, committed: Hypothesis) -> Command:
        """The start-up committed: track the robot from the hypothesis on, record it, drive."""
        startup = self.startup
        self.localized = True
        self.maintainer.start_at(committed.vertex, committed.pose, obs.odom)
        self.localizations.append(
            Localization(
                started=float(obs.stamp if startup.started is None else startup.started),
                stamp=obs.stamp,
                vertex_stamp=self.graph.vertices[committed.vertex].stamp,
                pose=committed.pose.copy(),
                looks=startup.looks,
                hypotheses=startup.seen,
            )
        )
        self._path_vertex = None
        return self._drive(obs, committed.vertex, committed.pose)

    # -- planning and following ----------------------------------------------------------------------------

    def _drive(self, obs: Observation, vertex: int, pose: NDArray, tentative: bool = False) -> Command:
        assert self.goal is not None
        goal_here = self._goal_in(vertex)
        if goal_here is not None and np.hypot(*(pose[:2] - goal_here)) <= self.follower.config.goal_tolerance and not tentative:
            if vertex == self.goal.vertex:
                self.status = NavStatus(Status.REACHED)
                return Command()
            # near the goal through the graph but not yet in v_goal: ask the maintainer to check v_goal
            if self._try_goal_vertex(obs, vertex, pose):
                self.status = NavStatus(Status.REACHED)
                return Command()
        if self._goal_short and self.follower.has_path and self.follower.reached and vertex == self.goal.vertex and not tentative:
            # a goal the robot does not fit at (estimated into a wall): as near as the free space allows
            self.counters["reached_short"] += 1
            self.status = NavStatus(Status.REACHED)
            return Command()
        self._remember_obstacles(obs, vertex, pose)
        if tentative:
            # the hypothesis may be another place's map: what the scan shows on the way is an obstacle
            hits = self.explorer.scan_on_path(obs, pose)
            if len(hits):
                self.obstacles.mark(hits)
                self.counters["tentative_blocked"] += 1
        if self._needs_plan(obs, vertex, pose):
            if not self._plan(obs, vertex, pose, tentative):
                return Command()
        if not tentative and self._stuck(obs, pose):
            return Command()
        command = self.follower.command(pose)
        return command

    def _goal_in(self, vertex: int) -> NDArray[np.float64] | None:
        """The goal's position in ``vertex``'s frame through the global path (None: no path)."""
        assert self.goal is not None
        if self.global_planner.goal != self.goal.vertex:
            return None
        route = self.global_planner.path(vertex)
        if route is None:
            return None
        last = path_positions(self.graph, route)[-1]
        return transform_points(last, self.goal.pose[None])[0]

    def _try_goal_vertex(self, obs: Observation, vertex: int, pose: NDArray) -> bool:
        assert self.goal is not None
        route = self.global_planner.path(vertex)
        if route is None:
            return False
        relative = path_positions(self.graph, route)[-1]  # v_goal in vertex's frame
        m = self.maintainer
        query = prepare(grid_from_points(obs.points, m.grid_config), m.grid_config, m.matching)
        located = m.localizer.verify(query, self.goal.vertex, between(relative, pose), m.config.max_neighbour_jump)
        if located is None:
            self.counters["reached_by_composition"] += 1
            return True  # the graph says the robot is there; one vertex short of v_goal is no other place
        m.start_at(self.goal.vertex, located.pose, obs.odom)
        return float(np.hypot(*(located.pose[:2] - self.goal.pose))) <= self.follower.config.goal_tolerance + 0.1

    def _needs_plan(self, obs: Observation, vertex: int, pose: NDArray) -> bool:
        if self._path_vertex != vertex or not self.follower.has_path:
            return True
        since = obs.stamp - self._plan_stamp
        if since >= self.local.config.replan_period:
            return True
        near_end = self.follower.path_length - self.follower.progress < self.config.replan_before_end
        if self.local.config.smoothing == "lookahead" and near_end and not self._target_is_goal and since >= 0.5:
            return True  # reach further before the robot slows down at the end of its path
        return self._path_blocked(pose)

    def _path_blocked(self, pose: NDArray) -> bool:
        clearance = self.robot_radius + self.config.block_clearance
        return self.follower.path_ahead_blocked(self._recent_obstacles(), pose, clearance, self.config.block_check_distance)

    def _plan(self, obs: Observation, vertex: int, pose: NDArray, tentative: bool = False) -> bool:
        """Global path from ``vertex`` (Dijkstra once per goal and per removed edge), then the local
        path. Driving by an unconfirmed hypothesis (``tentative``), a failure removes no edge and
        ends nothing: the hypothesis may be the wrong one."""
        assert self.goal is not None
        t0 = time.perf_counter()
        planned = None
        while True:
            if self.global_planner.goal != self.goal.vertex:
                self.global_planner.set_goal(self.goal.vertex)
            route = self.global_planner.path(vertex)
            if route is None:
                self._timed(t0)
                if not tentative:
                    self.status = NavStatus(Status.FAILED, "no_path")
                return False
            positions = path_positions(self.graph, route)
            goal_point = transform_points(positions[-1], self.goal.pose[None])
            points = np.vstack([positions[1:, :2], goal_point]) if len(route) > 1 else goal_point
            union = self.unions.get(vertex)
            target = self.local.target(union, pose, points, self._recent_obstacles())
            planned = self.local.plan(union, pose, target, self._recent_obstacles())
            if planned is None and not np.allclose(target, points[0]):  # a shorter reach: the next vertex
                target = points[0]
                planned = self.local.plan(union, pose, target, self._recent_obstacles())
            self.counters["plans"] += 1
            if planned is not None or len(route) == 1 or tentative:
                break
            # no way to the next vertex in the union grid (a closed door, an obstacle the map lacks)
            self.counters["plans_failed"] += 1
            self.counters["edges_removed"] += 1
            self.global_planner.remove_edge(route[0], route[1])
        self._timed(t0)
        if planned is None:
            self.counters["plans_failed"] += 1
            if not tentative:
                self.status = NavStatus(Status.FAILED, "no_path")
            return False
        self._route = route
        self._path_vertex = vertex
        self._plan_stamp = obs.stamp
        self._target_is_goal = bool(np.allclose(target, goal_point[0]))
        self._goal_short = self._target_is_goal and not np.allclose(planned.points[-1], target)
        self.follower.set_path(planned.points)
        return True

    def _timed(self, t0: float) -> None:
        # with the union grids built since the last plan (the new-obstacle check asks first)
        elapsed = (time.perf_counter() - t0) * 1e3 + self.unions.take_build_ms()
        self.planning_ms.append(elapsed)
        if self.first_plan_ms is None and self.localized:
            self.first_plan_ms = elapsed

    def _at_path_end(self) -> bool:
        """The local path has been driven to its end short of the goal: the maintainer must look now."""
        return bool(self.follower.has_path and self.follower.reached and not self._target_is_goal)

    # -- new obstacles and progress ---------------------------------------------------------------------

    def _remember_obstacles(self, obs: Observation, vertex: int, pose: NDArray) -> None:
        """Mark the scan's returns no mapped wall explains, clear those it sees through (in v_cur's frame)."""
        if self._obstacle_vertex is not None and self._obstacle_vertex != vertex and len(self.obstacles):
            # into the new location's frame, through the edge between them (or forget them)
            if self.graph.has_edge(self._obstacle_vertex, vertex):
                self.obstacles.transform(self.graph.edge(self._obstacle_vertex, vertex))
            else:
                self.obstacles.clear()
        self._obstacle_vertex = vertex
        points = obstacle_points(obs.points, self.maintainer.grid_config)
        new = self.local.new_obstacles(self.unions.get(vertex), pose, points)
        self.obstacles.update(pose, points, new, self.local.config.new_obstacle_range)

    def _recent_obstacles(self) -> NDArray[np.float64]:
        return self.obstacles.points

    def _stuck(self, obs: Observation, pose: NDArray) -> bool:
        """No progress for ``stuck_time``: remove the edge being followed and replan; twice: fail."""
        odom = np.asarray(obs.odom, dtype=np.float64)
        if self._progress is None or np.hypot(*(odom[:2] - self._progress[1][:2])) > 0.1:
            self._progress = (obs.stamp, odom.copy())
            return False
        if obs.stamp - self._progress[0] < self.config.stuck_time:
            return False
        self._progress = (obs.stamp, odom.copy())
        if self._stuck_once or not self._route or len(self._route) < 2:
            self.status = NavStatus(Status.FAILED, "stuck")
            return True
        self._stuck_once = True
        self.counters["edges_removed"] += 1
        self.global_planner.remove_edge(self._route[0], self._route[1])
        self._path_vertex = None
        return False
