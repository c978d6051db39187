"""Graph maintenance (Muravyev & Yakovlev, Sec. "Graph Maintaining", after PRISM-TopoMap).

At every update the maintainer knows the current vertex ``current`` and the robot's pose in
it, ``pose_in_current``, integrated from odometry. Then, in the paper's order:

1. still inside the current location? (the robot is within ``max_edge_length`` of the
   location's centre, the known areas of the current grid and the location's overlap by at least
   ``min_overlap``, and the robot's cell is one the location saw — or, if it never saw it, scan
   matching against the location agrees) → keep it; scan matching against the location corrects
   ``pose_in_current`` when it agrees with odometry;
2. else move along an edge: navigating, the path's next vertex first (the paper's order; the
   nearest neighbour may be the vertex the path just came from, and switching back to it made the
   robot shuttle between two locations); then the neighbours nearer than the current centre, each
   verified by scan matching seeded with the pose the edge predicts;
3. else a verified localization result (top-k descriptors, scan matching seeded by the
   vertices' odometry hints and gated by the drift odometry can explain); an edge to it is added
   if it passes the checks below — a loop closure when the graph's way round is much longer;
4. else add a new location at the robot's pose, with an edge from the current one.

Mapping, inside a location, loops also close without leaving it (``_close_from_inside``): a
location passed alongside, near by odometry hint and joined only the long way round, gets an edge
once matches over motion agree on it.

Edges are measured again and again while mapping: each time one scan matches both ends (moving
along the edge, and inside a location with a neighbour's centre about as near as its own), and
the edge keeps the information-weighted mean of its measurements, each weighted by the
covariance the matcher reports (a match sharing few walls fixes the rotation poorly: a degree off
where the usual error is a tenth, BENCHMARKS.md, "Design choices: edge measurements"). The first
measurement is the pose in the location the new one was made from, as odometry carried it since its
last match.

Every new edge is checked first (the reference code did not): its length must be at most
``2 * max_edge_length``, and where the graph already joins its ends by a path that is not much
longer (no loop to close), the edge must agree with the pose composed along that path.
Relative poses follow ``navkit.geometry``: an edge (u, v, T_uv) holds v's observation point in
u's frame. No ground truth enters: vertices live in their own frames and their odometry poses are
kept only as hints.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from navkit.geometry import (
    between,
    compose,
    compose_with_covariance,
    inverse_with_covariance,
    wrap_angle,
)
from navkit.odometer import Odometer
from navkit.raster import UNKNOWN
from navkit.scan_grid import GridConfig, grid_frame, grid_from_points
from navtopo.graph import TopologicalGraph
from navtopo.graph_poses import hint_chain, relaxed_poses
from navtopo.local_grid import CroppedGrid, overlap
from navtopo.localization import LocalizationConfig, Localized, Localizer, VertexGrids
from navtopo.scan_matching import MatchingConfig, MatchResult, PreparedGrid, prepare, refine, rival_minimum

# the way (m) a robot drives from location u's observation point to v's, v at the pose given in u's
# frame, or None: the navigator's local planner (``planning.LocalPlanner.way_between``)
WayBetween = Callable[[TopologicalGraph, int, int, NDArray[np.float64]], "float | None"]


class MappingConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    update_distance: float = Field(0.25, gt=0, description="the graph is updated after this much motion (m) ...")
    update_angle_deg: float = Field(15.0, gt=0, description="... or this much turning; odometry is integrated at every scan")
    min_overlap: float = Field(
        0.2, gt=0, le=1, description="still inside: shared known area over the smaller one (local_grid.overlap) at least this"
    )
    max_edge_length: float = Field(5.0, gt=0, description="still inside: at most this far from the location's centre (m)")
    max_neighbour_jump: float = Field(1.0, gt=0, description="a move along an edge may correct odometry by at most this (m)")
    max_correction: float = Field(0.5, gt=0, description="an in-location correction may move the pose by at most this (m)")
    correction_per_metre: float | None = Field(
        0.2,
        ge=0,
        description="a correction may move the pose by at most correction_base + this share of the odometry "
        "travelled since the last verified pose (and max_correction): a match that slides along a corridor is not "
        "drift (None: max_correction alone)",
    )
    correction_base: float = Field(0.05, ge=0, description="... plus this (m); see correction_per_metre")
    correction_turn_deg: float | None = Field(
        2.0,
        gt=0,
        description="a correction may turn the pose, together with the corrections taken in the last "
        "correction_turn_window metres of odometry, by at most this (degrees) plus correction_turn_per_metre_deg per "
        "metre of odometry since the last verified pose; one that would turn it further is refused (None: any "
        "turn, configs/navtopo_before_faces.yaml): odometry's heading drifts a few "
        "tenths of a degree a metre, and matches at a location's rim turned the tracked pose 4.8 degrees in 0.9 m, at "
        "once (a held-out SLAM-like ring) or in steps of under 2 degrees (a held-out aliased ring), and the next edge "
        "was made from it (BENCHMARKS.md, 'Design choices: ambiguous edge measurements and corrections that turn')",
    )
    correction_turn_per_metre_deg: float = Field(2.0, ge=0, description="... plus this (degrees per metre)")
    correction_turn_window: float = Field(
        1.0,
        ge=0,
        description="m of odometry: the corrections taken within this before a correction count with its turn "
        "(the noisy setting's odometry turns 1.5 degrees in a metre at three sigmas; 0: each correction alone)",
    )
    degenerate_ratio: float | None = Field(
        2.0,
        gt=1,
        description="tracking: where the match fixes the position this many times worse along one direction than "
        "across it (the square root of its covariance's eigenvalue ratio), the pose keeps its prediction along that "
        "direction (None: off; 2, measured on generated halls, rings and trees, BENCHMARKS.md, 'Design choices: "
        "tracking along a direction the match does not fix'; with matching.wall_closing, as the two go together)",
    )
    edge_tolerance: float = Field(1.0, gt=0, description="a new edge agrees with the graph's path within this (m) ...")
    edge_tolerance_per_metre: float = Field(0.05, ge=0, description="... plus this share of the path length")
    loop_ratio: float = Field(2.0, gt=1, description="a path longer than this times the edge closes a loop")
    stay_factor: float = Field(
        1.5,
        ge=1.0,
        description="mapping: before making a location, stay in the current one if its scan still matches "
        "within this times max_edge_length (revisits along another line do not map a place twice)",
    )
    shuttle_guard: float = Field(
        1.0,
        ge=0,
        description="navigating: after a move out of a location, no move along an edge or re-localization back into "
        "it before the robot has driven this far (m), for every location left (not only the last: three locations at "
        "one junction took the robot round 4 -> 5 -> 6 -> 4 at every update); a location left is still taken along "
        "the route. A robot "
        "between two locations, the new one not verifying it where it stands, was moved back and forth at every "
        "update, each move a plan in another frame, and turned on the spot until stuck or out of time",
    )
    relocalize_gate: float | None = Field(
        1.0,
        gt=0,
        description="navigating: a global re-localization into another location is refused where it puts the robot "
        "farther than this (m), plus relocalize_gate_per_metre per metre of odometry since the last verified pose "
        "and edge_tolerance_per_metre of the graph's path, from the tracked pose carried to that location along the "
        "graph's shortest path (None: off). Among identical rooms the scan matches "
        "the room next door as well as the robot's own: standing in the goal's room, a robot tracked to centimetres "
        "re-localized 3.9 m west into its twin and then room after room (a generated aliased wing, noisy; "
        "BENCHMARKS.md, 'Design choices: re-localizing among look-alike rooms')",
    )
    relocalize_gate_per_metre: float = Field(
        0.1, ge=0, description="... plus this (m per metre of odometry since the last verified pose)"
    )
    seen_only: bool = Field(
        True,
        description="mapping: a location holds the robot only on a cell its scan saw; a room entered through a "
        "door (seen only in part from the corridor) gets a location of its own, so that a start-up there "
        "can localize and a goal there can be planned to",
    )
    edge_measurements: int = Field(
        20, ge=1, description="measurements of an edge fused into it at most (information-weighted mean)"
    )
    measure_agreement: float | None = Field(
        0.1,
        gt=0,
        description="mapping: a scan matched against an edge's two ends measures the edge only when each match lands "
        "within this (m) and measure_agreement_deg of the distance-field fit alone from the same guess (the walls "
        "nearest the guess); where they part, the match cost has more than one minimum near the guess and the "
        "match's covariance, taken at one of them, is too sure: on a generated wing an edge made within 0.1 degrees "
        "was measured 2-4.4 degrees off with a claimed 0.2-0.37 (BENCHMARKS.md, 'Design choices: ambiguous "
        "edge measurements and corrections that turn'). None: every match measures "
        "(configs/navtopo_before_faces.yaml)",
    )
    measure_agreement_deg: float = Field(1.0, gt=0, description="... and this (degrees)")
    correction_agreement: bool = Field(
        True,
        description="a correction turning the tracked pose by more than measure_agreement_deg is taken only where "
        "its match lands within measure_agreement of the distance-field fit alone from the same guess, as an edge "
        "measurement (counter ambiguous_corrections): at a location's rim, 4.9 m from its centre, a match turned a "
        "generated noisy mirror building's pose 4.4 degrees the wrong way, the fit alone 4.36 degrees from it, and the "
        "next location's edge was made 5.4 degrees off. The default since replays of twelve generated tuning drives "
        "(BENCHMARKS.md, 'Design choices: corrections that turn only where the fit alone agrees'); False: every "
        "correction's turn is taken",
    )
    closure_radius: float | None = Field(
        2.5,
        gt=0,
        description="mapping, inside a location: a location whose odometry hint lies within this (m, plus the "
        "drift the odometry between them explains) and that the graph joins only the long way round is matched "
        "too; agreeing matches over motion make the edge (a corridor driven alongside a location without leaving "
        "the current one). None: loops close only where the robot leaves a location",
    )
    closure_every: float = Field(1.0, gt=0, description="... checked once per this much travel (m)")
    closure_candidates: int = Field(2, ge=1, description="... at most this many locations, nearest by hint, per check")
    closure_confirm_distance: float = Field(
        0.5, gt=0, description="... two matches at least this far apart (m of travel) must agree on the edge ..."
    )
    closure_agreement: float = Field(0.15, gt=0, description="... within this (m) ...")
    closure_agreement_deg: float = Field(1.5, gt=0, description="... and this (degrees)")
    closure_max_sigma: float = Field(
        0.1, gt=0, description="... and each match must fix the pose to this (m, the covariance's largest axis)"
    )
    closure_edge_sigma: float = Field(
        0.05,
        ge=0,
        description="a loop closure must agree with the pose composed along the graph's way round (the odometry "
        "chain and the edges between the two places): each edge of it counts the matcher's covariance plus this "
        "(m, standard deviation per edge, plus closure_edge_sigma_per_metre of its length) ...",
    )
    closure_edge_sigma_per_metre: float = Field(0.01, ge=0, description="... plus this share of the edge's length ...")
    closure_edge_sigma_deg: float = Field(0.3, ge=0, description="... and this (degrees per edge) ...")
    closure_gate: float | None = Field(
        16.27,
        gt=0,
        description="... within this squared Mahalanobis distance (chi-square, 3 degrees of freedom: 16.27 is its "
        "99.9 % quantile), else the closure is refused and counted (rejected_closures). None: no check",
    )
    closure_hint_gate: float | None = Field(
        1.0,
        gt=0,
        description="... and, where every location has a lidar-odometry hint, at most this far (m, plus "
        "closure_hint_per_sqrt_metre times the square root of the odometry travelled between the two locations' "
        "making) from where their hints put the two apart, else refused and counted (rejected_closures, "
        "hint_rejected_closures): along a rack hall's aisles the edges fix little, the chain admits a rack's length, "
        "and a generated noisy hall of 9,300 m2 closed a loop 3.97 m off 125 m into its tour, its lidar hints 0.15 m "
        "from the truth; the default since replays of eight generated drives (BENCHMARKS.md, 'Design choices: loop "
        "closures against the lidar hints'). None: no check (configs/navtopo_before_hint_gate.yaml)",
    )
    closure_hint_per_sqrt_metre: float = Field(
        0.025,
        ge=0,
        description="... (m per square-root metre of odometry): every pair of locations within 10 m on ten generated "
        "tuning maps lies within 0.16 m + 0.025 m/sqrt(m) of its hints; at 0.05 slam-hall 149's 6.4 km tour still closed a "
        "loop a rack's length off (worst edge 4.18 m), at 0.025 its worst edge is 0.57 m",
    )
    shortcut_radius: float | None = Field(
        8.0,
        gt=0,
        description="mapping's end: locations whose hints (the lidar odometry's where the wheels drift) lie within "
        "this (m, plus the drift the odometry between their making explains) that the graph joins only the long way "
        "round (shortcut_ratio) are matched; where the match is sure (shortcut_max_sigma), agrees with the graph's way "
        "round (closure_gate) and their grids show a way for the robot between them (shortcut_detour), they are "
        "joined. None: no shortcuts",
    )
    shortcut_ratio: float = Field(
        1.5,
        gt=1,
        description="... the graph's way between them longer than this times their distance (the long way round; "
        "such a pair's edge, under loop_ratio, must agree with the graph's way within edge_tolerance): on 6 generated "
        "maps 1.5 added 52 shortcuts, none off the truth, where 2 added 4, and a rack hall's routes across its open "
        "floor came from 0.885 to 0.903 (BENCHMARKS.md, 'Design choices: shortcuts at 1.5 times the distance')",
    )
    shortcut_max_sigma: float = Field(0.25, gt=0, description="... each match fixing the pose to this (m, largest axis)")
    shortcut_hint_agreement: float = Field(
        0.35,
        gt=0,
        description="... a match at most this far (m) from the hints that seeded it, where the graph has lidar-odometry "
        "hints to choose from (graph_poses.hint_chain: the lidar's under noisy wheels, exact wheels' otherwise): on the "
        "generated noisy ring 921 the lidar's were 0.1-0.2 m off between locations met again after a loop and every "
        "right shortcut within 0.23 m of them; one shortcut of a held-out ring, 0.44 m (noisy) and 0.52 m (precise) "
        "off the truth, was 0.45 and 0.52 m off them",
    )
    shortcut_turn_agreement: float | None = Field(
        1.0,
        gt=0,
        description="... where the graph has lidar-odometry hints, a match turned more than this (degrees) from the "
        "pose that seeded it keeps the seed's pose: the pair is verified, but two grids that share a fifth of their "
        "known area fix the turn between them to a few degrees (1-3 on a generated precise slam-ring), the relaxed "
        "poses to a few tenths (at most 0.3 on generated noisy drives; BENCHMARKS.md, 'Design choices: shortcuts "
        "seeded by the relaxed poses'). None: the match's",
    )
    shortcut_guess: Literal["hints", "relaxed", "way"] = Field(
        "relaxed",
        description="... seeded by the locations' hints (graph_poses.hint_chain) or by their relaxed map poses "
        "(graph_poses.relaxed_poses: the hints and every edge made while driving, loop closures among them); a match "
        "sharing too little known area to fix the pose (under matching.min_overlap) keeps the seed as the edge: on a "
        "generated noisy mirror building the lidar hints put three such edges 0.31-0.59 m off, the relaxed poses "
        "0.13-0.19 m. 'way': the relaxed poses, but a pair the graph joins by a short way (under loop_ratio times "
        "their distance) seeded by the pose composed along it (better on one generated noisy hall, worse on three "
        "other drives: BENCHMARKS.md, 'Design choices: an audit of the edge checks')",
    )
    shortcut_seed_agreement: float | None = Field(
        0.2,
        gt=0,
        description="... a pair whose match shares too little known area to fix the pose (under matching.min_overlap) "
        "keeps its seed as the edge only where the graph's way between the two, if short (under loop_ratio times their "
        "distance), lands within this (m) of the seed (shortcut_seed_by); else refused and counted "
        "(uncorroborated_shortcuts): on a generated noisy hall two shortcuts kept seeds 0.34 m off (the relaxed pose "
        "of a location its lidar hint pulled), the short way of one right to 3 cm; right seeds lay within 0.1 m of "
        "their ways (BENCHMARKS.md, 'Design choices: an audit of the edge checks'). None: every such seed kept "
        "(configs/navtopo_before_seed_agreement.yaml)",
    )
    shortcut_seed_by: Literal["way", "match_or_way"] = Field(
        "way",
        description="... judged by the graph's short way alone, a pair without one keeping its seed: a match under "
        "min_overlap is too weak to fix the pose, so too weak to speak against the seed ('match_or_way': the weak "
        "match may corroborate the seed too, and a pair without a short way needs it: on the bundled office02, noisy, "
        "it refused a shortcut 0.01 m off that a route took, 0.991 -> 0.855)",
    )
    shortcut_detour: float = Field(
        2.0,
        ge=1.0,
        description="... the way between them at most this times the straight line (plus two cells); the edge's "
        "length is the way's (1.25 before, configs/navtopo_before_faces.yaml: a location in a corridor's dead end "
        "2.3 m from a room's through a door off the straight line, the way 1.5 times it, was joined only 79 m round)",
    )
    shortcut_wall_agreement: float | None = Field(
        0.80,
        ge=0,
        le=1,
        description="... the match's wall agreement at least this (None: the matcher's min_wall_agreement, 0.9): two "
        "grids a few metres apart, one from a corridor and one from its junction, see a wall's far side differently "
        "(benchmarks/tune_shortcuts.py: on 4 generated maps 5 more shortcuts at 0.85 than at 0.9; on 4 maps made "
        "without shortcuts 2 more at 0.80 than at 0.85, one of them a pair the graph joined only the long way round, "
        "none off the truth; at 0.75 one 0.96 m off)",
    )
    closure_unique: bool = Field(
        False,
        description="a loop closure's match (driving or from inside) and a shortcut's each the best minimum of the "
        "distance-field fit within shortcut_hint_agreement of where it settled or was seeded "
        "(scan_matching.rival_minimum: none ranked as well lies farther than measure_agreement, "
        "measure_agreement_deg from it), else refused and counted (ambiguous_closures): along a rack hall's cross "
        "aisle, only rack ends a few metres off to fix the pose along it, a shortcut was made 0.32 m off, its match's "
        "covariance 0.02 m, a minimum ranked better 0.25 m from it",
    )
    # a prior on odometry's quality (not the benchmark's setting): how the pose's covariance grows
    # between matches, so that the pose a new location's edge starts from weighs what it is worth
    odometry_sigma_per_metre: float = Field(0.02, ge=0, description="odometry translation noise, m per m travelled")
    odometry_yaw_sigma_deg: float = Field(1.0, ge=0, description="odometry heading noise, degrees per square-root metre")


@dataclass
class EdgeCheck:
    """A new edge (u, v, ``pose``: T_uv measured) checked against the graph's way between its ends:
    ``way`` "short" (not much longer than the edge: ``edge_tolerance``) or "loop" (the long way round:
    the hints, the rival check and the closure gate), the pose ``composed`` along it, the squared
    Mahalanobis ``distance`` between the two (``closure_distance``), the edge's offset from the lidar
    hints (m; None without them) and the ``verdict``: "accepted" or the check that refused it."""

    u: int
    v: int
    pose: tuple[float, ...]
    way: str
    composed: tuple[float, ...]
    distance: float = 0.0
    hint_offset: float | None = None
    verdict: str = "accepted"


@dataclass
class EdgeEstimate:
    """An edge's relative pose T_uv (u < v) as the information-weighted mean of its measurements."""

    pose: NDArray[np.float64]
    information: NDArray[np.float64]
    count: int = 1

    @classmethod
    def first(cls, pose: NDArray[np.float64], covariance: NDArray[np.float64]) -> EdgeEstimate:
        return cls(np.asarray(pose, dtype=np.float64).copy(), _information(covariance))

    def fuse(self, measured: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        weight = _information(covariance)
        total = self.information + weight
        difference = np.asarray(measured, dtype=np.float64) - self.pose
        difference[2] = wrap_angle(difference[2])
        self.pose = self.pose + np.linalg.solve(total, weight @ difference)
        self.pose[2] = wrap_angle(self.pose[2])
        self.information = total
        self.count += 1


def _information(covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    # a floor of a millimetre and a hundredth of a degree: no measurement is exact
    floor = np.diag([1e-6, 1e-6, np.radians(0.01) ** 2])
    return np.asarray(np.linalg.inv(np.asarray(covariance, dtype=np.float64) + floor), dtype=np.float64)


@dataclass
class MappingCounters:
    updates: int = 0
    inside: int = 0
    corrections: int = 0
    moved_along_edge: int = 0
    moved_along_route: int = 0
    localized: int = 0
    loop_closures: int = 0
    new_vertices: int = 0
    rejected_edges: int = 0
    matches: int = 0
    odometry_only: int = 0  # navigating: no location verified, the pose kept by odometry in the last one
    edge_refinements: int = 0  # mapping: measurements of an existing edge fused into it
    stayed: int = 0  # mapping: outside the location's reach, yet its scan still matched
    closures_from_inside: int = 0  # mapping: edges to a location passed alongside, confirmed over motion
    rejected_closures: int = 0  # mapping: loop closures that disagreed with the graph's way round (look-alike places)
    undone_closures: int = 0  # mapping: loop-closure edges removed when a later closure contradicted them
    shortcuts: int = 0  # mapping's end: edges between locations joined only the long way round, a way seen between them
    edges_measured: int = 0  # mapping's end: edges whose length the grids measured (Dijkstra's weights)
    remapped: int = 0  # tracking: matches whose correction along a direction they fix poorly was left out (degenerate_ratio)
    refused_turns: int = 0  # tracking: corrections turning the pose more than odometry's drift explains (correction_turn_deg)
    refused_relocalizations: int = 0  # navigating: re-localizations far from the tracked pose (relocalize_gate)
    ambiguous_measurements: int = 0  # mapping: edge measurements left out, a match away from the nearest fit (measure_agreement)
    ambiguous_corrections: int = 0  # tracking: turning corrections left out, away from the nearest fit (correction_agreement)
    hint_rejected_closures: int = 0  # mapping: loop closures refused as far from the lidar hints (closure_hint_gate)
    ambiguous_closures: int = 0  # mapping: closures and shortcuts left out, a rival minimum near the match (closure_unique)
    uncorroborated_shortcuts: int = 0  # mapping's end: seed-kept shortcuts nothing agreed with (shortcut_seed_agreement)
    reasons: dict[str, int] = field(default_factory=dict)


def largest_sigma(covariance: NDArray[np.float64]) -> float:
    """The standard deviation (m) along the largest axis of a pose covariance's position part."""
    return float(np.sqrt(np.linalg.eigvalsh(np.asarray(covariance, dtype=np.float64)[:2, :2])[-1]))


def weak_direction(covariance: NDArray[np.float64] | None, ratio: float | None) -> NDArray[np.float64] | None:
    """The direction (2,) a match with this ``covariance`` fixes the position ``ratio`` times (or more)
    worse along than across (the square roots of its eigenvalues; ``degenerate_ratio``), or None:
    it fixes every direction (or the check is off, or the match has no covariance)."""
    if ratio is None or covariance is None:
        return None
    values, vectors = np.linalg.eigh(covariance[:2, :2])
    if values[0] <= 0.0 or values[1] < ratio**2 * values[0]:
        return None
    return vectors[:, 1]


def moved_enough(since: NDArray[np.float64], odom: NDArray[np.float64], config: MappingConfig) -> bool:
    """The update cadence: ``update_distance`` of motion or ``update_angle_deg`` of turning from the
    odometry pose ``since`` to ``odom`` (the maintainer's updates and the start-up's looks)."""
    delta = between(since, odom)
    return bool(np.hypot(delta[0], delta[1]) >= config.update_distance or abs(delta[2]) >= np.radians(config.update_angle_deg))


class GraphMaintainer:
    """Builds the graph online (``mapping=True``) or tracks the robot in a fixed graph."""

    def __init__(
        self,
        graph: TopologicalGraph,
        describe,  # callable: points (N, 3) float32 -> (D,) float32 descriptor
        grid_config: GridConfig,
        matching: MatchingConfig,
        config: MappingConfig,
        localization: LocalizationConfig,
        mapping: bool = True,
        grids: VertexGrids | None = None,
    ) -> None:
        self.graph = graph
        self.describe = describe
        self.grid_config = grid_config
        self.matching = matching
        self.config = config
        self.mapping = mapping
        self.grids = grids if grids is not None else VertexGrids(graph, grid_config, matching, localization.cache_size)
        self.localizer = Localizer(graph, self.grids, localization, matching, grid_config)
        self.last_verified = False  # the last update verified the pose by scan matching
        self.current: int | None = None
        self.pose_in_current = np.zeros(3)
        self.pose_covariance = np.zeros((3, 3))  # of pose_in_current
        self.counters = MappingCounters()
        self._odom = Odometer()  # of the whole drive
        self._odom_at_update: NDArray[np.float64] | None = None
        self._odometer_verified = 0.0  # the odometer when the pose was last verified by scan matching
        # correction_turn_deg: the corrections taken within its window, (the odometer then, the turn in radians)
        self._turns: deque[tuple[float, float]] = deque()
        self._odometer_at_vertex: dict[int, float] = {}
        self._left: dict[int, float] = {}  # the locations moved out of, and the odometer when the robot last left each
        self._edges: dict[tuple[int, int], EdgeEstimate] = {}
        self._odometer_at_measure: dict[tuple[int, int], float] = {}
        self._odometer_at_closure_check = -np.inf
        # (current, candidate) -> (T_current,candidate measured, its covariance, the odometer then)
        # every new edge checked against a way the graph already had between its ends (an audit:
        # benchmarks/tune_navtopo_mapping.py sets them against the truth)
        self.edge_checks: list[EdgeCheck] = []
        self._closure_edges: set[tuple[int, int]] = set()  # (u, v), u < v: the edges that closed loops
        self._pending_closures: dict[tuple[int, int], tuple[NDArray[np.float64], NDArray[np.float64], float]] = {}

    @property
    def closure_checks(self) -> list[tuple[int, int, float, bool]]:
        """The loop closures checked against the graph's way round by the closure gate: (u, v,
        squared Mahalanobis distance, accepted), from ``edge_checks``."""
        return [
            (c.u, c.v, round(c.distance, 2), c.verdict == "accepted")
            for c in self.edge_checks
            if c.way == "loop" and c.verdict in ("accepted", "gate")
        ]

    # -- odometry ----------------------------------------------------------------------------------

    def integrate(self, odom: NDArray[np.float64]) -> None:
        if not self._odom.started:
            self._odom.update(odom)
            return
        delta = self._odom.update(odom)
        self.pose_in_current = compose(self.pose_in_current, delta)
        step = float(np.hypot(delta[0], delta[1]))
        sigma_xy = self.config.odometry_sigma_per_metre * step
        sigma_yaw2 = np.radians(self.config.odometry_yaw_sigma_deg) ** 2 * step
        self.pose_covariance = self.pose_covariance + np.diag([sigma_xy**2, sigma_xy**2, sigma_yaw2])

    def due(self, odom: NDArray[np.float64]) -> bool:
        if self.current is None or self._odom_at_update is None:
            return True
        return moved_enough(self._odom_at_update, odom, self.config)

    # -- the update --------------------------------------------------------------------------------

    def start_at(self, vertex: int, pose_in_vertex: NDArray[np.float64], odom: NDArray[np.float64]) -> None:
        """Track from a known state (a navigation start, once localized): odometry counts from ``odom``."""
        self._switch(vertex, pose_in_vertex)
        self._odom.restart_from(odom)
        self._odom_at_update = np.array(odom, dtype=np.float64)
        self._turns.clear()

    def forget(self) -> None:
        """No current location, no odometry: the state of a robot that has not localized yet."""
        self.current = None
        self.pose_in_current = np.zeros(3)
        self._odom.restart_from(None)
        self._odom_at_update = None
        self.last_verified = False
        self._left = {}
        self._turns.clear()

    def update(
        self,
        points: NDArray[np.float32],
        odom: NDArray[np.float64],
        stamp: float,
        route: list[int] | None = None,
        force: bool = False,
        localize: bool = True,
        ahead: int = 1,
    ) -> str:
        """Integrate odometry and, when due (or ``force``), update the state (and, mapping, the graph).

        route: navigating, the global path from the current vertex; the robot moves to its next
        vertex as soon as it is nearer to that one's centre than to the current one's and scan
        matching agrees (the paper: "we try to change v_cur to the next node in the path").
        ahead: the index in ``route`` of the vertex the local path heads for (the vertices before it
        passed by a straight cut; ``_move_along_route``).
        localize: whether a robot that is neither inside nor along an edge may localize globally.
        Returns what happened: "odometry", "inside", "edge", "route", "localized", "new_vertex" or "lost".
        """
        self.integrate(odom)
        if not (force or self.due(odom)):
            return "odometry"
        self._odom_at_update = np.asarray(odom, dtype=np.float64).copy()
        self.counters.updates += 1
        self.last_verified = False
        grid = grid_from_points(points, self.grid_config)
        if self.current is None and self.mapping:
            self._add_vertex(grid, points, odom, stamp, edge_from_current=False)
            return "new_vertex"
        query = prepare(grid, self.grid_config, self.matching)
        way = route[: max(min(ahead, len(route) - 1), 1) + 1] if route else []
        if self.current is not None and len(way) > 1 and self._move_along_route(query, way):
            self.counters.moved_along_route += 1
            return "route"
        inside = self._inside(grid) if self.current is not None else ""
        if inside == "seen" or (inside == "unseen" and self._correct(query)):
            self.counters.inside += 1
            if inside == "seen":
                self._correct(query)
            if self.mapping and self.last_verified:
                self._measure_neighbour(query)
                self._close_from_inside(query, odom)
            return "inside"
        if self.current is not None and len(way) > 1 and self._move_along_route(query, way, nearer=False):
            # out of the location's reach: the paper's next try is the path's next vertex, before any
            # other neighbour (the nearest one may be the vertex the path just came from)
            self.counters.moved_along_route += 1
            return "route"
        if self.current is not None and self._move_along_edge(query):
            self.counters.moved_along_edge += 1
            return "edge"
        if localize and self._localize(query, points, odom):
            self.counters.localized += 1
            return "localized"
        if self.mapping and self.current is not None and self._still_matches(query):
            # a little beyond the location's reach, but its scan still matches: no place mapped twice
            self.counters.stayed += 1
            return "inside"
        if self.mapping:
            self._add_vertex(grid, points, odom, stamp, edge_from_current=self.current is not None)
            return "new_vertex"
        self.counters.odometry_only += 1
        return "lost"

    def _move_along_route(self, query: PreparedGrid, way: list[int], nearer: bool = True) -> bool:
        """Switch to a vertex of the route ahead (``way``: from the current vertex to the one the local
        path heads for) if matching agrees: that last one, else the route's next one (``way[1]``), each
        placed by the edges along the way; once nearer to it than to the current one (``nearer``), or
        wherever the robot is (it has left the current location's reach). A path cut straight past a
        location (``LocalPlanner.aim``) ends at a vertex no edge joins to the current one: the robot
        stood at its centre, in no location but the one it had left, and planned the same path again
        until the time ran out (office02, precise)."""
        assert self.current is not None
        candidates = []  # (vertex, its pose in the current vertex's frame)
        if (
            len(way) > 2
            and way[0] == self.current
            and all(self.graph.has_edge(a, b) for a, b in zip(way[:-1], way[1:], strict=True))
        ):
            candidates.append((way[-1], self.chain(way)[0]))
        if self.graph.has_edge(self.current, way[1]):
            candidates.append((way[1], self.graph.edge(self.current, way[1])))
        here = self.pose_in_current
        reach = self.config.stay_factor * self.config.max_edge_length
        for vertex, pose_uv in candidates:
            if nearer and float(np.hypot(*(pose_uv[:2] - here[:2]))) >= float(np.hypot(here[0], here[1])):
                continue
            guess = between(pose_uv, here)
            if float(np.hypot(guess[0], guess[1])) > reach:
                # no location holds a robot this far from its centre (``_still_matches``): moved into the
                # goal's location 8.5 m from it, the robot stood off that location's union grid, and the
                # plan to the goal had no start (a mirror building, held out)
                continue
            self.counters.matches += 1
            located = self.localizer.verify(query, vertex, guess, self.config.max_neighbour_jump)
            if located is None:
                continue
            located = self._remapped(guess, located)
            self._switch(vertex, located.pose, self._located_covariance(located))
            self.last_verified = True
            return True
        return False

    def _inside(self, grid: NDArray[np.uint8]) -> str:
        """ "seen": near the location's centre, on a cell it knows, the scans overlapping enough;
        "unseen": the same but on a cell it never saw (behind a door frame, in a room it saw through
        a door), to be confirmed by scan matching — navigating, or mapping with ``seen_only`` off
        (mapping with it on, such a cell is outside: the room becomes a location); "" (outside)
        otherwise."""
        assert self.current is not None
        pose = self.pose_in_current
        if float(np.hypot(pose[0], pose[1])) > self.config.max_edge_length:
            return ""
        vertex_grid = self.graph.vertices[self.current].grid.to_grid()
        if overlap(vertex_grid, grid, pose, self.grid_config) < self.config.min_overlap:
            return ""
        if self._sees(self.current, pose):
            return "seen"
        return "" if self._claims_seen_only else "unseen"

    @property
    def _claims_seen_only(self) -> bool:
        return self.mapping and self.config.seen_only

    def _sees(self, vertex: int, pose: NDArray[np.float64]) -> bool:
        """Did ``vertex``'s scan see the cell at ``pose`` (its frame)?"""
        cropped = self.graph.vertices[vertex].grid  # its known cells' box: outside it, unknown
        row, col = grid_frame(self.grid_config).to_cell(np.asarray(pose, dtype=np.float64)[None, :2])[0]
        row, col = row - cropped.row0, col - cropped.col0
        height, width = cropped.cells.shape
        return bool(0 <= row < height and 0 <= col < width and cropped.cells[row, col] != UNKNOWN)

    def _still_matches(self, query: PreparedGrid) -> bool:
        """Within ``stay_factor`` times the location's reach, does scan matching still place the robot
        in it? Only the answer counts: a match from this far fixes the pose worse than odometry over
        the last metres does (0.3 m and 4° off at 7 m, against centimetres within 4 m), so the pose
        stays as odometry carries it."""
        assert self.current is not None
        if float(np.hypot(*self.pose_in_current[:2])) > self.config.stay_factor * self.config.max_edge_length:
            return False
        if self._claims_seen_only and not self._sees(self.current, self.pose_in_current):
            return False
        self.counters.matches += 1
        return self.localizer.verify(query, self.current, self.pose_in_current, self.config.max_correction) is not None

    def _remapped(self, predicted: NDArray[np.float64], located: Localized) -> Localized:
        """``located`` with its correction of ``predicted`` taken out along the direction the match
        fixes poorly (``degenerate_ratio``): along an aisle or a corridor without ends in sight the
        scan says little, and what it says (dashes of a wall, a rack's end seen at a grazing angle)
        moves with the robot; there the prediction (odometry, an edge) is kept."""
        if located.result.overlap < self.matching.min_overlap:
            return located
        weak = weak_direction(located.result.covariance, self.config.degenerate_ratio)
        if weak is None:
            return located
        pose = located.pose.copy()
        pose[:2] -= weak * float(weak @ (pose[:2] - predicted[:2]))
        self.counters.remapped += 1
        return Localized(located.vertex, pose, located.result)

    def _correct(self, query: PreparedGrid) -> bool:
        assert self.current is not None
        limit = self.config.max_correction
        if self.config.correction_per_metre is not None:
            travelled = self._odom.metres - self._odometer_verified
            limit = min(limit, self.config.correction_base + self.config.correction_per_metre * travelled)
        located = self.localizer.verify(query, self.current, self.pose_in_current, limit)
        self.counters.matches += 1
        if located is None:
            return False
        if (
            self.config.correction_agreement
            and abs(float(wrap_angle(located.pose[2] - self.pose_in_current[2]))) > np.radians(self.config.measure_agreement_deg)
            and not self._unambiguous(query, located, self.pose_in_current, counted=False)
        ):
            self.counters.ambiguous_corrections += 1
            return False
        if self.config.correction_turn_deg is not None and not self._turn_explained(located.pose):
            self.counters.refused_turns += 1
            return False
        located = self._remapped(self.pose_in_current, located)
        self._odometer_verified = self._odom.metres
        self.pose_in_current = located.pose
        self.pose_covariance = self._located_covariance(located)
        self.counters.corrections += 1
        self.last_verified = True
        return True

    def _turn_explained(self, pose: NDArray[np.float64]) -> bool:
        """``correction_turn_deg``: does the correction to ``pose`` turn the tracked pose, with the
        corrections taken within ``correction_turn_window`` metres before it, by no more than
        odometry's drift since the last verified pose explains? Kept in the window when it does."""
        config = self.config
        assert config.correction_turn_deg is not None
        now = self._odom.metres
        while self._turns and now - self._turns[0][0] > config.correction_turn_window:
            self._turns.popleft()
        turn = float(wrap_angle(float(pose[2] - self.pose_in_current[2])))
        turned = turn + sum(t for _, t in self._turns)
        travelled = now - self._odometer_verified
        if abs(turned) > np.radians(config.correction_turn_deg + config.correction_turn_per_metre_deg * travelled):
            return False
        self._turns.append((now, turn))
        return True

    def _move_along_edge(self, query: PreparedGrid) -> bool:
        assert self.current is not None
        here = self.pose_in_current
        distance_to_current = float(np.hypot(here[0], here[1]))
        options = []
        just_left = self._just_left()
        for vertex, pose_uv in self.graph.neighbours(self.current):
            if vertex in just_left:
                continue  # just left it: the robot stays here by odometry a little longer
            distance = float(np.hypot(*(pose_uv[:2] - here[:2])))
            if distance < distance_to_current or distance < self.config.max_edge_length:
                options.append((distance, vertex, pose_uv))
        for _, vertex, pose_uv in sorted(options, key=lambda o: o[0]):
            guess = between(pose_uv, here)  # the robot in the neighbour's frame, by the edge
            self.counters.matches += 1
            located = self.localizer.verify(query, vertex, guess, self.config.max_neighbour_jump)
            if located is not None and self._claims_seen_only and not self._sees(vertex, located.pose):
                continue
            if located is not None:
                located = self._remapped(guess, located)
                if self.mapping:
                    self._refine_edge(query, self.current, vertex, located, guess)
                self._switch(vertex, located.pose, self._located_covariance(located))
                self.last_verified = True
                return True
        return False

    def _just_left(self) -> set[int]:
        """Navigating, the locations the robot moved out of within the last ``shuttle_guard`` metres."""
        guard = 0.0 if self.mapping else self.config.shuttle_guard
        return {vertex for vertex, odometer in self._left.items() if self._odom.metres - odometer < guard}

    def _refine_edge(self, query: PreparedGrid, u: int, v: int, at_v: Localized, guess_v: NDArray[np.float64]) -> None:
        """Moving along an edge while mapping: the scan matched against both ends at once measures
        ``T_uv`` with no odometry in between (``guess_v``: the guess ``at_v`` was matched from)."""
        guess_u = self.pose_in_current
        at_u = self.localizer.verify(query, u, guess_u, self.config.max_correction)
        self.counters.matches += 1
        if at_u is None:
            return
        if not (self._unambiguous(query, at_u, guess_u) and self._unambiguous(query, at_v, guess_v)):
            return
        self._measure_edge(u, v, *self._through(at_u.pose, self._located_covariance(at_u), at_v))

    def _unambiguous(self, query: PreparedGrid, located: Localized, guess: NDArray[np.float64], counted: bool = True) -> bool:
        """Does the match ``located`` (matched from ``guess``) land where the distance-field fit alone
        from the guess does, within ``measure_agreement``? Counted as an ambiguous measurement when
        not (``counted``)."""
        if self.config.measure_agreement is None:
            return True
        nearest = refine(self.localizer.grids.get(located.vertex), query, guess, self.matching, icp=False)
        step = between(nearest, located.result.pose)
        moved, turned = float(np.hypot(step[0], step[1])), abs(float(step[2]))
        if moved <= self.config.measure_agreement and turned <= np.radians(self.config.measure_agreement_deg):
            return True
        if counted:
            self.counters.ambiguous_measurements += 1
        return False

    def _measure_neighbour(self, query: PreparedGrid) -> None:
        """Mapping, inside a location whose neighbour's centre is about as near as its own (within a
        metre): the scan, just matched against the location, matched against the neighbour too
        measures their edge — both matches share many walls here, unlike at a location's rim where
        the robot moves along the edge. Once a metre of travel per edge, while it takes measurements."""
        assert self.current is not None
        here = self.pose_in_current
        own = float(np.hypot(here[0], here[1]))
        nearest = None
        for vertex, pose_uv in self.graph.neighbours(self.current):
            distance = float(np.hypot(*(pose_uv[:2] - here[:2])))
            if distance <= min(own + 1.0, self.config.max_edge_length) and (nearest is None or distance < nearest[0]):
                nearest = (distance, vertex, pose_uv)
        if nearest is None:
            return
        _, vertex, pose_uv = nearest
        key = (min(self.current, vertex), max(self.current, vertex))
        estimate = self._edges.get(key)
        if estimate is not None and estimate.count >= self.config.edge_measurements:
            return
        if self._odom.metres - self._odometer_at_measure.get(key, -np.inf) < 1.0:
            return
        self._odometer_at_measure[key] = self._odom.metres
        self.counters.matches += 1
        guess = between(pose_uv, here)
        located = self.localizer.verify(query, vertex, guess, self.config.max_neighbour_jump)
        if located is None or located.result.covariance is None or located.result.overlap < self.matching.min_overlap:
            return
        if self._claims_seen_only and not self._sees(vertex, located.pose):
            return
        if not self._unambiguous(query, located, guess):
            return
        self._measure_edge(self.current, vertex, *self._through(here, self.pose_covariance, located))

    def _close_from_inside(self, query: PreparedGrid, odom: NDArray[np.float64]) -> None:
        """Mapping, inside a location, the pose just verified: a loop closure without leaving it.

        A robot that drives alongside a known location while its own still holds it (a corridor
        seen whole from the location it is in) never moves along an edge or localizes, so the two
        stay unjoined and the graph goes the long way round. Once per ``closure_every`` metres,
        the nearest locations by odometry hint (within ``closure_radius`` plus what drift explains)
        that the graph joins only by a path ``loop_ratio`` times longer are matched, seeded by the
        hint, with the strict verdict; a match that fixes the pose well is kept pending, and the
        edge is made when a second one, at least ``closure_confirm_distance`` further on, agrees
        with it (a match sliding along a corridor does not stay consistent over motion)."""
        config = self.config
        if config.closure_radius is None or self.current is None:
            return
        if self._odom.metres - self._odometer_at_closure_check < config.closure_every:
            return
        self._odometer_at_closure_check = self._odom.metres
        robot, gates = self._hint_gates(odom, config.closure_radius)
        options = []
        for vertex, gate in gates.items():
            if vertex == self.current or self.graph.has_edge(self.current, vertex):
                continue
            guess = between(self.graph.vertices[vertex].pose_hint, robot)  # the robot in its frame, by odometry
            distance = float(np.hypot(guess[0], guess[1]))
            if distance <= gate:
                options.append((distance, vertex, guess, gate))
        for distance, vertex, guess, gate in sorted(options, key=lambda o: o[0])[: config.closure_candidates]:
            path, path_length = self.graph.shortest_path(self.current, vertex)
            if path is not None and path_length < config.loop_ratio * max(distance, 1.0):
                continue
            self.counters.matches += 1
            located = self.localizer.verify(query, vertex, guess, gate, strict=True)
            if located is None or located.result.covariance is None or located.result.overlap < self.matching.min_overlap:
                continue
            if self._claims_seen_only and not self._sees(vertex, located.pose):
                continue
            pose_cv, covariance_cv = self._through(self.pose_in_current, self.pose_covariance, located)
            if largest_sigma(covariance_cv) > config.closure_max_sigma:
                continue
            key = (self.current, vertex)
            pending = self._pending_closures.get(key)
            if pending is None or self._odom.metres - pending[2] < config.closure_confirm_distance:
                if pending is None:
                    self._pending_closures[key] = (pose_cv, covariance_cv, self._odom.metres)
                continue
            step = between(pending[0], pose_cv)
            agree = float(np.hypot(step[0], step[1])) <= config.closure_agreement and abs(step[2]) <= np.radians(
                config.closure_agreement_deg
            )
            if not agree:
                self._pending_closures[key] = (pose_cv, covariance_cv, self._odom.metres)  # start over from this one
                continue
            del self._pending_closures[key]
            if not self._edge_acceptable(
                self.current,
                vertex,
                pose_cv,
                covariance_cv,
                partial(self._ambiguous, vertex, query, located.result, located.result.pose),
            ):
                continue
            self._new_edge(self.current, vertex, pending[0], pending[1])
            self._measure_edge(self.current, vertex, pose_cv, covariance_cv)
            self.counters.closures_from_inside += 1

    def add_shortcuts(self, way: WayBetween) -> int:
        """Mapping's end: join locations that lie near each other but that the graph joins only the
        long way round (two corridors' locations met at a junction from different sides, a dead end
        driven into and out of without reaching the junction's location). A route between them went
        round the block: 2-3 times the shortest way on generated lattices (issue 30).

        Pairs whose seeds (``shortcut_guess``: the relaxed map poses, or the hints of
        ``graph_poses.hint_chain``, the lidar odometry's where the wheels drift) lie within
        ``shortcut_radius`` (plus what drift explains) and
        whose graph path is ``shortcut_ratio`` times longer are matched grid against grid, seeded by
        them (the verdict with a guess: two locations a few metres apart share a fifth of their
        known area, too little for the strict one, and fix the turn between them worse than the seeds
        do: ``shortcut_turn_agreement``). The edge is made when the match fixes the pose
        (``shortcut_max_sigma``), the two grids united show a way between the two observation points
        (``way``: the navigator's local planner through their known free space), at most
        ``shortcut_detour`` times the straight line (the edge's length, Dijkstra's weight, is then the
        way's within that), and it agrees with the graph's way round
        (``_edge_acceptable``: the loop-closure check against look-alike places). Returns the count."""
        config = self.config
        if config.shortcut_radius is None or len(self.graph) < 2:
            return 0
        per_metre = self.localizer.config.drift_per_metre
        vertices = self.graph.vertices
        # the seeds: the relaxed map poses (the hints below and the edges made driving), or the
        # hints that agree with the edges alone: the lidar odometry's under drifting wheels (a noisy
        # generated ring: the wheels' 3-8 m and 15-20° off between locations met again after a loop,
        # too far for the seeded match, the lidar's 0.1-0.2 m), the wheels' when exact
        hints = relaxed_poses(self.graph) if config.shortcut_guess in ("relaxed", "way") else hint_chain(self.graph)[1]
        # with lidar hints beside the wheels' the chain took the better of the two, a few decimetres
        # off at most; without them (wheels alone, however they drift) nothing gates the match
        gated = all(vertex.lidar_hint is not None for vertex in vertices)
        odometer = np.array([np.nan if vertex.odometer is None else vertex.odometer for vertex in vertices])
        added = 0
        for u in range(len(vertices)):
            drift = per_metre * np.nan_to_num(np.abs(odometer - odometer[u]), nan=0.0)
            near = np.hypot(*(hints[:, :2] - hints[u, :2]).T) <= config.shortcut_radius + drift
            for v in (np.flatnonzero(near[u + 1 :]) + u + 1).tolist():
                if self.graph.has_edge(u, v):
                    continue
                guess = between(hints[u], hints[v])
                distance = float(np.hypot(guess[0], guess[1]))
                path, path_length = self.graph.shortest_path(u, v)
                if path is not None and path_length < config.shortcut_ratio * max(distance, 1.0):
                    continue
                if config.shortcut_guess == "way" and path is not None and path_length < config.loop_ratio * max(distance, 1.0):
                    guess = self.graph.path_pose(path)
                self.counters.matches += 1
                query = self.grids.get(v)
                located = self.localizer.verify(
                    query,
                    u,
                    guess,
                    config.max_neighbour_jump + float(drift[v]),
                    min_wall_agreement=config.shortcut_wall_agreement,
                    # a match farther from the hints is refused below: its features are not
                    # searched for (along a corridor a feature pose 1.9 m off outscored the right
                    # one and the shortcut was lost; a generated lattice)
                    guess_tolerance=config.shortcut_hint_agreement if gated else None,
                )
                if located is None or located.result.covariance is None:
                    continue
                covariance = np.asarray(located.result.covariance, dtype=np.float64)
                if largest_sigma(covariance) > config.shortcut_max_sigma:
                    continue
                if not self._seed_corroborated(located, guess, path, path_length, distance):
                    continue
                off = between(guess, located.pose)
                if gated and float(np.hypot(off[0], off[1])) > config.shortcut_hint_agreement:
                    continue  # the hints are a few decimetres off at most: a match farther slid
                if self._ambiguous(u, query, located.result, guess):
                    continue
                turn = config.shortcut_turn_agreement
                if gated and turn is not None and abs(float(wrap_angle(off[2]))) > np.radians(turn):
                    located = Localized(located.vertex, guess.copy(), located.result)
                length = way(self.graph, u, v, located.pose)
                straight = float(np.hypot(located.pose[0], located.pose[1]))
                if length is None or length > config.shortcut_detour * straight + 2 * self.grid_config.resolution:
                    continue
                if not self._edge_acceptable(u, v, located.pose, covariance):
                    continue
                self._new_edge(u, v, located.pose, covariance)
                self.counters.shortcuts += 1
                added += 1
        return added

    def _seed_corroborated(
        self, located: Localized, guess: NDArray[np.float64], path: list[int] | None, path_length: float, distance: float
    ) -> bool:
        """A shortcut whose match shares too little known area to fix the pose keeps its seed
        (``Localizer.verify``); with ``shortcut_seed_agreement``, only where the graph's way between
        the two, if short (under ``loop_ratio`` times their distance), lands within that of the seed
        (``shortcut_seed_by`` "way": a pair without a short way keeps it; "match_or_way": the weak
        match may corroborate it too, and a pair without a short way needs it). Else refused and
        counted (``uncorroborated_shortcuts``)."""
        agreement = self.config.shortcut_seed_agreement
        if agreement is None or located.result.overlap >= self.matching.min_overlap:
            return True
        short = path is not None and path_length < self.config.loop_ratio * max(distance, 1.0)
        way = self.graph.path_pose(path) if short and path is not None else None
        if self.config.shortcut_seed_by == "way" and way is None:
            return True
        by_match = self.config.shortcut_seed_by == "match_or_way"
        if by_match and float(np.hypot(*(located.result.pose[:2] - guess[:2]))) <= agreement:
            return True
        if way is not None and float(np.hypot(*(way[:2] - guess[:2]))) <= agreement:
            return True
        self.counters.uncorroborated_shortcuts += 1
        return False

    def _ambiguous(self, vertex: int, query: PreparedGrid, result: MatchResult, centre: NDArray[np.float64]) -> bool:
        """With ``closure_unique``: does the fit of ``query`` in ``vertex``'s grid have a minimum as
        good as the match ``result``, away from it, within ``shortcut_hint_agreement`` of ``centre``
        (the seed, or where the match settled)? Counted (``ambiguous_closures``)."""
        config = self.config
        if not config.closure_unique:
            return False
        rival = rival_minimum(
            self.grids.get(vertex),
            query,
            result,
            centre,
            config.shortcut_hint_agreement,
            config.measure_agreement if config.measure_agreement is not None else 0.1,
            np.radians(config.measure_agreement_deg),
            self.matching,
        )
        if rival is None:
            return False
        self.counters.ambiguous_closures += 1
        return True

    def measure_edges(self, way: WayBetween) -> int:
        """Mapping's end: each edge's length as the robot drives it (``way``: the navigator's local
        planner through the two grids' known free space), Dijkstra's weight from then on: a route that
        turns round a wall corner or goes through a door is longer than its straight edges, and two
        routes are compared by what driving them takes. An edge with no such way (its two grids do
        not show one) keeps its straight length. Returns the count measured."""
        measured = 0
        for u, v, pose in self.graph.edges():
            length = way(self.graph, u, v, pose)
            if length is not None:
                self.graph.set_edge_length(u, v, length)
                measured += 1
        self.counters.edges_measured = measured
        return measured

    def _hint_gates(self, odom: NDArray[np.float64], base: float) -> tuple[NDArray[np.float64], dict[int, float]]:
        """Mapping: the robot's pose by odometry and, for each vertex it may be near, how far that
        vertex's hint may be off it (``base`` plus what drift explains).

        The hints share the mapping run's odometry frame with the robot and drift apart by what
        odometry travelled between their making: between a vertex made long ago and the robot now,
        the whole route since (a 67 m gate after 1.3 km let a place 26 m away that looked alike close
        a loop on loop_office_door; BENCHMARKS.md, "Design choices: loop-closure candidates gated
        through the current location's hint"). The robot's pose in the current vertex is
        scan-matched, so through the current vertex's hint the drift is only that between the two
        vertices' making, plus since the last match: a vertex farther than that from the robot by
        the current vertex's hint is left out. (Seeding the matcher from that hint instead of
        odometry changed the maps of a generated noisy ring for the worse: 5 places mapped twice
        against 2.)"""
        assert self.current is not None
        per_metre = self.localizer.config.drift_per_metre
        made_here = self._odometer_at_vertex.get(self.current, self._odom.metres)
        since_match = self._odom.metres - self._odometer_verified
        robot = np.asarray(odom, dtype=np.float64)
        through_current = compose(self.graph.vertices[self.current].pose_hint, self.pose_in_current)
        gates = {}
        for vertex, travelled in self._odometer_at_vertex.items():
            hint = self.graph.vertices[vertex].pose_hint[:2]
            if float(np.hypot(*(hint - through_current[:2]))) <= base + per_metre * (abs(made_here - travelled) + since_match):
                gates[vertex] = base + per_metre * abs(self._odom.metres - travelled)
        return robot, gates

    def _localize(self, query: PreparedGrid, points: NDArray[np.float32], odom: NDArray[np.float64]) -> bool:
        if len(self.graph) == 0:
            return False
        descriptor = self.describe(points)
        # navigating, not back into a location just left either (``shuttle_guard``): moved 6 -> 5 along
        # the route and re-localized 5 -> 6 at every update, the robot stood at a junction till time ran out
        exclude = ({self.current} | self._just_left()) if self.current is not None else set()
        hint, gates = None, None
        if self.mapping and self.current is not None:
            hint, gates = self._hint_gates(odom, self.localizer.config.drift_base)
            exclude |= set(self._odometer_at_vertex) - set(gates)
        elif self.current is not None:
            # navigating: the current vertex's hint and the pose in it say where the robot is in the
            # mapping run's odometry frame; locally the hints are consistent up to the drift between them
            hint = compose(self.graph.vertices[self.current].pose_hint, self.pose_in_current)
            config = self.localizer.config
            gates = {
                v: config.drift_base + config.drift_per_metre * float(np.hypot(*(vertex.pose_hint[:2] - hint[:2])))
                for v, vertex in enumerate(self.graph.vertices)
            }
        found = self.localizer.localize(query, descriptor, exclude=exclude, robot_hint=hint, hint_gate=gates)
        self.counters.matches += min(self.localizer.config.top_k, len(self.graph))
        for located in found:
            if self._claims_seen_only and not self._sees(located.vertex, located.pose):
                continue
            covariance = self._located_covariance(located)
            if self.current is None:
                self._switch(located.vertex, located.pose, covariance)
                self.last_verified = True
                return True
            if not self.mapping and not self._near_tracked(located):
                self.counters.refused_relocalizations += 1
                continue
            pose_cu, covariance_cu = self._through(self.pose_in_current, self.pose_covariance, located)
            if self.mapping and not self._edge_acceptable(
                self.current,
                located.vertex,
                pose_cu,
                covariance_cu,
                partial(self._ambiguous, located.vertex, query, located.result, located.result.pose),
            ):
                continue
            if self.mapping and not self.graph.has_edge(self.current, located.vertex):
                self._new_edge(self.current, located.vertex, pose_cu, covariance_cu)
            self._switch(located.vertex, located.pose, covariance)
            self.last_verified = True
            return True
        return False

    def _near_tracked(self, located: Localized) -> bool:
        """``relocalize_gate``, navigating: does ``located`` put the robot near where tracking has it, the
        tracked pose carried to ``located.vertex`` along the graph's shortest path? A location the graph
        does not reach from the current one is not gated (nothing to compare with)."""
        assert self.current is not None
        config = self.config
        if config.relocalize_gate is None or located.vertex == self.current:
            return True
        path, path_length = self.graph.shortest_path(self.current, located.vertex)
        if path is None:
            return True
        predicted = between(self.chain(path)[0], self.pose_in_current)
        since = self._odom.metres - self._odometer_verified
        gate = config.relocalize_gate + config.relocalize_gate_per_metre * since + config.edge_tolerance_per_metre * path_length
        return float(np.hypot(*(predicted[:2] - located.pose[:2]))) <= gate

    def _edge_acceptable(
        self,
        u: int,
        v: int,
        pose_uv: NDArray[np.float64],
        covariance: NDArray[np.float64] | None = None,
        ambiguous: Callable[[], bool] | None = None,
    ) -> bool:
        """May the edge ``T_uv`` be made? Too long, or disagreeing with the graph's way between its
        ends (a short way: within ``edge_tolerance``; the long way round, a loop closure: the lidar
        hints, ``ambiguous`` (its match has a rival, asked only of a closure) and the closure gate)."""
        length = float(np.hypot(pose_uv[0], pose_uv[1]))
        if length > 2.0 * self.config.max_edge_length:
            self.counters.rejected_edges += 1
            return False
        path, path_length = self.graph.shortest_path(u, v)
        if path is None:
            return True
        check = EdgeCheck(u, v, tuple(map(float, pose_uv)), "short", tuple(map(float, self.graph.path_pose(path))))
        check.distance = self.closure_distance(path, pose_uv, covariance)
        check.hint_offset = self._hint_offset(u, v, pose_uv)
        self.edge_checks.append(check)
        if path_length < self.config.loop_ratio * max(length, 1.0):
            error = float(np.hypot(*(np.asarray(check.composed[:2]) - pose_uv[:2])))
            if error > self.config.edge_tolerance + self.config.edge_tolerance_per_metre * path_length:
                self.counters.rejected_edges += 1
                check.verdict = "disagrees_with_way"
                return False
        else:
            check.way = "loop"
            if not self._agrees_with_hints(u, v, pose_uv):
                self.counters.rejected_closures += 1
                self.counters.hint_rejected_closures += 1
                check.verdict = "hints"
                return False
            if ambiguous is not None and ambiguous():
                self.counters.rejected_closures += 1
                check.verdict = "rival"
                return False
            gate = self.config.closure_gate
            distance = check.distance
            if gate is not None and distance > gate and self._undo_contradicted(u, v, path, pose_uv, covariance):
                path, _ = self.graph.shortest_path(u, v)
                distance = self.closure_distance(path, pose_uv, covariance) if path is not None else 0.0
            accepted = gate is None or distance <= gate
            check.distance = distance
            if not accepted:
                self.counters.rejected_closures += 1
                check.verdict = "gate"
                return False
            self.counters.loop_closures += 1
            self._closure_edges.add((min(u, v), max(u, v)))
        return True

    def _agrees_with_hints(self, u: int, v: int, pose_uv: NDArray[np.float64]) -> bool:
        """Does the loop closure ``T_uv`` lie within ``closure_hint_gate`` (plus what the odometry
        between the two locations' making explains) of their lidar-odometry hints' ``T_uv``? True
        where there is no such check or a location has no lidar hint."""
        config = self.config
        a, b = self.graph.vertices[u], self.graph.vertices[v]
        off = self._hint_offset(u, v, pose_uv)
        if config.closure_hint_gate is None or off is None or a.odometer is None or b.odometer is None:
            return True
        travelled = abs(a.odometer - b.odometer)
        return off <= config.closure_hint_gate + config.closure_hint_per_sqrt_metre * float(np.sqrt(travelled))

    def _hint_offset(self, u: int, v: int, pose_uv: NDArray[np.float64]) -> float | None:
        """How far (m) ``T_uv`` puts v from where the two locations' lidar-odometry hints put it;
        None where a location has no lidar hint."""
        a, b = self.graph.vertices[u], self.graph.vertices[v]
        if a.lidar_hint is None or b.lidar_hint is None:
            return None
        hinted = between(a.lidar_hint, b.lidar_hint)
        return float(np.hypot(pose_uv[0] - hinted[0], pose_uv[1] - hinted[1]))

    def _undo_contradicted(
        self, u: int, v: int, path: list[int], pose_uv: NDArray[np.float64], covariance: NDArray[np.float64] | None
    ) -> bool:
        """A closure (u, v) that disagrees with the graph's way round, where that way runs over
        earlier loop closures: if it agrees with the way round the graph's other edges (the
        chain made driving, no closure) and an earlier closure on the way does not, that earlier
        one joined look-alike places: its edge is removed (undone, counted). True if any was."""
        gate = self.config.closure_gate
        assert gate is not None
        on_path = [
            (min(a, b), max(a, b))
            for a, b in zip(path[:-1], path[1:], strict=True)
            if (min(a, b), max(a, b)) in self._closure_edges
        ]
        if not on_path:
            return False
        removed = {frozenset(key) for key in self._closure_edges}
        spine = self._path_avoiding(u, v, removed)
        if spine is None or self.closure_distance(spine, pose_uv, covariance) > gate:
            return False
        undone = False
        for a, b in on_path:
            way = self._path_avoiding(a, b, removed)
            estimate = self._edges.get((a, b))
            measured = None if estimate is None else np.asarray(np.linalg.inv(estimate.information), dtype=np.float64)
            if way is None or self.closure_distance(way, self.graph.edge(a, b), measured) <= gate:
                continue
            self.graph.remove_edge(a, b)
            self._edges.pop((a, b), None)
            self._closure_edges.discard((a, b))
            self.counters.undone_closures += 1
            undone = True
        return undone

    def _path_avoiding(self, u: int, v: int, removed: set[frozenset[int]]) -> list[int] | None:
        """The graph's shortest path from u to v over the edges but ``removed``; None if there is none."""
        dist, prev = self.graph.dijkstra(u, removed)
        if not np.isfinite(dist[v]):
            return None
        path = [v]
        while path[-1] != u:
            path.append(int(prev[path[-1]]))
        return path[::-1]

    def chain(self, path: list[int]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The last vertex of ``path`` in the first one's frame composed along its edges, and the
        covariance of that pose: each edge's (the information of its fused measurements) plus the
        floor ``closure_edge_sigma`` (+ per metre of the edge) and ``closure_edge_sigma_deg``, as
        the measurements of an edge are not independent (fused, they would claim millimetres)."""
        config = self.config
        pose, covariance = np.zeros(3), np.zeros((3, 3))
        for a, b in zip(path[:-1], path[1:], strict=True):
            pose_ab = self.graph.edge(a, b)
            sigma = config.closure_edge_sigma + config.closure_edge_sigma_per_metre * float(np.hypot(*pose_ab[:2]))
            edge_cov = np.diag([sigma**2, sigma**2, np.radians(config.closure_edge_sigma_deg) ** 2])
            estimate = self._edges.get((min(a, b), max(a, b)))
            if estimate is not None:
                measured = np.linalg.inv(estimate.information)
                if a > b:  # kept as T_ba: its covariance in a's frame
                    measured = inverse_with_covariance(self.graph.edge(b, a), measured)[1]
                edge_cov = edge_cov + measured
            pose, covariance = compose_with_covariance(pose, covariance, pose_ab, edge_cov)
        return pose, covariance

    def closure_distance(
        self, path: list[int], pose_uv: NDArray[np.float64], covariance: NDArray[np.float64] | None = None
    ) -> float:
        """The squared Mahalanobis distance between a loop closure's measured ``T_uv`` (with its
        ``covariance``) and the pose composed along the graph's ``path`` from u to v: how well the
        closure agrees with the odometry chain and the edges between its places. A look-alike place
        matched instead of the right one sits a room, a corridor's length or a half turn away from
        where the chain puts it; the chain's uncertainty grows with its edges, so a long way round
        admits more (the right place still agrees)."""
        composed, chain_covariance = self.chain(path)
        total = chain_covariance + (np.zeros((3, 3)) if covariance is None else np.asarray(covariance, dtype=np.float64))
        difference = np.asarray(pose_uv, dtype=np.float64) - composed
        difference[2] = wrap_angle(difference[2])
        return float(difference @ np.linalg.solve(total + np.diag([1e-6, 1e-6, 1e-8]), difference))

    # -- graph changes -----------------------------------------------------------------------------

    def _switch(self, vertex: int, pose_in_vertex: NDArray[np.float64], covariance: NDArray[np.float64] | None = None) -> None:
        if self.current is not None and vertex != self.current:
            self._left[self.current] = self._odom.metres
        self._odometer_verified = self._odom.metres
        self.current = vertex
        self.pose_in_current = np.asarray(pose_in_vertex, dtype=np.float64).copy()
        self.pose_covariance = np.zeros((3, 3)) if covariance is None else np.asarray(covariance, dtype=np.float64).copy()

    def _located_covariance(self, located: Localized) -> NDArray[np.float64]:
        """The covariance of a verified pose: the match's, or, where ``verify`` kept the guess (too
        little shared area to trust the match's pose), the pose's own carried along."""
        covariance = located.result.covariance
        if covariance is None or located.result.overlap < self.matching.min_overlap:
            return self.pose_covariance.copy()
        return covariance

    def _through(
        self, robot: NDArray[np.float64], robot_covariance: NDArray[np.float64], located: Localized
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The located vertex's centre in the frame the robot's pose ``robot`` is given in (one
        scan matched against both), and its covariance: an edge's measurement."""
        return compose_with_covariance(
            robot, robot_covariance, *inverse_with_covariance(located.pose, self._located_covariance(located))
        )

    @staticmethod
    def _canonical(u: int, v: int, pose_uv: NDArray[np.float64], covariance: NDArray[np.float64]) -> tuple:
        """(u, v, T_uv, covariance) with u < v, as edges are kept."""
        if u < v:
            return u, v, pose_uv, covariance
        return v, u, *inverse_with_covariance(pose_uv, covariance)

    def _measure_edge(self, u: int, v: int, pose_uv: NDArray[np.float64], covariance: NDArray[np.float64]) -> bool:
        """Fuse a measurement of the existing edge (u, v) into it; refused (False) when it disagrees
        with the edge by more than ``edge_tolerance`` or 5°, or the edge has all the measurements it takes."""
        u, v, pose_uv, covariance = self._canonical(u, v, pose_uv, covariance)
        estimate = self._edges.get((u, v))
        if estimate is None:  # an edge of a loaded graph: its stored pose counts as one measurement
            estimate = self._edges[(u, v)] = EdgeEstimate.first(self.graph.edge(u, v), covariance)
        if estimate.count >= self.config.edge_measurements:
            return False
        step = between(estimate.pose, pose_uv)
        if float(np.hypot(step[0], step[1])) > self.config.edge_tolerance or abs(step[2]) > np.radians(5.0):
            return False
        estimate.fuse(pose_uv, covariance)
        self.graph.add_edge(u, v, estimate.pose)
        self.counters.edge_refinements += 1
        return True

    def _new_edge(self, u: int, v: int, pose_uv: NDArray[np.float64], covariance: NDArray[np.float64]) -> None:
        u, v, pose_uv, covariance = self._canonical(u, v, pose_uv, covariance)
        self._edges[(u, v)] = EdgeEstimate.first(pose_uv, covariance)
        self.graph.add_edge(u, v, pose_uv)

    def _add_vertex(self, grid, points, odom, stamp: float, edge_from_current: bool) -> None:
        vertex = self.graph.add_vertex(CroppedGrid.from_grid(grid), self.describe(points), odom, stamp, self._odom.metres)
        self._odometer_at_vertex[vertex] = self._odom.metres
        self.counters.new_vertices += 1
        if edge_from_current and self.current is not None:
            self._new_edge(self.current, vertex, self.pose_in_current, self.pose_covariance)
        self._switch(vertex, np.zeros(3))
