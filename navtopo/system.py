"""NavTopo: the NavigationSystem of this package (Muravyev & Yakovlev, Sec. "System Overview").

``NavTopo`` composes the parts and owns no algorithm itself: the graph maintainer (mapping and
tracking the robot in the graph, ``navtopo.mapping``), the localizer (``navtopo.localization``),
the place-recognition descriptor (``navtopo.place_recognition``), the two-level planner
(``navtopo.planning``), the start-up localization and its exploring moves (``navtopo.startup``),
the goal server and stepping (``navtopo.navigation``) and the shared follower. Mapping builds the
graph from scans and odometry alone; ``save`` writes the graph folder with the resolved config;
``load`` restores it for navigation.

Memory (``memory()``, the runner's breakdown): ``map`` is the graph as stored (location grids,
odometry hints, stamps, edges); ``localization`` the descriptors and the prepared grids of the
matching cache; ``derived`` the union grids of the planning cache and the global planner's arrays;
``model`` the descriptor network's weights.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, field_validator

from navkit.explore import Explorer
from navkit.follower import FollowerConfig, PathFollower
from navkit.odometry import LidarOdometry, OdometryConfig
from navkit.scan_grid import GridConfig
from navkit.types import Command, MemoryBreakdown, NavStatus, Observation
from navtopo.graph import TopologicalGraph
from navtopo.graph_poses import hint_chain, relaxed_poses
from navtopo.localization import LocalizationConfig
from navtopo.mapping import GraphMaintainer, MappingConfig
from navtopo.navigation import NavigationConfig, Navigator
from navtopo.place_recognition import available_descriptors, default_weights_path, make_descriptor
from navtopo.planning import GlobalPlanner, LocalPlanner, PlanningConfig, UnionGrids
from navtopo.scan_matching import MatchingConfig
from navtopo.startup import Startup, StartupConfig


class NavTopoConfig(BaseModel):
    """Every parameter of NavTopo; the defaults reproduce the paper's setup."""

    model_config = ConfigDict(extra="forbid")

    descriptor: str = "minkloc3d"  # the paper's place recognition; also polar_bev, scan_context
    grid: GridConfig = GridConfig()
    matching: MatchingConfig = MatchingConfig()
    localization: LocalizationConfig = LocalizationConfig()
    mapping: MappingConfig = MappingConfig()
    planning: PlanningConfig = PlanningConfig()
    startup: StartupConfig = StartupConfig()
    navigation: NavigationConfig = NavigationConfig()
    follower: FollowerConfig = FollowerConfig()
    # while mapping, a lidar odometry (KISS-ICP on the same scans, seeded by the odometry) runs
    # alongside and each location keeps its pose there too: used only to place the locations in the
    # map frame for map-frame goals (navtopo.graph_poses), never to navigate. ~10-13 ms of CPU a scan
    # (kiss-icp and its point-to-line refinement).
    lidar_hints: bool = True
    lidar_odometry: OdometryConfig = OdometryConfig(source="lidar")

    @field_validator("descriptor")
    @classmethod
    def _registered(cls, name: str) -> str:
        # refused with the config, before a run folder exists, not when mapping starts
        if name not in available_descriptors():
            raise ValueError(f"unknown place descriptor {name!r} (available: {', '.join(available_descriptors())})")
        return name


class NavTopo:
    """Topological navigation on a graph of locations (PRISM-TopoMap mapping, two-level planning)."""

    def __init__(
        self, config: NavTopoConfig, graph: TopologicalGraph | None = None, mapping: bool = True, context: Any = None
    ) -> None:
        self.config = config
        self.descriptor = make_descriptor(config.descriptor)
        self.graph = graph if graph is not None else TopologicalGraph(self.descriptor.dim)
        if self.graph.descriptor_dim != self.descriptor.dim:
            raise ValueError(
                f"graph descriptors have {self.graph.descriptor_dim} dimensions, {config.descriptor} gives {self.descriptor.dim}"
            )
        self.maintainer = GraphMaintainer(
            self.graph,
            self.descriptor.embed,
            config.grid,
            config.matching,
            config.mapping,
            config.localization,
            mapping=mapping,
        )
        robot_radius = float(context.robot.radius) if context is not None else 0.3
        self.unions = UnionGrids(self.graph, config.grid, config.planning)
        local = LocalPlanner(self.unions, robot_radius, config.planning)
        follower = PathFollower(config.follower.for_robot(context))
        self.navigator = Navigator(
            graph=self.graph,
            maintainer=self.maintainer,
            startup=Startup(self.maintainer, self.descriptor.embed, config.startup),
            explorer=Explorer(
                follower,
                config.grid,
                config.startup.explore_distance,
                robot_radius,
                (local.wide, local.tight),
                config.navigation.block_check_distance,
            ),
            global_planner=GlobalPlanner(self.graph),
            local=local,
            unions=self.unions,
            follower=follower,
            config=config.navigation,
            robot_radius=robot_radius,
        )
        self.navigator.reset()
        self.update_ms: list[float] = []
        self._lidar: LidarOdometry | None = None  # while mapping with lidar_hints

    @staticmethod
    def warm_up() -> None:
        """Load the compiled kernels (grids, matching, planning) before anything is timed."""
        from navkit.grid_search import SEARCHES, far_from, inflate_free, nearest_free, without_disks
        from navkit.scan_grid import grid_from_points
        from navtopo.scan_matching import match

        angles = np.linspace(0, 2 * np.pi, 360, endpoint=False)
        ring = np.stack([4 * np.cos(angles), 3 * np.sin(angles), np.full(360, 1.0)], 1).astype(np.float32)
        grid = grid_from_points(ring)
        match(grid, grid, initial_guess=np.zeros(3))
        free = inflate_free(np.ones((8, 8), bool), 0.1, 0.1)
        nearest_free(free, (0, 0), 2)
        for search in SEARCHES.values():  # whichever ``planning.search`` a run's config names
            search(free, (0, 0), (7, 7))
        far_from(~free, np.array([[1, 1]]), 0.2, 0.1, True)
        without_disks(free, np.array([[1, 1]]), 0.2, 0.1)

    @property
    def status(self) -> NavStatus:
        return self.navigator.status

    # -- mapping -----------------------------------------------------------------------------------

    @classmethod
    def create(cls, config: NavTopoConfig, context: Any = None) -> NavTopo:
        return cls(config, context=context)

    def observe(self, obs: Observation) -> None:
        made = len(self.graph)
        self.maintainer.update(obs.points, obs.odom, obs.stamp)
        if self.config.lidar_hints:
            if self._lidar is None:
                self._lidar = LidarOdometry(self.config.lidar_odometry)
            pose = self._lidar.update(obs.points, obs.odom)
            for vertex in self.graph.vertices[made:]:  # made from this scan
                vertex.lidar_hint = pose.copy()

    def finish_mapping(self) -> None:
        # shortcuts where the local planner finds a way; every edge's length as it would drive it
        # (Dijkstra's weights)
        self.maintainer.add_shortcuts(self.navigator.local.way_between)
        self.maintainer.measure_edges(self.navigator.local.way_between)

    def save(self, directory: Path) -> None:
        self.graph.save(Path(directory), extra={"navtopo_config": self.config.model_dump(mode="json")})

    @classmethod
    def load(cls, directory: Path, config: NavTopoConfig, context: Any = None) -> NavTopo:
        graph, extra = TopologicalGraph.load(Path(directory))
        saved = extra.get("navtopo_config", {})
        if saved.get("descriptor") not in (None, config.descriptor):
            raise ValueError(
                f"{directory}: the graph was built with descriptor {saved.get('descriptor')!r}, not {config.descriptor!r}"
            )
        system = cls(config, graph, mapping=False, context=context)
        system.navigator.map_poses = relaxed_poses(graph)  # for map-frame goals: part of loading
        for vertex in graph.vertices:  # each location's wall direction, which union grids turn to
            vertex.grid.wall_axis  # noqa: B018 - made here, as loading
        system.navigator.startup.map_poses = system.navigator.map_poses
        return system

    def mapping_stats(self) -> dict[str, Any]:
        counters = self.maintainer.counters
        stamps = [v.stamp for v in self.graph.vertices]
        return {
            "map_bytes": self.memory().map,
            "vertices": len(self.graph),
            "edges": self.graph.edge_count,
            "descriptor": self.config.descriptor,
            "counters": {k: v for k, v in vars(counters).items() if k != "reasons"},
            "vertex_stamps": stamps,
            "edges_stamped": [(stamps[u], stamps[v], [float(x) for x in pose]) for u, v, pose in self.graph.edges()],
            "map_frame_hints": hint_chain(self.graph)[0],
            # each loop closure checked against the graph's way round: [stamp_u, stamp_v, squared
            # Mahalanobis distance, accepted]
            "closure_checks": [
                [stamps[u], stamps[v], distance, accepted] for u, v, distance, accepted in self.maintainer.closure_checks
            ],
            # every new edge checked against the graph's way between its ends (mapping.EdgeCheck)
            "edge_checks": [
                {
                    "stamps": [stamps[check.u], stamps[check.v]],
                    "pose": [round(x, 4) for x in check.pose],
                    "way": check.way,
                    "composed": [round(x, 4) for x in check.composed],
                    "distance": round(check.distance, 3),
                    "hint_offset": None if check.hint_offset is None else round(check.hint_offset, 4),
                    "verdict": check.verdict,
                }
                for check in self.maintainer.edge_checks
            ],
        }

    # -- navigation --------------------------------------------------------------------------------

    def reset(self) -> None:
        """Forget the previous trial: no location, no pose, no goal, no removed edge."""
        self.navigator.reset()
        self.update_ms = []

    def set_initial_pose(self, pose: NDArray[np.float64]) -> None:
        """A given start pose (3,, map frame; the protocol's ``perturbed`` start, off by its error): the
        start-up's prior (``Startup.from_prior``), not taken as true."""
        self.navigator.startup.set_prior(np.asarray(pose, dtype=np.float64))

    def set_goal(self, goal: NDArray[np.float64]) -> None:
        """A map-frame goal (2,), turned into ``(v_goal, T_goal)`` with the vertices' odometry hints."""
        self.navigator.set_goal(np.asarray(goal, dtype=np.float64))

    def set_goal_in_graph(self, vertex: int, pose_in_vertex: NDArray[np.float64]) -> None:
        """The paper's goal form: the goal's vertex and its position (2,) in that vertex's frame."""
        self.navigator.set_goal_in_graph(vertex, pose_in_vertex)

    def set_goal_anchored(self, vertex_stamp: float, point_in_vertex: NDArray[np.float64]) -> None:
        """The paper's goal form, the location named by its creation stamp (as the runner knows it)."""
        stamps = np.array([v.stamp for v in self.graph.vertices])
        vertex = int(np.argmin(np.abs(stamps - float(vertex_stamp))))
        if abs(stamps[vertex] - float(vertex_stamp)) > 1e-6:
            raise ValueError(f"no location was made at stamp {vertex_stamp}")
        self.set_goal_in_graph(vertex, point_in_vertex)

    def step(self, obs: Observation) -> Command:
        t0 = time.perf_counter()
        command = self.navigator.step(obs)
        self.update_ms.append((time.perf_counter() - t0) * 1e3)
        return command

    def stats(self) -> dict[str, Any]:
        nav = self.navigator
        goal = None
        if nav.goal is not None:
            goal = {"vertex_stamp": self.graph.vertices[nav.goal.vertex].stamp, "pose": [float(v) for v in nav.goal.pose]}
        counters = {k: v for k, v in vars(self.maintainer.counters).items() if k != "reasons"}
        return {
            "planning_ms": list(nav.planning_ms),
            "first_plan_ms": nav.first_plan_ms,
            "startup_planning_ms": list(nav.startup_planning_ms),
            "map_bytes": self.memory().map,
            "counters": {**counters, **nav.counters},
            "localizations": [loc.as_json() for loc in nav.localizations],
            "goal": goal,
        }

    def memory(self) -> MemoryBreakdown:
        descriptors = int(self.graph.descriptors.nbytes)
        return MemoryBreakdown(
            map=self.graph.nbytes - descriptors,
            localization=descriptors + self.maintainer.grids.nbytes,
            derived=self.unions.nbytes
            + self.navigator.global_planner.nbytes
            + self._map_poses_nbytes
            + self.navigator.obstacles.nbytes,
            model=int(self.descriptor.nbytes),
        )

    @property
    def _map_poses_nbytes(self) -> int:
        poses = self.navigator.map_poses
        return int(poses.nbytes) if poses is not None else 0

    @staticmethod
    def disk_usage(directory: Path) -> dict[str, int]:
        """The saved graph's bytes per memory part; the model is the shipped weights file it loads."""
        directory = Path(directory)
        descriptors = directory / "descriptors.npy"
        grids = sum(p.stat().st_size for p in (directory / "grids").glob("*") if p.is_file())
        index = directory / "graph.json"
        model = 0
        try:
            name = json.loads(index.read_text()).get("navtopo_config", {}).get("descriptor")
            weights = default_weights_path(name) if name else None
            model = weights.stat().st_size if weights is not None and weights.is_file() else 0
        except (OSError, ValueError, KeyError):
            pass
        return {
            "map": grids + (index.stat().st_size if index.is_file() else 0),
            "localization": descriptors.stat().st_size if descriptors.is_file() else 0,
            "model": model,
        }

    def anchored_pose(self) -> tuple[float, NDArray[np.float64]] | None:
        """(creation stamp of the current location, the pose in it): what the runner compares with the truth."""
        if not self.navigator.localized or self.maintainer.current is None:
            return None
        return self.graph.vertices[self.maintainer.current].stamp, self.maintainer.pose_in_current.copy()

    def pose_estimate(self) -> NDArray[np.float64] | None:
        return None  # NavTopo has no map frame: its pose is relative to a location (anchored_pose)
