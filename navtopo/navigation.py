"""NavTopo's navigation on a saved graph: start-up localization, the goal server and stepping
(Muravyev & Yakovlev, Secs. "Localization", "Path Planning" and "Path Following").

Start-up localization (``Startup``). The robot is given no pose. Each *look* (after every 0.25 m or
15° of motion, the graph maintainer's cadence) retrieves the ``top_k`` locations whose descriptors
are nearest to the scan's and verifies each by scan matching — every location instead at a look
with no hypothesis and before a commitment (``check_all``: place recognition may rank the right
place far down); a verified candidate that no live
hypothesis explains becomes a hypothesis ``(vertex, pose)``, tracked from then on by odometry and
scan matching like the robot itself (inside its location, or along an edge). A look that verifies a
hypothesis supports it; two looks in a row that do not drop it; while rivals live, a look verifies
only by the thresholds without a guess. The robot commits to a hypothesis
only when it is the one left, has been supported at ``confirm_looks`` looks, has survived
``confirm_distance`` metres of motion and has been verified in ``confirm_places`` locations (or
survived ``confirm_distance_one_place`` metres): a wrong localization is worse than none (repeated
rooms, symmetric corridors verify from one viewpoint, a room and its mirror image over metres of
motion inside it; rarely across a door into the next location). Meanwhile the robot
drives toward the goal as the best hypothesis sees it (so confirmation costs no detour when the
best is right), or, with no hypothesis, explores its own scan toward the free point farthest from
where it has driven (out of a room through its door rather than round it again). Without a
commitment after ``timeout`` seconds the trial fails with ``not_localized``.

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
from navkit.geometry import between, compose, distance_to_polyline, inverse, transform_points
from navkit.grid_planning import plan_path
from navkit.grid_search import inflate_free
from navkit.obstacles import ObstacleMemory
from navkit.raster import FREE, OCCUPIED, GridFrame
from navkit.scan import obstacle_points
from navkit.types import Command, NavStatus, Observation, Status
from navtopo.graph import TopologicalGraph
from navtopo.graph_poses import relaxed_poses
from navtopo.local_grid import GridConfig, grid_from_points, xy_to_cell
from navtopo.mapping import GraphMaintainer
from navtopo.planning import GlobalPlanner, LocalPlanner, UnionGrids, path_positions
from navtopo.scan_matching import PreparedGrid, prepare


class StartupConfig(BaseModel):
    """Start-up localization; see the module docstring."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    top_k: int = Field(10, ge=1, description="place-recognition candidates verified at each look")
    check_all: bool = Field(
        True,
        description="verify every location, not only the top_k, at a look with no hypothesis (at most once a metre) and "
        "before a commitment",
    )
    confirm_looks: int = Field(3, ge=1, description="looks that must verify a hypothesis before it is committed")
    confirm_distance: float = Field(2.0, ge=0, description="m of motion a hypothesis must survive before it is committed")
    confirm_places: int = Field(
        2, ge=1, description="locations the hypothesis must have been verified in before it is committed ..."
    )
    confirm_distance_one_place: float = Field(
        4.0, ge=0, description="... unless it has survived this many m of motion (a start and goal in one location)"
    )
    drop_after: int = Field(2, ge=1, description="looks in a row without verification drop a hypothesis")
    same_place: float = Field(1.0, gt=0, description="m: candidates this close (through the graph) are one hypothesis")
    same_place_in_map: float = Field(
        1.5, gt=0, description="m: ... or this close by the locations' map poses, where the graph does not join them"
    )
    explore_distance: float = Field(1.5, gt=0, description="m: with no hypothesis, drive this far toward open space")
    timeout: float = Field(60.0, gt=0, description="s of simulated time without a commitment: not_localized")


class NavigationConfig(BaseModel):
    """Failure handling while navigating."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    stuck_time: float = Field(15.0, gt=0, description="s without 0.1 m of progress: remove the edge, replan; twice: fail")
    block_check_distance: float = Field(4.0, gt=0, description="m of the path ahead checked against new obstacles")
    block_clearance: float = Field(0.05, ge=0, description="m beyond the robot radius; nearer new obstacles block the path")
    replan_before_end: float = Field(1.5, gt=0, description="m: replan when the local path ends this close ahead")


@dataclass
class Hypothesis:
    tracker: GraphMaintainer
    support: int  # looks that verified it
    odometer_start: float  # the robot's odometer when it was found
    misses: int = 0
    places: set[int] = field(default_factory=set)  # the locations it was verified in

    @property
    def vertex(self) -> int:
        assert self.tracker.current is not None
        return self.tracker.current

    @property
    def pose(self) -> NDArray[np.float64]:
        return self.tracker.pose_in_current


@dataclass
class Localization:
    """A start-up localization as the runner checks it against the truth afterwards (the vertex is
    named by its creation stamp, the one identifier the runner knows it by)."""

    started: float
    stamp: float
    vertex_stamp: float
    pose: NDArray[np.float64]
    looks: int
    hypotheses: int

    def as_json(self) -> dict:
        return {
            "started": self.started,
            "stamp": self.stamp,
            "seconds": round(self.stamp - self.started, 3),
            "vertex_stamp": self.vertex_stamp,
            "pose": [float(v) for v in self.pose],
            "looks": self.looks,
            "hypotheses": self.hypotheses,
        }


def goal_in_graph(
    graph: TopologicalGraph, goal_xy: NDArray, grid_config: GridConfig, poses: NDArray | None = None
) -> tuple[int, NDArray[np.float64]]:
    """A map-frame goal (2,) as ``(v_goal, T_goal)``: among the vertices whose known free area holds
    the goal, the nearest; if none holds it, the nearest. ``poses`` (V, 3): the vertices' poses in
    the map frame (``navtopo.graph_poses.relaxed_poses``; default: their odometry hints)."""
    goal_xy = np.asarray(goal_xy, dtype=np.float64)[:2]
    if poses is None:
        poses = np.array([vertex.pose_hint for vertex in graph.vertices])
    best, best_free = None, None
    for v, vertex in enumerate(graph.vertices):
        local = transform_points(inverse(poses[v]), goal_xy[None])[0]
        distance = float(np.hypot(local[0], local[1]))
        row, col = xy_to_cell(local[None], grid_config)[0] - (vertex.grid.row0, vertex.grid.col0)
        cells = vertex.grid.cells
        free = 0 <= row < cells.shape[0] and 0 <= col < cells.shape[1] and cells[row, col] == FREE
        if best is None or distance < best[0]:
            best = (distance, v, local)
        if free and (best_free is None or distance < best_free[0]):
            best_free = (distance, v, local)
    chosen = best_free if best_free is not None else best
    assert chosen is not None, "an empty graph has no goal vertex"
    return chosen[1], chosen[2]


class Startup:
    """Hypotheses of where the robot starts, looked for and confirmed over motion."""

    def __init__(self, maintainer: GraphMaintainer, describe, config: StartupConfig) -> None:
        self.maintainer = maintainer
        self.describe = describe
        self.config = config
        self.reset()

    map_poses: NDArray[np.float64] | None = None  # (V, 3) the locations in the map frame (navtopo.graph_poses)

    def reset(self) -> None:
        self.hypotheses: list[Hypothesis] = []
        self.looks = 0
        self.started: float | None = None
        self._last_look_odom: NDArray[np.float64] | None = None
        self._odometer = 0.0
        self._last_odom: NDArray[np.float64] | None = None
        self._checked_at = -np.inf  # the odometer at the last look that verified every location
        self._perceived: tuple[float, PreparedGrid, NDArray[np.float32]] | None = None  # (stamp, query, descriptor)
        self.seen = 0
        self.checks = 0

    def _tracker(self, vertex: int, pose: NDArray, odom: NDArray) -> GraphMaintainer:
        m = self.maintainer
        tracker = GraphMaintainer(m.graph, m.describe, m.grid_config, m.matching, m.config, m.localizer.config, False, m.grids)
        tracker.start_at(vertex, pose, odom)
        return tracker

    def _due(self, odom: NDArray) -> bool:
        if self._last_look_odom is None:
            return True
        delta = between(self._last_look_odom, odom)
        cfg = self.maintainer.config
        return bool(np.hypot(delta[0], delta[1]) >= cfg.update_distance or abs(delta[2]) >= np.radians(cfg.update_angle_deg))

    def step(
        self, obs: Observation, driven: Hypothesis | None = None, route: list[int] | None = None, force: bool = False
    ) -> Hypothesis | None:
        """One tick: track the hypotheses, look when due (or ``force``); the committed hypothesis, or
        None. ``driven``: the hypothesis the robot drives by, which follows ``route`` (its global
        path) from location to location as the committed state would."""
        if self.started is None:
            self.started = obs.stamp
        if self._last_odom is not None:
            delta = between(self._last_odom, obs.odom)
            self._odometer += float(np.hypot(delta[0], delta[1]))
        self._last_odom = np.asarray(obs.odom, dtype=np.float64).copy()
        for h in self.hypotheses:
            h.tracker.integrate(obs.odom)
        if not (force or self._due(obs.odom)):
            return None
        self._last_look_odom = np.asarray(obs.odom, dtype=np.float64).copy()
        self.looks += 1
        self._look(obs, driven, route)
        committed = self._committed()
        if committed is not None and self.config.check_all and self._odometer > self._checked_at:
            # place recognition may rank the right location low (a look-alike ranked above it, 29 m
            # away, committed on a loop scene): no commitment while another place verifies too
            if self._recognise(obs, check_all=True):
                return None
        return committed

    def _look(self, obs: Observation, driven: Hypothesis | None, route: list[int] | None) -> None:
        # the live hypotheses, each checked where it says the robot is; among rivals, by the
        # thresholds without a guess (a look-alike matches a guess well enough, not as well as
        # the right place does)
        rivals = len(self.hypotheses) > 1
        for h in self.hypotheses:
            h.tracker.localizer.strict = rivals
            h.tracker.update(obs.points, obs.odom, obs.stamp, route=route if h is driven else None, force=True, localize=False)
            if h.tracker.last_verified:
                h.support, h.misses = h.support + 1, 0
                h.places.add(h.vertex)
            else:
                h.misses += 1
        self.hypotheses = [h for h in self.hypotheses if h.misses < self.config.drop_after]
        check_all = self.config.check_all and not self.hypotheses and self._odometer >= self._checked_at + 1.0
        self._recognise(obs, check_all)

    def _recognise(self, obs: Observation, check_all: bool) -> int:
        """New hypotheses from place recognition's ``top_k`` (or every location), verified by scan
        matching; how many were added."""
        m = self.maintainer
        if self._perceived is None or self._perceived[0] != obs.stamp:  # once a look, though asked twice
            query = prepare(grid_from_points(obs.points, m.grid_config), m.grid_config, m.matching)
            self._perceived = (obs.stamp, query, self.describe(obs.points))
        _, query, descriptor = self._perceived
        if check_all:
            self._checked_at = self._odometer
            self.checks += 1
        top_k = len(m.graph) if check_all else self.config.top_k
        found = m.localizer.localize(query, descriptor, top_k=top_k)
        added = 0
        for located in found:
            if not any(self._same_place(h, located.vertex, located.pose) for h in self.hypotheses):
                tracker = self._tracker(located.vertex, located.pose, obs.odom)
                self.hypotheses.append(Hypothesis(tracker, support=1, odometer_start=self._odometer, places={located.vertex}))
                self.seen += 1
                added += 1
        return added

    def _same_place(self, h: Hypothesis, vertex: int, pose: NDArray) -> bool:
        """Does (vertex, pose) put the robot where ``h`` does? Compared through the graph, or, for
        locations the graph does not join closely (a place mapped twice), through their map poses."""
        graph = self.maintainer.graph
        if vertex == h.vertex:
            relative = np.zeros(3)
        else:
            path, length = graph.shortest_path(h.vertex, vertex)
            if path is None or length > 4 * self.maintainer.config.max_edge_length:
                if self.map_poses is None:
                    return False
                here = compose(self.map_poses[h.vertex], h.pose)
                there = compose(self.map_poses[vertex], pose)
                return float(np.hypot(*(here[:2] - there[:2]))) <= self.config.same_place_in_map
            relative = graph.path_pose(path)  # vertex in h.vertex's frame
        predicted = compose(relative, pose)  # the robot in h.vertex's frame, by the candidate
        return float(np.hypot(*(predicted[:2] - h.pose[:2]))) <= self.config.same_place

    def _committed(self) -> Hypothesis | None:
        if len(self.hypotheses) != 1:
            return None
        h = self.hypotheses[0]
        moved = self._odometer - h.odometer_start
        if h.support < self.config.confirm_looks or moved < self.config.confirm_distance:
            return None
        # a room and its mirror image agree from inside; the corridor outside the door tells them apart
        if len(h.places) >= self.config.confirm_places or moved >= self.config.confirm_distance_one_place:
            return h
        return None

    @property
    def odometer(self) -> float:
        """Metres of odometry since the start-up began."""
        return self._odometer

    def best(self) -> Hypothesis | None:
        """The hypothesis to drive by while none is committed: most supported."""
        return max(self.hypotheses, key=lambda h: h.support, default=None)


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
    _explore: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None  # (odom at start, path in that frame)
    _tentative: Hypothesis | None = None
    _explore_until: float = 0.0  # the startup odometer reading where the current exploring move ends
    _progress_mark: tuple[float, float] | None = None  # (stamp, startup odometer) of the last progress
    _trail: list[NDArray[np.float64]] = field(default_factory=list)  # start-up: where the robot drove (odometry frame)

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
        self._explore = None
        self._tentative = None
        self._explore_until = 0.0
        self._trail = []
        self._progress_mark = None

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
        return self._drive(obs, self.maintainer.current, self.maintainer.pose_in_current)

    def _step_unlocalized(self, obs: Observation) -> Command:
        startup = self.startup
        here = np.asarray(obs.odom, dtype=np.float64)[:2].copy()
        if not self._trail or np.hypot(*(here - self._trail[-1])) >= 0.25:
            self._trail.append(here)
        driven = self._tentative if self._tentative in startup.hypotheses else None
        committed = startup.step(obs, driven, self._route if driven is not None else None, force=self._at_path_end())
        if committed is not None:
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
        if startup.started is not None and obs.stamp - startup.started > startup.config.timeout:
            self.status = NavStatus(Status.FAILED, "not_localized")
            return Command()
        best = startup.best()
        odometer = startup.odometer
        if self._explore is not None and odometer < self._explore_until and not self.follower.reached:
            return self._explore_step(obs)  # an exploring move runs to its end
        if best is not None and not self._no_progress(obs.stamp, odometer):
            # drive as the best hypothesis sees it: confirmation on the way
            if best is not self._tentative or self._explore is not None:
                self._tentative, self._path_vertex, self._route, self._explore = best, None, None, None
            return self._drive(obs, best.vertex, best.pose, tentative=True)
        # no hypothesis, or driving by the best one gets nowhere (it may be the wrong one, or two
        # places look alike from here): move toward open space for a new view
        self._tentative = None
        if self._explore is None or odometer >= self._explore_until or self.follower.reached:
            self._explore = None
            self._explore_until = odometer + startup.config.explore_distance
            self._progress_mark = (obs.stamp, odometer)
        return self._explore_step(obs)

    def _no_progress(self, stamp: float, odometer: float) -> bool:
        """While not localized: less than 0.3 m of motion in the last 5 s."""
        if self._progress_mark is None or odometer - self._progress_mark[1] >= 0.3:
            self._progress_mark = (stamp, odometer)
            return False
        return stamp - self._progress_mark[0] > 5.0

    def _explore_step(self, obs: Observation) -> Command:
        """No hypothesis: drive toward the most open direction of the robot's own scan. The way ahead
        is checked against every new scan: a path planned through cells the first scan did not see
        (a wall seen edge-on from a doorway) is given up at the first scan that shows a wall on it."""
        if self._explore is not None and len(self._scan_on_path(obs, between(self._explore[0], obs.odom))):
            self._explore = None
            self.follower.clear()
            self.counters["explore_blocked"] += 1
        if self._explore is None or self.follower.reached or not self.follower.has_path:
            path = self._open_space_path(obs)
            if path is None:
                return Command(0.0, self.follower.config.max_angular / 2)
            self._explore = (np.asarray(obs.odom, dtype=np.float64).copy(), path)
            self.follower.set_path(path)
            self.counters["explore_moves"] += 1
        start_odom, _ = self._explore
        return self.follower.command(between(start_odom, obs.odom))

    def _scan_on_path(self, obs: Observation, pose: NDArray) -> NDArray[np.float64]:
        """The scan's obstacle returns (in the path's frame, the robot at ``pose`` there) within the
        robot's radius of the path ahead: the robot would touch them."""
        if not self.follower.has_path:
            return np.zeros((0, 2))
        ahead = np.vstack([pose[None, :2], self.follower.path_ahead(self.config.block_check_distance)])
        points = np.asarray(obstacle_points(obs.points, self.maintainer.grid_config)[:, :2], dtype=np.float64)
        # returns farther from the robot than the way ahead reaches (plus the radius) cannot touch it
        reach = float(np.hypot(*(ahead - pose[:2]).T).max()) + self.robot_radius
        xy = transform_points(pose, points[np.hypot(points[:, 0], points[:, 1]) <= reach])
        return xy[distance_to_polyline(xy, ahead) < self.robot_radius]

    def _open_space_path(self, obs: Observation) -> NDArray[np.float64] | None:
        """A path in the robot's own scan to new ground: of the free points ``explore_distance`` (or
        twice, or half that) away, the one farthest from where the start-up has already driven (the
        way out of a room leads through its door, not round the room again), forward first on ties."""
        grid_config = self.maintainer.grid_config
        grid = grid_from_points(obs.points, grid_config)
        frame = GridFrame(np.array([-grid_config.radius, -grid_config.radius]), grid_config.resolution)
        # the local planner's fallbacks: with its margin, then the robot's radius alone (a narrow
        # door); in the scan's free space, then between the walls it saw (a door seen at a slant
        # leaves little free space); the ends in free space it saw
        masks = [
            inflate_free(space, radius, frame.resolution)
            for radius in (self.local.wide, self.local.tight)
            for space in (grid == FREE, grid != OCCUPIED)
        ]
        passable = masks[-1] & (grid == FREE)
        angles = np.radians(np.arange(0.0, 360.0, 15.0))
        reach = self.startup.config.explore_distance
        directions = np.stack([np.cos(angles), np.sin(angles)], axis=1)
        ends = np.vstack([directions * reach * scale for scale in (2.0, 1.0, 0.5)])
        cells = frame.to_cell(ends)
        inside = np.all((cells >= 0) & (cells < passable.shape), axis=1)
        ok = np.flatnonzero(inside)[passable[cells[inside, 0], cells[inside, 1]]]
        if not len(ok):
            return None
        trail = np.array(self._trail) if self._trail else np.zeros((0, 2))
        odom = np.asarray(obs.odom, dtype=np.float64)
        in_odom = transform_points(odom, ends[ok])
        novelty = (
            np.min(np.hypot(*(in_odom[:, None, :] - trail[None, :, :]).transpose(2, 0, 1)), axis=1)
            if len(trail)
            else np.zeros(len(ok))
        )
        forward = np.cos(np.tile(angles, 3))[ok]
        order = np.lexsort((-forward, -np.round(novelty / 0.5)))  # novelty in 0.5 m steps, then forward
        for k in ok[order][:8]:
            planned = plan_path(masks, frame, np.zeros(2), ends[k], snap_cells=5)
            if planned is not None:
                return planned.points
        return None

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
            hits = self._scan_on_path(obs, pose)
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
