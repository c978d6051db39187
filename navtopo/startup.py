"""NavTopo's start-up localization: where the robot is, found without a pose and confirmed over
motion (Muravyev & Yakovlev, Sec. "Localization"; the confirmation goes beyond the paper).

Hypotheses (``Startup``). The robot is given no pose. Each *look* (after every 0.25 m or 15° of
motion, the graph maintainer's cadence) retrieves the ``top_k`` locations whose descriptors are
nearest to the scan's and verifies each by scan matching — every location instead at a look with no
hypothesis or one alone (at most once a metre), and before a commitment (``check_all``: place
recognition may rank the right place far down); a verified candidate that no live hypothesis explains
becomes a hypothesis ``(vertex, pose)``, tracked from then on by odometry and scan matching like the
robot itself (inside its location, or along an edge). While rivals live, a look verifies only by
the thresholds without a guess.

Evidence against a hypothesis: the ledger both systems' start-ups share (``navkit.hypotheses``).
A look that verifies a hypothesis supports it. A look that fails it counts against it only where it
tells the hypotheses apart: some other hypothesis was verified at that look. A look that verifies
none of them (turning on the spot, a scan the matcher cannot use) is no evidence for any place over
another: it drops nobody, else the right place falls with the wrong ones and a look-alike the next
look happens to verify is left alone (on a generated wing of identical rooms, 7 of 35 start-ups
committed 3.6-14 m off that way); nor is a look that verifies all of them. Each telling look against
a hypothesis adds one to its count against, each telling look for it takes one off (never below
zero): it is dropped when the count reaches ``drop_after``, or after ``drop_unverified`` looks in a
row that did not verify it. A place the scan contradicts falls within ``drop_after`` looks; the
right place, verified at most looks, and its exact look-alikes, verified as often, stay (dropped
after a few looks in a row against it, the right place fell by chance among a dozen look-alikes
while one of them stayed). A hypothesis alone is dropped only after ``drop_unverified`` looks
(between locations, in a corridor that fixes the pose along it poorly, the matcher refuses looks in
a row); meanwhile every location is checked once a metre, and a place verified elsewhere becomes a
rival that the next looks weigh.

The far evidence. The matcher lets a few per cent of a grid's walls disagree, and along a corridor of
identical rooms the places a room apart differ by fewer: by the beams that reach the corridor's end.
So among rivals each look also counts the scan's beams each hypothesis's map contradicts
(``beam_contradictions``), and counts the look against a hypothesis with ``far_margin`` more than the
least contradicted one; a verified candidate so contradicted is not made a hypothesis (it would come
back at every look and keep a rival alive). Nor is one, found while others have been followed, that
explains the last ``far_history`` looks (kept one a metre) worse than they do: a look-alike ruled out
at a corridor's end is found again in the next identical room, where no beam reaches the end.

The commitment rule, as a test. Commit to ``h`` only when all of these hold:
  1. ``h`` is the only hypothesis left, and the look that commits verified it;
  2. it has been verified at ``confirm_looks`` looks and survived ``confirm_distance`` metres, and
     in ``confirm_places`` locations at places ``confirm_span`` metres apart (or, if set, over
     ``confirm_distance_one_place`` metres): a room and its look-alike agree from inside however far
     the robot drives about it (a start in a room the map never entered, 8.9 m of dithering in it,
     committed 5.3 m off to the one room elsewhere that matched), the corridor outside the door
     tells them apart; and a location's grid reaches into the rooms round it, so the look-alike's
     tracker changed location while the robot was still in the room (committed 5.3 m off again);
  3. since its last rival fell it has been verified at ``confirm_alone_looks`` looks over
     ``confirm_alone_distance`` metres (a rival dropped at one look may have been the right place:
     place recognition and every location's check get the chance to find it again);
  4. every location checked at this look (``check_all``) verifies nowhere farther than
     ``same_place`` from ``h``.
Else the robot keeps driving and looking; after ``timeout`` seconds without a commitment the trial
fails with ``not_localized``: a wrong localization is worse than none.

Moving meanwhile. The navigator (``navtopo.navigation``) drives toward the goal as the best
hypothesis sees it (so confirmation costs no detour when the best is right), or, with no hypothesis
(or none that gets anywhere, or look-alikes as well supported as the best: ``ambiguous``), the
``Explorer`` moves in the robot's own scan toward the free point
farthest from where it has driven (out of a room through its door rather than round it again).
Both are blind moves — a path in one scan's grid, or in a map that may be another place's — so
both are checked against every new scan (``Explorer.scan_on_path``).

Frames: a hypothesis's pose is the robot's in its vertex's frame (``navtopo.mapping``); an
exploring move's path is in the odometry frame of the pose it started from; the trail is in the
odometry frame.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy.ndimage import maximum_filter1d

from navkit.geometry import between, compose, transform_points, wrap_angle
from navkit.hypotheses import Tally, settle, weigh
from navkit.odometer import Odometer
from navkit.raster import FREE, OCCUPIED, UNKNOWN
from navkit.scan import azimuth_bins, obstacle_points
from navkit.scan_grid import GridConfig, grid_from_points
from navkit.types import Observation
from navtopo.mapping import GraphMaintainer, moved_enough, weak_direction
from navtopo.planning import UnionGrid, build_union_grid
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
    confirm_span: float = Field(
        3.0,
        ge=0,
        description="... and at places this far apart (m, by odometry): a location's grid reaches into the rooms round "
        "it, so a look-alike room's tracker changed location without the robot leaving the room",
    )
    confirm_distance_one_place: float | None = Field(
        None,
        ge=0,
        description="... unless it has survived this many m of motion (default: never; driving about a room does not "
        "tell it from a look-alike room elsewhere)",
    )
    drop_after: int = Field(
        3, ge=1, description="looks against a hypothesis (another one verified, it not), less those for it, that drop it"
    )
    drop_unverified: int = Field(
        6, ge=1, description="looks in a row that verify a hypothesis not at all drop it (no other one verified either)"
    )
    confirm_alone_looks: int = Field(
        3, ge=1, description="looks that must verify a hypothesis after its last rival fell before it is committed"
    )
    confirm_alone_distance: float = Field(
        1.0, ge=0, description="m of motion a hypothesis must survive after its last rival fell before it is committed"
    )
    same_place: float = Field(1.0, gt=0, description="m: candidates this close (through the graph) are one hypothesis")
    same_place_in_map: float = Field(
        1.5, gt=0, description="m: ... or this close by the locations' map poses, where the graph does not join them"
    )
    far_evidence: bool = Field(
        True,
        description="weigh the hypotheses by the scan's beams against each one's map beyond the matcher's verdict (see "
        "``beam_contradictions``)",
    )
    far_tolerance: float = Field(
        0.5, gt=0, description="m a beam must run past a mapped wall (or end clear of one) to contradict"
    )
    far_margin: int = Field(
        6, ge=1, description="contradicted beams beyond the fewest among the hypotheses that count a look against one ..."
    )
    far_margin_share: float = Field(0.015, ge=0, le=1, description="... or this share of the beams, if more")
    union_radius: float = Field(20.0, gt=0, description="m: half the side of a hypothesis's map (its location and neighbours)")
    far_history: int = Field(
        8,
        ge=0,
        description="earlier looks (one a metre, beams 2° apart) a place found while others live must explain: refused "
        "with twice far_margin more contradicted beams in all than the least",
    )
    ambiguous_looks: int = Field(8, ge=1, description="looks after which equally supported rivals make the robot explore ...")
    ambiguous_support: int = Field(2, ge=0, description="... 'equally': the two best supports this close")
    lone_explore_distance: float = Field(
        6.0,
        ge=0,
        description="m driven by a lone hypothesis verified in one location before the robot explores instead (driving "
        "by the right one toward the goal leaves the room; by a look-alike of a room the map never entered, it may not)",
    )
    explore_distance: float = Field(1.5, gt=0, description="m: with no hypothesis, drive this far toward open space")
    timeout: float = Field(90.0, gt=0, description="s of simulated time without a commitment: not_localized")
    prior_search: float = Field(
        1.5,
        gt=0,
        description="m: a given initial pose (map frame) is taken where a match puts the robot at most this far from it "
        "(its error, and the drift of the locations' map poses) ...",
    )
    prior_yaw_deg: float = Field(20.0, gt=0, description="... and at most this many degrees from its heading")
    prior_locations: int = Field(3, ge=1, description="the locations nearest a given pose that are matched against")
    prior_distance: float = Field(
        3.0, ge=0, description="m of motion the given pose is tried for (carried by odometry); then the start-up goes on without"
    )
    prior_strict: bool = Field(
        True,
        description="a match seeded by the given pose is judged by the verdict without a guess (wall agreement 96 %, "
        "score 0.4): with the guess's verdict (90 %, 0.1) a location seen through a thin wall from its other side "
        "agreed at 0.3-0.6 m off (office02, both settings: the two faces of the wall paired as one)",
    )
    prior_gate: float = Field(
        2.0,
        ge=0,
        description="m: with a given initial pose, a place found later is made a hypothesis only this far (plus "
        "prior_gate_per_m of the metres driven) from the pose carried there by odometry: the given pose's error "
        "(0.71 m at most by the protocol) and the locations' map-pose drift; look-alikes farther off are no rivals, "
        "as an initial pose confines AMCL's particles (0: no gate)",
    )
    prior_gate_per_m: float = Field(0.1, ge=0, description="m the gate grows per metre driven (the odometry's drift)")


@dataclass(eq=False)
class Hypothesis(Tally):
    """Where the robot may be: a location and the pose in it, tracked by a graph maintainer of its own;
    its looks for and against it in the ledger (``navkit.hypotheses.Tally``)."""

    tracker: GraphMaintainer
    odometer_start: float  # the robot's odometer when it was found
    places: set[int] = field(default_factory=set)  # the locations it was verified in
    contradicted: int = 0  # the scan's beams its map contradicted at the last look weighed by the far evidence
    spots: list[NDArray[np.float64]] = field(default_factory=list)  # odometry xy of its verified looks, 0.5 m apart

    def verified_at(self, odom: NDArray) -> None:
        """A look verified it with the robot at ``odom`` (odometry frame)."""
        xy = np.asarray(odom, dtype=np.float64)[:2].copy()
        if not self.spots or float(np.hypot(*(xy - self.spots[-1]))) >= 0.5:
            self.spots.append(xy)

    @property
    def span(self) -> float:
        """m between the two farthest apart places it was verified at."""
        if len(self.spots) < 2:
            return 0.0
        spots = np.array(self.spots)
        return float(np.hypot(*(spots[:, None, :] - spots[None, :, :]).transpose(2, 0, 1)).max())

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
    given_pose: bool = False  # committed from the given initial pose (``Startup.from_prior``)

    def as_json(self) -> dict:
        return {
            "started": self.started,
            "stamp": self.stamp,
            "seconds": round(self.stamp - self.started, 3),
            "vertex_stamp": self.vertex_stamp,
            "pose": [float(v) for v in self.pose],
            "looks": self.looks,
            "hypotheses": self.hypotheses,
            "given_pose": self.given_pose,
        }


WALL_WIDTH_M = 0.3  # a wall the far evidence counts a beam through is at least this wide across the beam


def scan_beams(points: NDArray, band: GridConfig, step_deg: float = 1.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The scan as beams: the nearest obstacle return in each ``step_deg`` of azimuth, (angles,
    ranges) in the robot frame, for the bins that have one (a bin without a return says nothing)."""
    xy = np.asarray(obstacle_points(points, band)[:, :2], dtype=np.float64)
    ranges = np.hypot(xy[:, 0], xy[:, 1])
    xy, ranges = xy[ranges > 0.05], ranges[ranges > 0.05]
    if not len(ranges):
        return np.zeros(0), np.zeros(0)
    angles = np.arctan2(xy[:, 1], xy[:, 0])
    bins = azimuth_bins(xy, int(round(360.0 / step_deg)))
    order = np.lexsort((ranges, bins))
    first = order[np.r_[True, bins[order][1:] != bins[order][:-1]]]
    return angles[first], ranges[first]


def beam_contradictions(union: UnionGrid, pose: NDArray, angles: NDArray, ranges: NDArray, tolerance: float) -> int:
    """How many of the scan's beams (``scan_beams``) contradict the map ``union`` (a location's
    grid and its neighbours', ``planning.build_union_grid`` unturned) with the robot at ``pose`` in
    the location's frame:

    * *through a wall*: the beam crosses a mapped wall and runs on at least ``tolerance`` beyond it
      (the scan sees open floor where the map has a wall). Only a crossing counts: a wall cell
      followed ``tolerance`` further on by one that is not a wall, with wall cells
      ``WALL_WIDTH_M / 2`` to either side of the beam there (a beam along a wall at a grazing angle,
      or past the end of a door's jamb a few centimetres off, has free space to one side);
    * *a phantom return*: the return lies in mapped free space at least ``tolerance`` from every
      mapped wall (the scan sees a wall where the map has open floor).

    Unknown cells contradict nothing. Scan matching verifies a place by the agreement of walls
    within its grid, a few per cent of them allowed to disagree; two look-alike places along a
    corridor of identical rooms differ by the few beams that reach the corridor's end, which this
    counts."""
    if not len(ranges):
        return 0
    res = union.frame.resolution
    steps = np.arange(0.3, float(ranges.max()) + res, res)
    offset = max(1, int(round(tolerance / res)))
    direction = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    across = np.stack([-direction[:, 1], direction[:, 0]], axis=1) * WALL_WIDTH_M / 2
    points = direction[:, None, :] * steps[None, :, None]  # (B, S, 2)

    def wall_at(shift: NDArray) -> NDArray[np.bool_]:
        xy = transform_points(pose, (points + shift[:, None, :]).reshape(-1, 2))
        return union.values_at(xy, union.cells, UNKNOWN).reshape(points.shape[:2]) == OCCUPIED

    wall = wall_at(np.zeros_like(across))
    # a wall, not the end of a door's jamb or a wall the beam runs along: walls on both sides of the
    # beam too, within two samples along it (a wall crossed at a slant)
    sides = [maximum_filter1d(wall_at(side), size=5, axis=1) for side in (across, -across)]
    crossing = wall & sides[0] & sides[1]
    before = steps[None, :-offset] <= (ranges[:, None] - tolerance)  # a sample with `tolerance` of the beam beyond it
    through = (crossing[:, :-offset] & ~wall[:, offset:] & before).any(axis=1)
    ends = transform_points(pose, direction * ranges[:, None])
    open_floor = union.values_at(ends, union.cells, UNKNOWN) == FREE
    phantom = open_floor & union.clear_of_walls(ends, tolerance, outside=False)
    return int(np.count_nonzero(through | phantom))


class Startup:
    """Hypotheses of where the robot starts, looked for and confirmed over motion."""

    map_poses: NDArray[np.float64] | None = None  # (V, 3) the locations in the map frame (navtopo.graph_poses)

    def __init__(self, maintainer: GraphMaintainer, describe, config: StartupConfig) -> None:
        self.maintainer = maintainer
        self.describe = describe
        self.config = config
        self.reset()

    def reset(self) -> None:
        self._prior: NDArray[np.float64] | None = None  # the given initial pose, map frame (``set_prior``)
        self._first_odom: NDArray[np.float64] | None = None  # the odometry at the start-up's first tick
        self.from_given_pose = False  # the commitment came from the given pose
        self.hypotheses: list[Hypothesis] = []
        self.looks = 0
        self.started: float | None = None
        self._last_look_odom: NDArray[np.float64] | None = None
        self._odom = Odometer()
        self._checked_at = -np.inf  # the odometer at the last look that verified every location
        self._perceived: tuple[float, PreparedGrid, NDArray[np.float32]] | None = None  # (stamp, query, descriptor)
        self.seen = 0
        self.checks = 0
        self._unions: dict[int, UnionGrid] = {}  # the hypotheses' maps, for the far evidence
        self._beams: tuple[float, NDArray[np.float64], NDArray[np.float64]] | None = None  # (stamp, angles, ranges)
        # earlier looks' beams (odometry, angles, ranges), one a metre: what a place found late must explain too
        self._history: deque[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]] = deque(
            maxlen=self.config.far_history
        )
        self._history_at = -np.inf  # the odometer at the last look kept
        self.far_dropped = 0  # looks that counted against a hypothesis by the far evidence alone
        self.far_refused = 0  # verified candidates not made hypotheses by it
        self.prior_refused = 0  # verified candidates not made hypotheses: too far from the given pose (``prior_gate``)

    def set_prior(self, pose: NDArray) -> None:
        """A given initial pose (3,, map frame; the protocol's ``perturbed`` start): tried at each look
        while the robot has driven under ``prior_distance`` (``from_prior``)."""
        self._prior = np.asarray(pose, dtype=np.float64).copy()

    def from_prior(self, obs: Observation) -> Hypothesis | None:
        """A start from the given pose (``set_prior``; the robot now by it, map frame, carried by
        odometry from the start-up's first tick): the scan matched against the ``prior_locations``
        locations whose map poses lie nearest it, each from the pose the prior puts the robot at in it
        (the thresholds with a guess, and the known area shared that a match without one needs: a
        match that shares less keeps the guess as its pose); the first match that puts the robot within ``prior_search`` and
        ``prior_yaw_deg`` of the prior, as a committed hypothesis. None: none did (the start-up looks
        on, the prior tried again at the next look while the robot has driven under ``prior_distance``).

        As a person sets a pose by hand for a metric system: no rival is weighed; the prior rules out
        every place farther off, look-alikes included."""
        if self._prior is None or self.map_poses is None or not len(self.map_poses):
            return None
        if self._odom.metres > self.config.prior_distance or self._first_odom is None:
            return None
        prior = self._carried_prior(obs.odom)
        assert prior is not None
        query, _ = self._perceive(obs)
        localizer, config = self.maintainer.localizer, self.config
        nearest = np.argsort(np.hypot(*(self.map_poses[:, :2] - prior[:2]).T), kind="stable")[: config.prior_locations]
        for vertex in (int(v) for v in nearest):
            guess = between(self.map_poses[vertex], prior)
            if float(np.hypot(guess[0], guess[1])) > self.maintainer.grid_config.radius:
                break  # the robot is off that location's grid: farther ones even more so
            located = localizer.verify(query, vertex, guess, config.prior_search, strict=config.prior_strict)
            if located is None or located.result.overlap < localizer.matching.min_overlap:
                continue  # a match that shares little with the location keeps the guess: no evidence
            if weak_direction(located.result.covariance, self.maintainer.config.degenerate_ratio) is not None:
                # along an aisle the match fixes nothing: it slid 0.56 m from a given pose 0.37 m off and
                # was committed (a generated rack hall, closed walls); a later look sees an end
                continue
            placed = compose(self.map_poses[vertex], located.pose)
            off_yaw = abs(float(np.degrees(wrap_angle(placed[2] - prior[2]))))
            if float(np.hypot(*(placed[:2] - prior[:2]))) > config.prior_search or off_yaw > config.prior_yaw_deg:
                continue
            tracker = self._tracker(vertex, located.pose, obs.odom)
            tracker.last_verified = True
            self.seen += 1
            self.from_given_pose = True
            return Hypothesis(tracker=tracker, odometer_start=self._odom.metres, places={vertex}, alone_since=self._odom.metres)
        return None

    def _carried_prior(self, odom: NDArray) -> NDArray[np.float64] | None:
        """The given initial pose carried by odometry to the robot now (map frame), or None."""
        if self._prior is None or self._first_odom is None:
            return None
        return compose(self._prior, between(self._first_odom, odom))

    def _near_prior(self, vertex: int, pose: NDArray, odom: NDArray) -> bool:
        """Could the robot be at ``pose`` in ``vertex`` by the given initial pose? True without one
        (the kidnapped protocol) or without map poses; else within ``prior_gate`` (grown by
        ``prior_gate_per_m`` a metre driven) of the prior carried by odometry."""
        prior = self._carried_prior(odom)
        if prior is None or self.map_poses is None or not self.config.prior_gate:
            return True
        placed = compose(self.map_poses[vertex], pose)
        gate = self.config.prior_gate + self.config.prior_gate_per_m * self._odom.metres
        return float(np.hypot(*(placed[:2] - prior[:2]))) <= gate

    def _tracker(self, vertex: int, pose: NDArray, odom: NDArray) -> GraphMaintainer:
        m = self.maintainer
        tracker = GraphMaintainer(m.graph, m.describe, m.grid_config, m.matching, m.config, m.localizer.config, False, m.grids)
        tracker.start_at(vertex, pose, odom)
        return tracker

    def _due(self, odom: NDArray) -> bool:
        if self._last_look_odom is None:
            return True
        return moved_enough(self._last_look_odom, odom, self.maintainer.config)

    def step(
        self, obs: Observation, driven: Hypothesis | None = None, route: list[int] | None = None, force: bool = False
    ) -> Hypothesis | None:
        """One tick: track the hypotheses, look when due (or ``force``); the committed hypothesis, or
        None. ``driven``: the hypothesis the robot drives by, which follows ``route`` (its global
        path) from location to location as the committed state would."""
        if self.started is None:
            self.started = obs.stamp
            self._first_odom = np.asarray(obs.odom, dtype=np.float64).copy()
        self._odom.update(obs.odom)
        for h in self.hypotheses:
            h.tracker.integrate(obs.odom)
        if not (force or self._due(obs.odom)):
            return None
        self._last_look_odom = np.asarray(obs.odom, dtype=np.float64).copy()
        self.looks += 1
        given = self.from_prior(obs)
        if given is not None:
            return given
        self._look(obs, driven, route)
        last = self._odom.last
        if self.config.far_evidence and last is not None and self._odom.metres >= self._history_at + 1.0:
            self._history_at = self._odom.metres
            self._history.append((last.copy(), *scan_beams(obs.points, self.maintainer.grid_config, 2.0)))
        committed = self._committed()
        if committed is not None and self.config.check_all and self._odom.metres > self._checked_at:
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
            if not h.tracker.last_verified:
                self._relocate(h, self._perceive(obs)[0], obs.odom)
        self._weigh(self._far_against(obs))
        alone = len(self.hypotheses) == 1
        check_all = self.config.check_all and (not self.hypotheses or alone) and self._odom.metres >= self._checked_at + 1.0
        self._recognise(obs, check_all)

    def _weigh(self, far: list[bool] | None = None) -> None:
        """This look's evidence by the ledger's rule (``navkit.hypotheses.weigh``; ``far``: the far
        evidence counts the look against the hypothesis): the dropped ones gone; each one the look
        was for, verified in its location here."""
        config = self.config
        verified = [h.tracker.last_verified for h in self.hypotheses]
        self.far_dropped += sum(bool(bad) for bad in far or [])
        self.hypotheses, looked_for = weigh(
            self.hypotheses, verified, far, self._odom.metres, config.drop_after, config.drop_unverified
        )
        for h in looked_for:
            h.places.add(h.vertex)
            if (last := self._odom.last) is not None:
                h.verified_at(last)

    def _recognise(self, obs: Observation, check_all: bool) -> int:
        """New hypotheses from place recognition's ``top_k`` (or every location), verified by scan
        matching; how many were added."""
        m = self.maintainer
        query, descriptor = self._perceive(obs)
        if check_all:
            self._checked_at = self._odom.metres
            self.checks += 1
        top_k = len(m.graph) if check_all else self.config.top_k
        found = m.localizer.localize(query, descriptor, top_k=top_k)
        new = [loc for loc in found if not any(self._same_place(h, loc.vertex, loc.pose) for h in self.hypotheses)]
        near = [loc for loc in new if self._near_prior(loc.vertex, loc.pose, obs.odom)]
        self.prior_refused += len(new) - len(near)
        new = near
        if self.config.far_evidence and new and len(self.hypotheses) + len(new) > 1:
            # a place the far evidence counts against at this look is not made a hypothesis (it
            # would come back at every look and keep a rival alive)
            places = [(h.vertex, h.pose) for h in self.hypotheses] + [(loc.vertex, loc.pose) for loc in new]
            keep = ~self._far_outliers(obs, self._far_counts(obs, places))[len(self.hypotheses) :]
            if self.hypotheses and self._history and keep.any():
                # a place found now while others have been followed for a while must explain the
                # robot's earlier looks as well as they do: a look-alike the far evidence ruled out
                # a few metres back is found again as soon as the beams no longer reach what told
                # them apart (inside the next identical room), and would keep a rival alive for good
                live = len(self.hypotheses)
                later = [i for i in range(len(new)) if keep[i]]
                replayed = self._replayed(obs, places[:live] + [places[live + i] for i in later])
                refused = replayed[live:] >= replayed.min() + 2 * self.config.far_margin
                keep[[i for i, r in zip(later, refused, strict=True) if r]] = False
            self.far_refused += int(np.count_nonzero(~keep))
            new = [loc for loc, kept in zip(new, keep, strict=True) if kept]
        added = 0
        for located in new:
            if not any(self._same_place(h, located.vertex, located.pose) for h in self.hypotheses):
                tracker = self._tracker(located.vertex, located.pose, obs.odom)
                tracker.last_verified = True  # this look verified it
                hypothesis = Hypothesis(tracker=tracker, odometer_start=self._odom.metres, places={located.vertex})
                hypothesis.verified_at(obs.odom)
                self.hypotheses.append(hypothesis)
                self.seen += 1
                added += 1
        settle(self.hypotheses, self._odom.metres)  # a new rival: nobody is alone; a first find: alone from now
        return added

    def _far_against(self, obs: Observation) -> list[bool]:
        """For each live hypothesis: does the far evidence count this look against it? Among rivals
        only: a hypothesis whose map the scan's beams contradict (``beam_contradictions``) at
        ``far_margin`` beams (or ``far_margin_share`` of them) more than the least contradicted one's.
        The right place and its exact look-alikes agree within the matcher's grid; the beams that
        reach farther (a corridor's end, a junction) tell them apart."""
        # the maps kept: the live hypotheses' (a lone one's too: candidates found later are weighed
        # against it at every look)
        in_use = {h.vertex for h in self.hypotheses}
        self._unions = {v: u for v, u in self._unions.items() if v in in_use}
        if not self.config.far_evidence or len(self.hypotheses) < 2:
            return [False] * len(self.hypotheses)
        counts = self._far_counts(obs, [(h.vertex, h.pose) for h in self.hypotheses])
        for h, count in zip(self.hypotheses, counts, strict=True):
            h.contradicted = int(count)
        return [bool(x) for x in self._far_outliers(obs, counts)]

    def _far_counts(self, obs: Observation, places: list[tuple[int, NDArray]]) -> NDArray[np.int64]:
        if self._beams is None or self._beams[0] != obs.stamp:
            self._beams = (obs.stamp, *scan_beams(obs.points, self.maintainer.grid_config))
        _, angles, ranges = self._beams
        return np.array(
            [beam_contradictions(self._union(v), pose, angles, ranges, self.config.far_tolerance) for v, pose in places]
        )

    def _replayed(self, obs: Observation, places: list[tuple[int, NDArray]]) -> NDArray[np.int64]:
        """For each place (vertex, the robot's pose in it now): the beams of the kept earlier looks
        (``far_history``, one a metre) its map contradicts, the robot carried back to each by odometry."""
        now = np.asarray(obs.odom, dtype=np.float64)
        totals = np.zeros(len(places), np.int64)
        for odom, angles, ranges in self._history:
            back = between(now, odom)  # the earlier pose in the current robot frame
            for k, (vertex, pose) in enumerate(places):
                totals[k] += beam_contradictions(
                    self._union(vertex), compose(pose, back), angles, ranges, self.config.far_tolerance
                )
        return totals

    def _far_outliers(self, obs: Observation, counts: NDArray[np.int64]) -> NDArray[np.bool_]:
        assert self._beams is not None and self._beams[0] == obs.stamp
        margin = max(self.config.far_margin, self.config.far_margin_share * len(self._beams[2]))
        return counts >= counts.min() + margin

    def _union(self, vertex: int) -> UnionGrid:
        union = self._unions.get(vertex)
        if union is None:
            m = self.maintainer
            union = build_union_grid(m.graph, vertex, m.grid_config, self.config.union_radius, align=False)
            self._unions[vertex] = union
        return union

    def _perceive(self, obs: Observation) -> tuple[PreparedGrid, NDArray[np.float32]]:
        """The look's scan prepared for matching, and its descriptor (once a look, though asked twice)."""
        m = self.maintainer
        if self._perceived is None or self._perceived[0] != obs.stamp:
            query = prepare(grid_from_points(obs.points, m.grid_config), m.grid_config, m.matching)
            self._perceived = (obs.stamp, query, self.describe(obs.points))
        return self._perceived[1], self._perceived[2]

    def _relocate(self, h: Hypothesis, query: PreparedGrid, odom: NDArray) -> bool:
        """A hypothesis its tracker did not verify, checked again where it puts the robot: in its
        location and the neighbouring ones, at the pose the edges predict, within
        ``max_neighbour_jump``. A tracker keeps its location until the robot leaves its reach and may
        refuse corrections there while the robot has crossed into the next one (out of a room into
        the corridor): the hypothesis is a place, not the location it is kept in, and the right
        place lost three looks that way while a look-alike's tracker crossed (on a generated wing,
        a start-up committed 12.5 m off). Re-verified: tracked from that location on."""
        graph, config = self.maintainer.graph, self.maintainer.config
        candidates = [(h.vertex, np.zeros(3))] + graph.neighbours(h.vertex)
        for vertex, pose_uv in candidates:
            guess = between(pose_uv, h.pose)  # the robot in that location's frame, by the edge
            if float(np.hypot(guess[0], guess[1])) > config.max_edge_length:
                continue
            located = h.tracker.localizer.verify(query, vertex, guess, config.max_neighbour_jump)
            if located is not None:
                h.tracker.start_at(vertex, located.pose, odom)
                h.tracker.last_verified = True
                return True
        return False

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
        """The hypothesis that passes points 1-3 of the commitment rule (the module docstring), or None."""
        if len(self.hypotheses) != 1:
            return None
        h, config = self.hypotheses[0], self.config
        if not h.tracker.last_verified or h.alone_since is None:
            return None
        moved = self._odom.metres - h.odometer_start
        if h.support < config.confirm_looks or moved < config.confirm_distance:
            return None
        if h.alone_looks < config.confirm_alone_looks or h.alone_for(self._odom.metres) < config.confirm_alone_distance:
            return None
        # a room and its mirror image agree from inside; the corridor outside the door tells them apart
        one_place = config.confirm_distance_one_place
        if len(h.places) >= config.confirm_places and h.span >= config.confirm_span:
            return h
        if one_place is not None and moved >= one_place:
            return h
        return None

    def timed_out(self, stamp: float) -> bool:
        """More than ``timeout`` s since the start-up began: the trial fails with ``not_localized``."""
        return self.started is not None and stamp - self.started > self.config.timeout

    @property
    def odometer(self) -> float:
        """Metres of odometry since the start-up began."""
        return self._odom.metres

    def ambiguous(self) -> bool:
        """Two or more hypotheses equally supported (within ``ambiguous_support`` looks) after
        ``ambiguous_looks`` looks: exact look-alikes, which driving by one of them toward the goal
        need never tell apart (along a corridor of identical rooms it may stop between them); the
        robot explores instead, away from where it has driven, toward a corridor's end or a
        junction, which the far evidence tells apart. Or one hypothesis alone, verified at twice
        ``ambiguous_looks`` looks in fewer than ``confirm_places`` locations, driven by for
        ``lone_explore_distance``: it cannot be committed until the robot leaves the location, and
        driving by it did not (a start in a room the map never entered, driving by its look-alike
        elsewhere, went round that room for 90 s). Not sooner: driving by the right place toward the
        goal leaves the room, and exploring from the start (16 looks, 3.4 m) kept a robot in its
        room for 90 s."""
        if len(self.hypotheses) == 1:
            # one place, verified for twice as long in one location alone: driving by it has not left
            # the room (it may be a look-alike of a room the map never entered), and only a second
            # location can confirm it
            h, config = self.hypotheses[0], self.config
            return (
                len(h.places) < config.confirm_places
                and h.support >= 2 * config.ambiguous_looks
                and self._odom.metres - h.odometer_start >= config.lone_explore_distance
            )
        if len(self.hypotheses) < 2:
            return False
        first, second = sorted((h.support for h in self.hypotheses), reverse=True)[:2]
        return first >= self.config.ambiguous_looks and first - second <= self.config.ambiguous_support

    def best(self) -> Hypothesis | None:
        """The hypothesis to drive by while none is committed: most supported."""
        return max(self.hypotheses, key=lambda h: h.support, default=None)
