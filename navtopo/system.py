"""NavTopo: the NavigationSystem of this package (Muravyev & Yakovlev, Sec. "System Overview").

``NavTopo`` composes the parts and owns no algorithm itself: the graph maintainer (mapping and
tracking the robot in the graph, ``navtopo.mapping``), the localizer (``navtopo.localization``),
the place-recognition descriptor (``navtopo.place_recognition``) and the shared follower.
Mapping builds the graph from scans and odometry alone; ``save`` writes the graph folder with
the resolved config; ``load`` restores it for navigation.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict

from navtopo.follower import FollowerConfig
from navtopo.graph import TopologicalGraph
from navtopo.local_grid import GridConfig
from navtopo.localization import LocalizationConfig
from navtopo.mapping import GraphMaintainer, MappingConfig
from navtopo.place_recognition import make_descriptor
from navtopo.scan_matching import MatchingConfig
from navtopo.types import Command, NavStatus, Observation, Status


class NavTopoConfig(BaseModel):
    """Every parameter of NavTopo; the defaults reproduce the paper's setup."""

    model_config = ConfigDict(extra="forbid")

    descriptor: str = "minkloc3d"  # the paper's place recognition; also polar_bev, scan_context
    grid: GridConfig = GridConfig()
    matching: MatchingConfig = MatchingConfig()
    localization: LocalizationConfig = LocalizationConfig()
    mapping: MappingConfig = MappingConfig()
    follower: FollowerConfig = FollowerConfig()


class NavTopo:
    """Topological navigation on a graph of locations (PRISM-TopoMap mapping)."""

    def __init__(self, config: NavTopoConfig, graph: TopologicalGraph | None = None, mapping: bool = True) -> None:
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
        self.status = NavStatus()
        self.planning_ms: list[float] = []
        self.update_ms: list[float] = []

    @staticmethod
    def warm_up() -> None:
        """Load the compiled kernels (grids, matching, planning) before anything is timed."""
        from navtopo.grid_search import theta_star
        from navtopo.local_grid import grid_from_points
        from navtopo.scan_matching import match

        angles = np.linspace(0, 2 * np.pi, 360, endpoint=False)
        ring = np.stack([4 * np.cos(angles), 3 * np.sin(angles), np.full(360, 1.0)], 1).astype(np.float32)
        grid = grid_from_points(ring)
        match(grid, grid, initial_guess=np.zeros(3))
        theta_star(np.ones((8, 8), bool), (0, 0), (7, 7))

    # -- mapping -----------------------------------------------------------------------------------

    @classmethod
    def create(cls, config: NavTopoConfig, context: Any = None) -> NavTopo:
        return cls(config)

    def observe(self, obs: Observation) -> None:
        self.maintainer.update(obs.points, obs.odom, obs.stamp)

    def finish_mapping(self) -> None:
        pass

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
        return cls(config, graph, mapping=False)

    def mapping_stats(self) -> dict[str, Any]:
        counters = self.maintainer.counters
        stamps = [v.stamp for v in self.graph.vertices]
        return {
            "map_bytes": self.graph.nbytes,
            "vertices": len(self.graph),
            "edges": self.graph.edge_count,
            "descriptor": self.config.descriptor,
            "counters": {k: v for k, v in vars(counters).items() if k != "reasons"},
            "vertex_stamps": stamps,
            "edges_stamped": [(stamps[u], stamps[v], [float(x) for x in pose]) for u, v, pose in self.graph.edges()],
        }

    # -- navigation --------------------------------------------------------------------------------

    def set_goal(self, goal: NDArray[np.float64]) -> None:
        self.status = NavStatus()
        self.planning_ms = []
        self.goal = np.asarray(goal, dtype=np.float64)

    def step(self, obs: Observation) -> Command:
        t0 = time.perf_counter()
        self.maintainer.update(obs.points, obs.odom, obs.stamp)
        self.update_ms.append((time.perf_counter() - t0) * 1e3)
        # Two-level planning and goal serving are the next milestone (DESIGN.md: planning.py);
        # until then a trial ends at once with this reason rather than with a made-up path.
        self.status = NavStatus(Status.FAILED, "navigation_not_implemented")
        return Command()

    def stats(self) -> dict[str, Any]:
        return {"planning_ms": list(self.planning_ms), "map_bytes": self.graph.nbytes}

    def pose_estimate(self) -> NDArray[np.float64] | None:
        return None
