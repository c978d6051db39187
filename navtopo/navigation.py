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

Where it fails (``status.stage``, docs/DESIGN.md "Trial end"): ``startup`` (``not_localized``, or
any ending before the commitment); ``global_plan`` (no route over the graph, no edge removed: the
graph does not join the robot's location and the goal's); ``local_plan`` (no local path to the
goal in its location, or edges removed for want of a local path until no route was left);
``follower`` (``stuck``, or no route left once edges were removed for being stuck on them);
``localization`` while odometry alone has kept the pose for ``LOST_AFTER_M`` (no location verified).
The detail names the locations (their index in the graph), the edges removed and how far the goal
is (straight, by the locations' map-frame poses).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from navkit.explore import Explorer
from navkit.follower import PathFollower, ProgressCheck
from navkit.geometry import between, compose, inverse, transform_points
from navkit.obstacles import ObstacleMemory, scan_guard
from navkit.odometer import Odometer
from navkit.passages import PassageCheck, PassageConfig, returns_near
from navkit.raster import FREE
from navkit.scan import obstacle_points
from navkit.scan_grid import GridConfig, ScanGrid, grid_frame, grid_from_points
from navkit.types import Command, FailureStage, NavStatus, Observation, Status
from navtopo.graph import TopologicalGraph
from navtopo.graph_poses import relaxed_poses
from navtopo.mapping import GraphMaintainer
from navtopo.planning import GlobalPlanner, LocalPlanner, PlannedPath, UnionGrid, UnionGrids, bypasses
from navtopo.scan_matching import prepare
from navtopo.startup import Hypothesis, Localization, Startup

#: metres of odometry alone (every update "lost": outside every location's reach, none verified)
#: after which the navigator says it is lost (stage ``localization``); a diagnosis, no behaviour
LOST_AFTER_M = 2.0


class NavigationConfig(BaseModel):
    """Failure handling while navigating."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    stuck_time: float = Field(15.0, gt=0, description="s without 0.1 m of progress: remove the edge, replan; twice: fail")
    block_check_distance: float = Field(4.0, gt=0, description="m of the path ahead checked against new obstacles")
    block_clearance: float = Field(0.05, ge=0, description="m beyond the robot radius; nearer new obstacles block the path")
    replan_before_end: float = Field(1.5, gt=0, description="m: replan when the local path ends this close ahead")
    passage_check_range: float = Field(
        3.0,
        ge=0,
        description="m along the path: a narrow passage (a path found on a medial level) this near ahead is checked "
        "against the scan's returns, moved sideways to their middle or, if the robot does not fit, blocked (0: never)",
    )
    passage_margin: float = Field(
        0.04,
        ge=0,
        description="m beyond the robot radius the scan must leave in a passage (its returns sample a jamb's corner "
        "a few centimetres apart)",
    )
    passage_block_range: float = Field(
        1.5, ge=0, description="m along the path: a passage this near is shut if the robot does not fit"
    )
    passage_mouth_margin: float | None = Field(
        0.0,
        ge=0,
        description="m beyond the robot radius the scan must leave where the robot stands at a passage's mouth "
        "(navkit.passages.PassageConfig.mouth_margin; 0: no contact, what the scan guard asks; None: "
        "passage_margin, as before, configs/navtopo_before_faces.yaml)",
    )
    passage_check_period: float = Field(0.2, ge=0, description="s of simulated time between checks of a passage")
    passage_max_shift: float = Field(0.3, ge=0, description="m a passage may be moved sideways to the scan's middle")
    route_check_confirm: float = Field(
        0.6,
        description="s: a scan's new obstacles that shut an edge of the route ahead (LocalPlanner.blocked_leg, checked "
        "at every plan) must shut it again in a scan this much later before the edge is removed and the route planned "
        "again round it, as soon as seen rather than when the robot stands before them (a shut door); negative: never "
        "checked",
    )
    recoveries: int = Field(
        3,
        ge=0,
        description="per goal, as the metric baseline's (Nav2's behaviour tree: clear the costmap, plan again): a local "
        "plan that only the remembered obstacles stop forgets them and plans again before the edge is removed (returns "
        "a few decimetres off a mapped wall in a narrow corridor, kept as obstacles, shut it both ways)",
    )


def goal_in_graph(
    graph: TopologicalGraph,
    goal_xy: NDArray,
    grid_config: GridConfig,
    poses: NDArray | None = None,
    way: Callable[[int, NDArray], float | None] | None = None,
) -> tuple[int, NDArray[np.float64]]:
    """A map-frame goal (2,) as ``(v_goal, T_goal)``: among the vertices whose known free area holds
    the goal, the nearest. If none holds it (a room the mapping route passed by without looking in),
    the vertex with the shortest ``way(vertex, goal in its frame)`` (metres, None: no way; the
    navigator's: a local plan from the vertex through its union grid, unknown cells inside the room
    included); with no way found, or no ``way`` given, the nearest. ``poses`` (V, 3): the vertices'
    poses in the map frame (``navtopo.graph_poses.relaxed_poses``; default: their odometry hints)."""
    goal_xy = np.asarray(goal_xy, dtype=np.float64)[:2]
    if poses is None:
        poses = np.array([vertex.pose_hint for vertex in graph.vertices])
    assert len(poses), "an empty graph has no goal vertex"
    local = np.array([transform_points(inverse(pose), goal_xy[None])[0] for pose in poses])
    distance = np.hypot(local[:, 0], local[:, 1])
    order = [int(v) for v in np.argsort(distance, kind="stable")]
    held = [v for v in order if goal_held(graph, v, local[v], grid_config)]
    if held:
        return held[0], local[held[0]]
    best: tuple[float, int] | None = None
    for v in order:  # nearest first; no way is shorter than the straight line
        if way is None or distance[v] > grid_config.radius or (best is not None and distance[v] >= best[0]):
            break
        length = way(v, local[v])
        if length is not None and (best is None or length < best[0]):
            best = (length, v)
    chosen = order[0] if best is None else best[1]
    return chosen, local[chosen]


def _same_point(a: NDArray, b: NDArray) -> bool:
    """Two points (2,) the same but for rounding (a micrometre): ``np.allclose`` costs more."""
    return abs(float(a[0]) - float(b[0])) <= 1e-6 and abs(float(a[1]) - float(b[1])) <= 1e-6


def goal_held(graph: TopologicalGraph, vertex: int, pose: NDArray, grid_config: GridConfig) -> bool:
    """Does the goal ``pose`` (2,) in ``vertex``'s frame lie in that location's known free space?"""
    row, col = grid_frame(grid_config).to_cell(np.asarray(pose, dtype=np.float64)[None, :2])[0]
    grid = graph.vertices[vertex].grid
    row, col = row - grid.row0, col - grid.col0
    return bool(0 <= row < grid.cells.shape[0] and 0 <= col < grid.cells.shape[1] and grid.cells[row, col] == FREE)


@dataclass
class Goal:
    vertex: int
    pose: NDArray[np.float64]  # (2,) the goal in v_goal's frame
    held: bool = True  # it lies in v_goal's known free space (else: the nearest location, none holds it)


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
    planning_ms: list[float] = field(default_factory=list)  # plans after the start-up committed
    startup_planning_ms: list[float] = field(default_factory=list)  # plans while driving by a hypothesis
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
    # no 0.1 m of odometry for ``stuck_time`` (set at reset)
    _progress: ProgressCheck = field(default_factory=lambda: ProgressCheck(0.1, np.inf))
    _stuck_once: bool = False
    _tentative: Hypothesis | None = None  # the start-up hypothesis the robot drives by
    _odometer: Odometer = field(default_factory=Odometer)  # of this trial
    _lost_since: float | None = None  # the odometer at the first of the "lost" updates in a row
    _removed: dict[tuple[int, int], str] = field(default_factory=dict)  # edges removed this trial, and why
    _added: list[tuple[int, int]] = field(default_factory=list)  # edges added this trial (``_bypass``)
    _shut_since: tuple[tuple[int, int], float] | None = None  # the route's edge new obstacles shut, since when
    _latest_new: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 2)))  # this scan's, v_cur's frame
    # ((v_cur, route), route points the lookahead passed, its target there): ``LocalPlanner.aim``
    _aimed: tuple[tuple[int, tuple[int, ...]], int, NDArray[np.float64]] | None = None
    # the planner level of the last local path to the goal from the goal's own location (``_goal_straight``)
    _goal_level: int | None = None
    passages: PassageCheck | None = None  # the narrow part of the path being followed, checked against the scan

    def reset(self) -> None:
        self.status = NavStatus()
        self.goal = None
        self.localized = False
        self.planning_ms = []
        self.startup_planning_ms = []
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
                "passages_centred",
                "passages_blocked",
                "scan_plans",
                "recoveries",
                "edges_shut_ahead",
                "longer_ways",
                "bypass_edges",
                "scan_guard_stops",
            ],
            0,
        )
        self.maintainer.forget()
        # cold: nothing built from the map for planning or matching carries over from the last
        # trial (a first plan times every grid it needs)
        self.unions.clear()
        self.maintainer.grids.clear()
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
        self._progress = ProgressCheck(0.1, self.config.stuck_time)
        self._stuck_once = False
        self.explorer.reset()
        self._tentative = None
        self._odometer, self._lost_since = Odometer(), None
        for p, q in self._added:  # this trial's edges: the map as it was loaded for the next
            self.graph.remove_edge(p, q)
        self._added = []
        self._removed = {}
        self._shut_since = None
        self._latest_new = np.zeros((0, 2))
        self._aimed = None
        self._goal_level = None
        self._passages().clear()

    # -- the goal server ----------------------------------------------------------------------------

    def set_goal(self, goal_xy: NDArray) -> None:
        """A map-frame goal, turned into the paper's form with the vertices' map-frame poses (their
        odometry hints, relaxed against the scan-matched edges: ``navtopo.graph_poses``)."""
        if self.map_poses is None or len(self.map_poses) != len(self.graph):
            self.map_poses = relaxed_poses(self.graph)
        self.startup.map_poses = self.map_poses
        vertex, pose = goal_in_graph(self.graph, goal_xy, self.maintainer.grid_config, self.map_poses, self._way_from)
        self.set_goal_in_graph(vertex, pose)

    def _way_from(self, vertex: int, point: NDArray) -> float | None:
        """Metres of the local plan from ``vertex``'s centre to ``point`` (2,) in its frame, through
        its union grid (None: none): where a goal no location holds is reached from."""
        planned = self.local.plan(self.unions.get(vertex), np.zeros(3), point)
        return None if planned is None else planned.length

    def set_goal_in_graph(self, vertex: int, pose: NDArray) -> None:
        """The paper's goal form: ``(v_goal, T_goal)``, T_goal the goal's position in v_goal's frame."""
        pose = np.asarray(pose, dtype=np.float64)[:2].copy()
        self.goal = Goal(int(vertex), pose, goal_held(self.graph, int(vertex), pose, self.maintainer.grid_config))
        self.status = NavStatus()
        self._goal_level = None

    # -- stepping -------------------------------------------------------------------------------------

    def step(self, obs: Observation) -> Command:
        if self.goal is None:
            raise RuntimeError("step() before set_goal()")
        if self.status.state != Status.ACTIVE:
            return Command()
        self._odometer.update(obs.odom)
        if not self.localized:
            return self._step_unlocalized(obs)
        before = self.maintainer.current
        event = self.maintainer.update(
            obs.points, obs.odom, obs.stamp, route=self._route, force=self._at_path_end(), ahead=self._heading_for()
        )
        if self.maintainer.current != before or event == "localized":
            self._path_vertex = None  # a new frame: plan again
        current = self.maintainer.current
        assert current is not None, "a localized robot is in a location"
        self._track_lost(event, current)
        return self._drive(obs, current, self.maintainer.pose_in_current)

    def _step_unlocalized(self, obs: Observation) -> Command:
        startup, explorer = self.startup, self.explorer
        explorer.record(obs.odom)
        driven = self._tentative if self._tentative in startup.hypotheses else None
        looks = startup.looks
        committed = startup.step(obs, driven, self._route if driven is not None else None, force=self._at_path_end())
        if committed is not None:
            return self._commit(obs, committed)
        if startup.timed_out(obs.stamp):
            detail = f"no commitment in {startup.config.timeout:g} s: {self._startup_state()}"
            self.status = NavStatus(Status.FAILED, "not_localized", FailureStage.STARTUP, detail)
            return Command()
        if startup.looks != looks or self.status.stage != FailureStage.STARTUP:
            self.status = NavStatus(stage=FailureStage.STARTUP, detail=f"start-up, not localized yet: {self._startup_state()}")
        best = startup.best()
        odometer = startup.odometer
        if explorer.under_way(odometer):
            return explorer.step(obs, self.counters)  # an exploring move runs to its end
        # look-alikes make the robot explore, but not from a doorway: an exploring move planned
        # from inside one turned on the spot and cut the jamb (on a held-out wing)
        ambiguous = startup.ambiguous() and explorer.roomy(obs)
        if best is not None and not ambiguous and not explorer.no_progress(obs.stamp, odometer):
            # drive as the best hypothesis sees it: confirmation on the way
            if best is not self._tentative or explorer.move is not None:
                self._tentative, self._path_vertex, self._route = best, None, None
                explorer.stop()
            return self._drive(obs, best.vertex, best.pose, tentative=True)
        # no hypothesis, look-alikes as well supported as the best, or driving by the best one gets
        # nowhere (it may be the wrong one, or two places look alike from here): move toward open
        # space for a new view (no move is under way here: a new one begins)
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
                given_pose=startup.from_given_pose,
            )
        )
        self._path_vertex = None
        # the obstacles remembered so far were placed by the hypotheses' poses (a wrong one, or
        # the right place off by a few decimetres, puts a door's jambs into its opening, and a
        # door's middle is rarely seen through again from afar: the door stays shut); the scans
        # from the committed pose on mark what is there
        self.obstacles.clear()
        self._obstacle_vertex = None
        # the first plan from here is timed cold: the union grids the start-up built go (their
        # milliseconds to the start-up's), and the first plan builds what it needs
        self.unions.clear()
        built = self.unions.take_build_ms()
        if built > 0:
            self.startup_planning_ms.append(built)
        self.status = NavStatus(detail=f"localized in location {committed.vertex} after {startup.looks} looks")
        return self._drive(obs, committed.vertex, committed.pose)

    # -- planning and following ----------------------------------------------------------------------------

    def _drive(self, obs: Observation, vertex: int, pose: NDArray, tentative: bool = False) -> Command:
        assert self.goal is not None
        goal_here = self._goal_in(vertex)
        if goal_here is not None and np.hypot(*(pose[:2] - goal_here)) <= self.follower.config.goal_tolerance and not tentative:
            if vertex == self.goal.vertex:
                self.status = NavStatus(Status.REACHED, detail=self._reached_detail("in"))
                return Command()
            # near the goal through the graph but not yet in v_goal: ask the maintainer to check v_goal
            if self._try_goal_vertex(obs, vertex, pose):
                self.status = NavStatus(Status.REACHED, detail=self._reached_detail(f"in location {vertex}, next to"))
                return Command()
        if self._goal_short and self.follower.has_path and self.follower.reached and vertex == self.goal.vertex and not tentative:
            # a goal the robot does not fit at (estimated into a wall): as near as the free space allows
            self.counters["reached_short"] += 1
            self.status = NavStatus(Status.REACHED, detail=self._reached_detail("short of the goal (no room at it) in"))
            return Command()
        band = self._remember_obstacles(obs, vertex, pose)
        if tentative:
            # the hypothesis may be another place's map: what the scan shows on the way is an obstacle
            hits = self.explorer.scan_on_path(obs, pose)
            if len(hits):
                self.obstacles.mark(hits)
                self.counters["tentative_blocked"] += 1
        if self._needs_plan(obs, vertex, pose):
            if not self._plan(obs, vertex, pose, tentative):
                return Command()
        if not self._check_passage(obs, pose):
            return Command()  # the passage is shut to the robot: plan again at the next tick
        if self._guard_stops(band, pose):
            return Command()  # the scan shows the way ahead too near a return: plan again round it
        if not tentative and self._stuck(obs, pose):
            return Command()
        command = self.follower.command(pose)
        return command

    def _heading_for(self) -> int:
        """The index in the route of the vertex the local path heads for: past the route points a
        straight cut left behind (``LocalPlanner.aim``; 1: the next vertex)."""
        route, aimed = self._route, self._aimed
        if not route or aimed is None or aimed[0] != (self._path_vertex, tuple(route)):
            return 1
        return max(min(aimed[1] + 1, len(route) - 1), 1)

    def _goal_in(self, vertex: int) -> NDArray[np.float64] | None:
        """The goal's position in ``vertex``'s frame through the global path (None: no path)."""
        assert self.goal is not None
        if self.global_planner.goal != self.goal.vertex:
            return None
        route = self.global_planner.path(vertex)
        if route is None:
            return None
        last = self.graph.path_poses(route)[-1]
        return transform_points(last, self.goal.pose[None])[0]

    def _try_goal_vertex(self, obs: Observation, vertex: int, pose: NDArray) -> bool:
        assert self.goal is not None
        route = self.global_planner.path(vertex)
        if route is None:
            return False
        relative = self.graph.path_poses(route)[-1]  # v_goal in vertex's frame
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
        if self._shut_since is not None and obs.stamp - self._shut_since[1] >= self.config.route_check_confirm:
            return True  # an edge ahead looked shut: look again
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
                    self.status = NavStatus(Status.FAILED, "no_path", *self._no_route(vertex, pose))
                return False
            positions = self.graph.path_poses(route)
            goal_point = transform_points(positions[-1], self.goal.pose[None])
            points = np.vstack([positions[1:, :2], goal_point]) if len(route) > 1 else goal_point
            union = self.unions.get(vertex, self.unions.window(route, positions))
            if not tentative and self._shut_ahead(obs, union, pose, route, points):
                continue  # the edge is gone: the route again, round it
            target, planned = self._local_path(union, pose, vertex, route, points)
            self.counters["plans"] += 1
            if planned is None and not tentative and (not self.goal.held or self.obstacles.holding):
                # a goal in a room no location saw into: planned in the robot's own scan, which shows
                # the room through its door once the robot stands before it; so too a way the scan
                # guard stopped (the pose 0.2 m off: the map's walls and the returns marked beside
                # them shut a passage the scan shows open)
                target = target if self.goal.held else goal_point[0]
                planned = self._plan_in_scan(obs, pose, target)
            if planned is not None or tentative:
                break
            if self._recover(union, pose, target):
                continue  # only the remembered obstacles stopped it: forgotten, planned again
            if len(route) == 1:
                break  # in the goal's location: no edge to remove
            longer = self._longer_way(union, pose, route, points[0])
            if longer is not None:
                target, planned = points[0], longer
                break
            # no way to the next vertex in the union grid (a closed door, an obstacle the map lacks)
            self.counters["plans_failed"] += 1
            self._remove_edge(route, positions, 0, "no local path", self._recent_obstacles())
        self._timed(t0)
        if planned is None:
            self.counters["plans_failed"] += 1
            if not tentative:
                # in v_goal (a route of one vertex): no local path to the goal itself
                detail = f"no local path to the goal in its location {vertex} (union grid){self._far(vertex, pose)}"
                self.status = NavStatus(Status.FAILED, "no_path", FailureStage.LOCAL_PLAN, detail)
            return False
        self._route = route
        self._path_vertex = vertex
        self._plan_stamp = obs.stamp
        self._target_is_goal = _same_point(target, goal_point[0])
        if len(route) == 1 and self._target_is_goal:
            self._goal_level = planned.level
        self._goal_short = self._target_is_goal and not _same_point(planned.points[-1], target)
        kind, radius, medial = self.local.levels[planned.level]
        # the narrow part checked against the scan: a medial path's stretch off the level's own cells,
        # any other's nearer the walls than the first level's margin (a door passed diagonally at the
        # radius, the pose 0.1-0.2 m off under noise, met its jamb), as the baseline's every path
        roomy = radius if medial is not None else (self.local.wide if radius < self.local.wide else None)
        self._passages().follow(self.follower, planned.points, None if roomy is None else union.passable_at(kind, roomy))
        if not tentative:
            self._describe(self._following(route))
        return True

    def _local_path(
        self, union: UnionGrid, pose: NDArray, vertex: int, route: list[int], points: NDArray
    ) -> tuple[NDArray[np.float64], PlannedPath | None]:
        """The local target along the route's ``points`` (the goal last) and the path to it, or None."""
        along = (vertex, tuple(route))  # route points a cut passed by stay passed along this route
        skip, resume = (self._aimed[1], self._aimed[2]) if self._aimed is not None and self._aimed[0] == along else (0, None)
        target, kept = self.local.aim(union, pose, points, self._recent_obstacles(), skip)
        planned = self.local.plan(union, pose, target, self._recent_obstacles())
        if resume is not None and (planned is None or self.local.levels[planned.level][0] == "unknown"):
            # the route taken up at a point only unknown cells reach (the lookahead's target had gone
            # past it into a door the union grid shows as a gap; the way to it went into another room
            # and through its unseen wall, and the robot went to and fro until the time ran out: an
            # office ring, precise): taken up at the last target instead, where a way through known
            # cells reaches (``LocalPlanner.aim``). Taken up there every time, the route lost the straighter cuts
            # the robot's new spot showed (a depot, noisy: 0.82 against 1.00)
            again, passed = self.local.aim(union, pose, points, self._recent_obstacles(), skip, resume)
            planned_again = None if _same_point(again, target) else self.local.plan(union, pose, again, self._recent_obstacles())
            if planned_again is not None and self.local.levels[planned_again.level][0] == "known":
                target, kept, planned = again, passed, planned_again
        self._aimed = (along, kept, target)
        if planned is None and not _same_point(target, points[0]):  # a shorter reach: the next vertex
            target, self._aimed, kept = points[0], None, 0
            planned = self.local.plan(union, pose, target, self._recent_obstacles())
        if len(route) == 2 and not _same_point(target, points[-1]):
            target, planned = self._goal_straight(union, pose, target, planned, points[kept:])
            if _same_point(target, points[-1]):
                self._aimed = (along, len(points) - 1, target)  # the goal location's position passed
        return target, planned

    def _goal_straight(
        self, union: UnionGrid, pose: NDArray, target: NDArray, planned: PlannedPath | None, rest: NDArray
    ) -> tuple[NDArray[np.float64], PlannedPath | None]:
        """One edge from the goal's location: the local path to the goal itself where it is no longer
        than the path to ``target`` and on along the route (``rest``: its points after the target, the
        goal last). The goal is reached from this location by the composed pose; by the goal
        location's position first, a goal 6.8 m from it (a room that location saw into) sent the
        robot from beside the goal back to that position and forth again until it was stuck."""
        goal = rest[-1]
        direct = self.local.plan(union, pose, goal, self._recent_obstacles())
        if direct is None or (direct.level > 0 and (self._goal_level is None or direct.level > self._goal_level)):
            # with the margin all the way only: a way by a door at the radius, taken straight from the
            # side, met the jamb (office02), where the way by the location's position met the door square.
            # But once the goal's own location planned to the goal on no better level than this, the
            # direct way: from beside it, that location's position first sent the robot back there and,
            # the goal beyond cells neither location saw, to and fro between the two locations until the
            # time ran out (a generated slam-ring, precise)
            return target, planned
        onward = np.vstack([target[None, :2], rest])
        if planned is not None and direct.length > planned.length + float(np.hypot(*np.diff(onward, axis=0).T).sum()):
            return target, planned
        return goal, direct

    def _shut_ahead(self, obs: Observation, union: UnionGrid, pose: NDArray, route: list[int], points: NDArray) -> bool:
        """Whether this scan's new obstacles shut an edge of the route ahead (``LocalPlanner.
        blocked_leg``), as a scan ``route_check_confirm`` s before did: then it is removed (counted,
        ``edges_shut_ahead``). A leg into the goal's location's own goal point is no edge: the plan
        to it decides."""
        confirm = self.config.route_check_confirm
        if confirm < 0:
            return False
        # this scan's new obstacles only: remembered ones may have been placed by a pose since
        # corrected (a wrong location for a moment put returns across an open corridor)
        leg = self.local.blocked_leg(union, pose, points, self._latest_new)
        if leg is None or leg >= len(route) - 1:
            self._shut_since = None
            return False
        edge = (route[leg], route[leg + 1])
        if self._shut_since is None or self._shut_since[0] != edge:
            self._shut_since = (edge, obs.stamp)  # plans again then (``_needs_plan``) to look again
            return False
        if obs.stamp - self._shut_since[1] < confirm:
            return False
        self._shut_since = None
        self.counters["edges_shut_ahead"] += 1
        self._remove_edge(route, self.graph.path_poses(route), leg, "shut ahead", self._latest_new)
        return True

    def _longer_way(self, union: UnionGrid, pose: NDArray, route: list[int], target: NDArray) -> PlannedPath | None:
        """Before the route's first edge goes for want of a local path: a way to the next vertex
        (``target``) through cells no location saw, longer than ``planning.unknown_detour`` allows, as
        long as it still beats the route round without the edge (counted, ``longer_ways``). A robot
        starting in a room no location saw, its door 2 m behind it, had its way out refused (7.6 m
        against 2.7 m straight to the next location, through the wall between rooms) and went round
        a ring of 85 m for a goal 15 m away (an aliased wing, noisy)."""
        round_m = self.global_planner.distance_without(route[0], route[0], route[1])
        # no way round at all: any way the union grid holds (twice its sides, a bound for the search)
        bound = min(round_m - self.global_planner.distance(route[1]), 2.0 * sum(union.cells.shape) * union.frame.resolution)
        if bound <= self.local.detour(pose, target):
            return None  # no longer than the plan already allowed
        planned = self.local.plan(union, pose, target, self._recent_obstacles(), detour_m=bound)
        if planned is not None:
            self.counters["longer_ways"] += 1
        return planned

    def _remove_edge(self, route: list[int], positions: NDArray, leg: int, why: str, obstacles: NDArray) -> None:
        """The route's edge ``leg`` (route[leg] -> route[leg + 1]; ``positions``: the route's vertices in
        v_cur's frame) removed for this trial, and why (counted, ``edges_removed``; the trial's detail
        names it); its far vertex bypassed where ``obstacles`` (v_cur's frame) cover its spot."""
        edge = (route[leg], route[leg + 1])
        self.counters["edges_removed"] += 1
        self._bypass(edge[1], positions[leg + 1], obstacles)
        self.global_planner.remove_edge(*edge)
        self._removed[edge] = why

    def _bypass(self, vertex: int, where: NDArray, new: NDArray) -> None:
        """An edge into ``vertex`` found shut or impassable where ``vertex``'s own position (``where``,
        in v_cur's frame) lies under the obstacles the map lacks (``new``; a door shut on the spot the
        location was made at): the route through it need not pass there. Each two of its neighbours
        that its union grid joins round the obstacles get an edge of this trial
        (``planning.bypasses``; counted, ``bypass_edges``; gone at reset)."""
        if not len(new) or float(np.hypot(*(new[:, :2] - where[:2]).T).min()) > self.local.tight:
            return
        blocked = transform_points(inverse(where), new[:, :2])
        for p, q, pose_pq, metres in bypasses(self.graph, self.unions, self.local, vertex, blocked, self.global_planner.removed):
            self.graph.add_edge(p, q, pose_pq)
            self.graph.set_edge_length(p, q, metres)
            self._added.append((p, q))
            self.unions.forget({p, q})
            self.counters["bypass_edges"] += 1

    def _recover(self, union: UnionGrid, pose: NDArray, target: NDArray) -> bool:
        """A failed local plan that the map alone allows (the remembered obstacles stopped it): forget
        them and plan again, as the metric baseline clears its costmap, while this goal has
        ``recoveries`` left (counted). A door shut after mapping is seen again at the next scan, and
        the plan fails again; past the recoveries the edge is removed."""
        if not len(self.obstacles) or self.counters["recoveries"] >= self.config.recoveries:
            return False
        if self.local.plan(union, pose, target) is None:
            return False  # no way even on the map: the edge goes
        self.counters["recoveries"] += 1
        self.obstacles.clear()
        return True

    def _plan_in_scan(self, obs: Observation, pose: NDArray, goal: NDArray) -> PlannedPath | None:
        """The local path to ``goal`` (2,, v_cur's frame) in the scan's grid (``ScanGrid.
        plan_seen_first``), in v_cur's frame."""
        scan = ScanGrid.of(obs.points, self.maintainer.grid_config, self.local.wide, self.local.tight)
        end = transform_points(inverse(pose), goal[None])[0]
        found = scan.plan_seen_first(end, self.local.config.unknown_detour, self.local.medial, search=self.local.search)
        if found is None:
            return None
        self.counters["scan_plans"] += 1
        points = transform_points(pose, found.points)
        points[0], points[-1] = pose[:2], goal
        return PlannedPath(points, 0)

    def _timed(self, t0: float) -> None:
        # with the union grids built since the last plan (the new-obstacle check asks first)
        elapsed = (time.perf_counter() - t0) * 1e3 + self.unions.take_build_ms()
        if not self.localized:  # start-up plans, counted apart
            self.startup_planning_ms.append(elapsed)
            return
        self.planning_ms.append(elapsed)
        if self.first_plan_ms is None:
            self.first_plan_ms = elapsed

    def _at_path_end(self) -> bool:
        """The local path has been driven to its end short of the goal: the maintainer must look now."""
        return bool(self.follower.has_path and self.follower.reached and not self._target_is_goal)

    def _passages(self) -> PassageCheck:
        if self.passages is None:
            c = self.config
            config = PassageConfig(
                check_range=c.passage_check_range,
                margin=c.passage_margin,
                mouth_margin=c.passage_mouth_margin,
                block_range=c.passage_block_range,
                period=c.passage_check_period,
                max_shift=c.passage_max_shift,
            )
            self.passages = PassageCheck(config, self.robot_radius)
        return self.passages

    def _check_passage(self, obs: Observation, pose: NDArray) -> bool:
        """The narrow passage of the path against the scan's returns (``navkit.passages``): moved to
        their middle, or shut (its returns become obstacles, the path is dropped; False: plan again).
        True: follow on."""
        verdict = self._passages().step(
            self.follower, obs.stamp, pose, lambda segment, reach: self._returns_near(obs, pose, segment, reach)
        )
        if verdict.shut is not None:
            self.obstacles.mark(verdict.shut)
            self.counters["passages_blocked"] += 1
            self._path_vertex = None
            self.follower.clear()
            return False
        self.counters["passages_centred"] += int(verdict.path is not None)
        return True

    def _guard_stops(self, band: NDArray, pose: NDArray) -> bool:
        """The scan guard (``navkit.obstacles.scan_guard``) on this scan's obstacle band (robot frame):
        True when returns the way ahead comes too near to were marked and the path dropped (plan again)."""
        if not scan_guard(self.follower, self.obstacles, pose, band, self.robot_radius):
            return False
        self.counters["scan_guard_stops"] += 1
        self._path_vertex = None
        self.follower.clear()
        return True

    def _returns_near(self, obs: Observation, pose: NDArray, segment: NDArray, reach: float) -> NDArray[np.float64]:
        """The scan's obstacle returns (v_cur's frame) within ``reach`` of ``segment`` (2, 2)."""
        points = np.asarray(obstacle_points(obs.points, self.maintainer.grid_config)[:, :2], dtype=np.float64)
        return returns_near(transform_points(pose, points), segment, reach)

    # -- new obstacles and progress ---------------------------------------------------------------------

    def _remember_obstacles(self, obs: Observation, vertex: int, pose: NDArray) -> NDArray:
        """Mark the scan's returns no mapped wall explains, clear those it sees through (in v_cur's frame);
        the scan's obstacle band (robot frame), for the scan guard of the same tick."""
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
        self._latest_new = new
        return points

    def _recent_obstacles(self) -> NDArray[np.float64]:
        return self.obstacles.points

    def _stuck(self, obs: Observation, pose: NDArray) -> bool:
        """No progress for ``stuck_time``: remove the edge being followed and replan; twice: fail."""
        if not self._progress.stalled(obs.stamp, obs.odom):
            return False
        if self._stuck_once or not self._route or len(self._route) < 2:
            route = self._route or []
            where = f"location {route[0]} toward location {route[1]}" if len(route) > 1 else "the goal's location"
            twice = "twice" if self._stuck_once else "once, with no edge to remove"
            detail = f"no 0.1 m of progress for {self.config.stuck_time:g} s {twice}, in {where}"
            current = self.maintainer.current
            detail += "" if current is None else self._far(current, pose)
            self.status = NavStatus(Status.FAILED, "stuck", FailureStage.FOLLOWER, detail)
            return True
        self._stuck_once = True
        route = self._route
        # the remembered obstacles are in the current location's frame, which a route is planned
        # from (``_drive``): defensive, a route from another location is not bypassed by them
        obstacles = self._recent_obstacles() if route[0] == self._obstacle_vertex else np.zeros((0, 2))
        self._remove_edge(route, self.graph.path_poses(route), 0, "stuck", obstacles)
        self._path_vertex = None
        return False

    # -- what the status says (docs/DESIGN.md, "Trial end") ----------------------------------------------

    def _track_lost(self, event: str, vertex: int) -> None:
        """Lost: every update for ``LOST_AFTER_M`` of odometry kept the pose by odometry alone."""
        if event == "odometry":
            return
        if event != "lost":
            if self._lost_since is not None:
                self._lost_since = None
                if self.status.stage == FailureStage.LOCALIZATION:
                    self._describe(f"found again in location {vertex}")
            return
        if self._lost_since is None:
            self._lost_since = self._odometer.metres
        alone = self._odometer.metres - self._lost_since
        if self.status.stage != FailureStage.LOCALIZATION and alone >= LOST_AFTER_M:
            self._describe(f"lost in location {vertex}: odometry only for {alone:.1f} m, no location verified")

    def _describe(self, doing: str) -> None:
        """The active status: the stage the robot is in (start-up, lost, or None) and what it is doing."""
        if not self.localized:
            stage: FailureStage | None = FailureStage.STARTUP
        elif self._lost_since is not None and self._odometer.metres - self._lost_since >= LOST_AFTER_M:
            stage = FailureStage.LOCALIZATION
        else:
            stage = None
        self.status = NavStatus(stage=stage, detail=doing)

    def _startup_state(self) -> str:
        startup = self.startup
        alive = len(startup.hypotheses)
        state = f"{alive} hypotheses alive ({startup.seen} found), {startup.looks} looks, {startup.odometer:.1f} m driven"
        if startup.prior_refused:
            state += f", {startup.prior_refused} finds too far from the given pose"
        best = startup.best()
        if best is not None:
            state += f"; best: location {best.vertex}, verified at {best.support} looks in {len(best.places)} locations"
        return state

    def _following(self, route: list[int]) -> str:
        assert self.goal is not None
        if self.status.stage == FailureStage.LOCALIZATION:
            return self.status.detail or ""  # lost: that is the news, until found again
        where = f"location {route[0]} toward location {route[1]}" if len(route) > 1 else f"the goal's location {route[0]}"
        return f"following a local path in {where} (goal location {self.goal.vertex}, {len(route) - 1} edges away)"

    def _far(self, vertex: int, pose: NDArray) -> str:
        """How far the goal is (", 12.3 m from the goal": straight, by the locations' map-frame poses;
        nothing without them), and whether it lies in no location's known free space."""
        assert self.goal is not None
        text = ""
        poses = self.map_poses
        if poses is not None and len(poses) == len(self.graph):
            robot = compose(poses[vertex], np.asarray(pose, dtype=np.float64))
            goal = transform_points(poses[self.goal.vertex], self.goal.pose[None])[0]
            text = f", {float(np.hypot(*(robot[:2] - goal))):.1f} m from the goal"
        if not self.goal.held:
            text += f" (the goal lies in no location's known free space: given to the nearest, {self.goal.vertex})"
        return text

    def _no_route(self, vertex: int, pose: NDArray) -> tuple[FailureStage, str]:
        """The stage and detail of a graph with no route left from ``vertex`` to the goal's location."""
        assert self.goal is not None
        far = self._far(vertex, pose)
        if not self._removed:
            detail = f"no route over the graph from location {vertex} to the goal's location {self.goal.vertex}: not joined{far}"
            return FailureStage.GLOBAL_PLAN, detail
        removed = [f"{u}-{v} ({why})" for (u, v), why in self._removed.items()]
        listed = ", ".join(removed[:4]) + (f" and {len(removed) - 4} more" if len(removed) > 4 else "")
        detail = f"no route left from location {vertex} to the goal's location {self.goal.vertex}, edges removed {listed}{far}"
        local = any(why in ("no local path", "shut ahead") for why in self._removed.values())
        return (FailureStage.LOCAL_PLAN if local else FailureStage.FOLLOWER), detail

    def _reached_detail(self, where: str) -> str:
        assert self.goal is not None
        held = "" if self.goal.held else " (the goal lies in no location's known free space)"
        return f"by its pose {where} the goal's location {self.goal.vertex}{held}"
