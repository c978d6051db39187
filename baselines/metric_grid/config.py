"""Every parameter of the metric baseline (DESIGN.md), as small models nested in one config.

``MetricGridConfig`` nests one model per part: the odometry (``navkit.odometry``), the pose graph
(``pose_graph``), the global grid (``occupancy``), the obstacle band of a scan (``ScanConfig``), the
scan-to-map tracking and the relocalization (``localization``), the planner on the global grid
(``PlanningConfig``) and the shared follower. Its field names and nesting are what a run stores
(``model_dump``) and what users override, so they stay as they are.

The values that follow the robot and its sensor (the odometry's and the grid's range, the
follower's speed limits and stop tolerance) are filled in one place, ``for_context``; the
overrides a benchmark setting applies are ``SETTING_OVERRIDES``.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from navkit.follower import FollowerConfig
from navkit.odometry import OdometryConfig
from navkit.passages import PassageConfig
from navkit.scan import CEILING_HEIGHT, FLOOR_HEIGHT

from .localization import RelocalizationConfig, ScanToMapConfig
from .occupancy import OccupancyConfig
from .pose_graph import PoseGraphConfig


class ScanConfig(BaseModel):
    """The height band whose returns are obstacles: the shared rule (``navkit.scan``)."""

    model_config = ConfigDict(extra="forbid")

    floor_height: float = Field(FLOOR_HEIGHT, description="m above the floor; lower returns are floor")
    ceiling_height: float = Field(CEILING_HEIGHT, description="m above the floor; higher returns are ceiling")


class PlanningConfig(BaseModel):
    """The search on the global grid, and when to plan again."""

    model_config = ConfigDict(extra="forbid")

    search: Literal["astar", "jps", "theta_star"] = Field(
        "jps",
        description="jps: jump point search (A*'s shortest 8-connected path, only jump points on the open list) "
        "string-pulled from both ends and refined (navkit.grid_search.jps_smoothed); astar: the same with A*; "
        "theta_star: Lazy Theta*, shortcut and refined. Chosen by measurement (benchmarks/bench_metric_search.py, "
        "generated and real maps): jps 2x faster than astar, which is up to 2x faster than Theta*, paths within "
        "0.1 % of Theta*'s in total",
    )
    goal_field: bool = Field(
        True,
        description="from the second plan to a goal on, descend a field rooted at it (navkit.grid_search.goal_field: "
        "one whole-map Dijkstra per goal, 16 bits a cell kept while the goal lasts) instead of searching, round new "
        "obstacles through the remade mask, searched where that meets a dead end. Replans 4x faster on corridor_150m "
        "(benchmarks/bench_planners.py), for 2 bytes a cell of memory: the baseline made as fast as it can be where "
        "NavTopo's advantage is claimed",
    )

    inflation_margin: float = Field(
        0.1,
        ge=0,
        description="m beyond the robot radius (and half a cell, so the clearance holds to the cell boundary) "
        "that paths keep from mapped walls; the follower deviates a little at corners",
    )
    unknown_fallback: bool = Field(True, description="with no path through known free cells, count unknown as free")
    medial_passages: bool = Field(
        True,
        description="when no path keeps the robot radius plus half a cell from every wall cell, a passage along "
        "the free space's medial axis at the robot radius from the wall cells' centres (a door of the robot's width)",
    )
    keep_clear: float = Field(
        0.2,
        ge=0,
        description="m beyond the first level's clearance that a path is eased off mapped walls where the free space "
        "allows (navkit.grid_planning.ease_path, as a Nav2 inflation cost keeps paths off walls; 0: the shortest path)",
    )
    keep_clear_horizon: float = Field(
        10.0,
        gt=0,
        description="m: only the first so many metres of a path are eased (the robot plans again every replan_period "
        "and drives the near part; easing a whole 100 m path cost 2-5x the search on corridor_150m)",
    )
    snap_radius: float = Field(1.0, ge=0, description="m; a start or goal in the inflated zone moves to the nearest free cell")
    passages: PassageConfig = Field(
        default_factory=PassageConfig,
        description="where a path passes with less than the first level's clearance and a cell more (a door near "
        "the robot's width, as the map draws it) it is checked against the scan as the robot nears it: moved to "
        "the returns' middle, or shut if the robot does not fit (navkit.passages, as NavTopo's; check_range 0: "
        "never). The map's cells and the pose on the map are each a few centimetres off, where such a door leaves "
        "ten a side",
    )
    replan_period: float = Field(2.0, gt=0, description="s of simulated time between replans")
    block_check_distance: float = Field(5.0, gt=0, description="m of the path ahead checked against new obstacles")
    block_clearance: float = Field(0.05, ge=0, description="m beyond the robot radius; nearer new obstacles block")
    new_obstacle_distance: float = Field(0.25, gt=0, description="m from every mapped wall: an obstacle the map lacks")
    scan_guard: bool = Field(
        True, description="stop a path the scan shows touching a return and plan again (navkit.obstacles.scan_guard)"
    )
    new_obstacle_range: float = Field(
        10.0, gt=0, description="m; only nearer returns can be new obstacles (NavTopo's range, docs/DESIGN.md)"
    )
    progress_distance: float = Field(
        0.5, gt=0, description="m of odometry the robot must cover every progress_time (Nav2's progress checker)"
    )
    progress_time: float = Field(10.0, gt=0, description="s of simulated time; no progress_distance in it: recover")
    recoveries: int = Field(
        3,
        ge=0,
        description="recoveries per goal (Nav2's behaviour tree: clear the costmap, plan again), on no progress or on no "
        "path while obstacles are remembered; past them the goal fails",
    )


#: Overrides for the benchmark's noisy setting (wheel odometry with 2 % and 0.5°/m random walks,
#: lidar range noise 1 cm), chosen on generated scenes (benchmarks/tune_metric_mapping.py, trees
#: seeds 101-103 and a ring building; BENCHMARKS.md, "Design choices: the metric baseline's odometry
#: source and odometry-factor sigmas"): noisy wheels fail on every generated scene (wall recall
#: 0.33-0.85, the map turned up to 2.5°), so kiss-icp seeded by the wheels; of the
#: odometry-factor sigmas tried, yaw 0.1° + 0.1°/m with the default xy sigmas had the best worst case
#: over the four noisy scenes (trees 0.969 mean / 0.919 worst, ring 0.904 wall recall). Since
#: ``959fe02`` the lidar odometry refines kiss-icp point-to-line (``navkit.odometry``), for both
#: systems: on the same trees wall recall 0.991 mean / 0.986 worst, ATE 0.086 -> 0.021 m mean
#: (BENCHMARKS.md, "Design choices: point-to-line lidar odometry").
NOISY_ODOMETRY: dict[str, Any] = {
    "odometry": {"source": "lidar"},
    "pose_graph": {"odometry_sigma_yaw_deg": 0.1, "odometry_sigma_yaw_deg_per_m": 0.1},
}

#: Overrides for the benchmark's precise setting (exact wheel odometry): odometry factors as tight
#: as the odometry (0.002 m + 0.002/m, 0.02° + 0.02°/m), chosen on generated scenes
#: (benchmarks/tune_metric_mapping.py, candidate ``wheel-precise``; BENCHMARKS.md, "Design choices: the
#: metric baseline's precise recipe"). With the default factors (0.02 m + 0.02/m, 0.5° + 0.5°/m) the few
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

    * ``odometry.source: wheel``: with precise wheel odometry the keyframes get the true
      relative poses, the best map on every generated scene tried (BENCHMARKS.md, "Design
      choices: the metric baseline's odometry source and odometry-factor sigmas"); under the
      precise setting the runner also applies ``SETTING_OVERRIDES["precise"]``
      (``PRECISE_ODOMETRY``: odometry factors as tight as the odometry, so that loop closures
      cannot bend it). With noisy wheel odometry (2 %, 0.5°/m) the runner applies
      ``SETTING_OVERRIDES["noisy"]`` (``NOISY_ODOMETRY``: kiss-icp seeded by the wheels, tighter
      yaw factors, loop closures on top). The same odometry tracks the pose during navigation.
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


def for_context(config: MetricGridConfig, context: Any) -> MetricGridConfig:
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
