"""The metric baseline's pose on its map while it navigates (DESIGN.md): the ``map -> odom`` chain.

As a Nav2 user runs a robot: the initial pose is given in the map frame by hand (off by up to the
protocol's ±0.5 m, ±10°). Odometry (``navkit.odometry.LidarOdometry``, restarted at every initial
pose) is composed onto it through ``map_from_odom``. Until the pose has been found on the map, each
scan is searched for around the estimate, then over the whole map (``localization.Relocalizer``);
while none is found the caller turns in place, and gives up after the relocalization timeout. Once
found, every ``every_scans``-th scan is registered to the map (``localization.ScanToMap``) and an
accepted fit moves ``map_from_odom``; after ``lost_after`` rejected fits in a row, the window around
the estimate is searched again. The tracker is ``lost`` from a window search that finds nothing to
the next accepted fit (the system's failure stage ``localization`` meanwhile).

Kidnapped (the protocol's ``initial_pose: none``: no pose given): the places the scan may be at are
followed as hypotheses and weighed look by look by the ledger NavTopo's start-up uses too
(``navkit.hypotheses``). A look comes at the first scan and after every ``look_turn_deg`` of
turning or ``look_distance`` of motion. Each look
fits the scan where odometry carried each hypothesis (``ScanToMap.refine``; a fit that moves it more
than ``confirm_xy`` or ``confirm_yaw_deg`` does not verify it) and searches the whole map
(``Relocalizer.places``). A look where the scan fits somewhere weighs the hypotheses against the best
fit: one that fits within ``min_margin`` of it is verified; one that does not is counted against;
when the look tells them apart so (some verified, some not), the verified ones get one off their
count. A look that verifies all of them, or fits nowhere, is no evidence for one place over another.
A hypothesis is dropped when its count reaches ``drop_after``. A place the search finds within
``min_margin`` of the best that no hypothesis explains becomes one, unless others are followed and
it fits one of the last ``recheck_looks`` looks worse than the best place then did (a look-alike
dropped where the views told it apart would come back wherever they do not).

The pose is taken when one hypothesis is left, the look verified it, and it has been verified at
``confirm_looks`` looks spread over ``confirm_turn_deg`` of turning and ``confirm_distance`` of motion,
the last ``confirm_alone_looks`` of them over ``confirm_alone_distance`` since its last rival fell.
One view of a place can fit a look-alike elsewhere, and a building symmetric under a half turn fits
every view from one spot (on loop_office_door, with its door shut since mapping, a start committed
19 m off after 90° of turning and a metre). The rule before (``ba0c2d7``-``3191cbf``) followed one
candidate and dropped it at any look that fitted a second place about as well: on a floor where most
views fit two places, the agreeing finds it needed seldom came in a row, and three start-ups of 20
on loop_office_door ran out of time.

Poses are map-frame ``[x, y, yaw]`` float64; scans are (N, 2) obstacle points in the robot frame.
"""

from __future__ import annotations

from collections import deque
from typing import NamedTuple

import numpy as np
from numpy.typing import ArrayLike, NDArray

from navkit import geometry as se2
from navkit.hypotheses import Tally, settle, weigh
from navkit.odometer import Odometer
from navkit.odometry import LidarOdometry, OdometryConfig
from navkit.types import Observation

from .localization import RelocalizationConfig, Relocalizer, ScanToMap, ScanToMapConfig
from .occupancy import GridMap

#: the tracker's counters, in the order the system reports them
COUNTERS = ("fits", "fits_rejected", "relocalizations", "global_searches", "relocalizations_failed", "hypotheses_dropped")


class Look(NamedTuple):
    """A kidnapped start's past look: the odometry pose, the scan's points and the best inlier share
    any place had then."""

    odom_pose: NDArray[np.float64]
    points: NDArray
    best: float


class Hypothesis(Tally):
    """A kidnapped start's pose as the global searches found it: ``map_from_odom``, its looks for and
    against it in the ledger (``navkit.hypotheses.Tally``), and the motion since it was found."""

    def __init__(self, map_from_odom: NDArray[np.float64], odom_pose: NDArray[np.float64]) -> None:
        super().__init__()
        self.map_from_odom = map_from_odom
        self.odometer = Odometer()  # since it was found
        self.odometer.update(odom_pose)

    @property
    def turned(self) -> float:
        """rad of odometry turning since it was found."""
        return self.odometer.radians

    @property
    def moved(self) -> float:
        """m of odometry motion since it was found."""
        return self.odometer.metres


class PoseTracker:
    """Map-frame pose from odometry, corrected by the map fit; relocalization while not found."""

    def __init__(
        self,
        odometry: OdometryConfig,
        localization: ScanToMapConfig,
        relocalization: RelocalizationConfig,
        robot_radius: float,
    ) -> None:
        self.odometry_config = odometry
        self.localization = localization
        self.relocalization = relocalization
        self.robot_radius = robot_radius
        self.localizer: ScanToMap | None = None
        self.relocalizer: Relocalizer | None = None
        self.counters = dict.fromkeys(COUNTERS, 0)
        self.reset()

    def use_map(self, grid_map: GridMap) -> None:
        """The map to track on: its distance field (also the new-obstacle test's) and score field."""
        self.localizer = ScanToMap(grid_map, self.localization)
        self.relocalizer = Relocalizer(grid_map, self.localizer, self.robot_radius, self.relocalization)

    @property
    def nbytes(self) -> int:
        """Bytes of the distance field and the relocalizer's score field."""
        return (self.localizer.nbytes if self.localizer is not None else 0) + (
            self.relocalizer.nbytes if self.relocalizer is not None else 0
        )

    def reset(self) -> None:
        """Forget the pose, the odometry and the counters (a new trial)."""
        self._initial_pose: NDArray[np.float64] | None = None
        self.pose: NDArray[np.float64] | None = None
        self._map_from_odom: NDArray[np.float64] | None = None
        self._odometry: LidarOdometry | None = None
        self._localized = False
        self.kidnapped = False  # no initial pose given this trial: the pose is searched for everywhere
        self.hypotheses: list[Hypothesis] = []  # a kidnapped start's places, weighed look by look
        self._last_look: NDArray[np.float64] | None = None  # odometry at the last global search (kidnapped)
        self._search_odometer = Odometer()  # motion since the kidnapped search began
        self._looks: deque[Look] = deque(maxlen=self.relocalization.recheck_looks)  # the last looks (kidnapped)
        self.localize_started: float | None = None
        self.localized_at: float | None = None  # the stamp the pose was found on the map ...
        self.localized_pose: NDArray[np.float64] | None = None  # ... and the pose found then (map frame)
        self._rejections = 0
        self.lost = False  # a window search after lost_after rejected fits found nothing; until a fit is accepted
        self.rejected_in_row = 0  # rejected fits since the last accepted one
        self.counters = dict.fromkeys(self.counters, 0)

    def set_initial_pose(self, pose: ArrayLike) -> None:
        """The robot's pose (3,) in the map frame as given; odometry restarts here and the pose is
        searched for around it."""
        self._initial_pose = np.asarray(pose, dtype=np.float64).copy()
        self.kidnapped = False
        self.pose = self._initial_pose.copy()
        self._map_from_odom = None
        self._odometry = None
        self._localized = False
        self.localize_started = None
        self.lost = False
        self.rejected_in_row = 0

    @property
    def wants_turning(self) -> bool:
        """A kidnapped start's hypothesis that lacks only the turning to be taken (alone, verified
        enough, over enough motion): a drive straight on turns little; a turn in place completes it."""
        if len(self.hypotheses) != 1 or self._localized:
            return False
        h, config = self.hypotheses[0], self.relocalization
        return self._confirmed(h, turning=False) and h.turned < np.radians(config.confirm_turn_deg)

    def _confirmed(self, h: Hypothesis, turning: bool = True) -> bool:
        """The commitment rule for the one hypothesis left (module docstring)."""
        config = self.relocalization
        return (
            h.support >= config.confirm_looks
            and h.moved >= config.confirm_distance
            and (not turning or h.turned >= np.radians(config.confirm_turn_deg))
            and h.alone_for(self._search_odometer.metres) >= config.confirm_alone_distance
            and h.alone_looks >= config.confirm_alone_looks
        )

    @property
    def localized(self) -> bool:
        """Whether the pose has been found on the map since the initial pose was given."""
        return self._localized

    @property
    def initial_pose(self) -> NDArray[np.float64] | None:
        """The initial pose as given (map frame), None before one is."""
        return None if self._initial_pose is None else self._initial_pose.copy()

    def search_timed_out(self, stamp: float) -> bool:
        """Whether the pose has been searched for longer than the relocalization timeout at ``stamp``
        (a kidnapped start's own, as long as NavTopo's start-up)."""
        config = self.relocalization
        limit = config.kidnapped_timeout if self.kidnapped else config.timeout
        return stamp - (self.localize_started or 0.0) > limit

    def track(self, obs: Observation, points: NDArray) -> NDArray[np.float64] | None:
        """Map-frame pose at this scan (``points``: its filtered obstacle points, robot frame): odometry
        composed onto the initial pose, corrected by the map fit; None while the pose has not been
        found on the map."""
        if self._initial_pose is None and not self.kidnapped:
            if self.pose is None:
                self.kidnapped = True  # no pose given: search the whole map (the protocol's ``none``)
            else:
                self.set_initial_pose(self.pose)  # carry on from the last tracked pose
                self._localized = True
        if self._odometry is None:
            self._odometry = LidarOdometry(self.odometry_config)
        odom_pose = self._odometry.update(obs.points, obs.odom)
        loc = self.localization
        near = points[np.hypot(points[:, 0], points[:, 1]) <= loc.max_range]
        if self.kidnapped and not self._localized:
            if self.localize_started is None:
                self.localize_started = obs.stamp
            found = self._kidnapped_look(near, odom_pose)
            if found is None:
                return None
            self._map_from_odom, self._localized, self.localized_at = found, True, obs.stamp
            self.localized_pose = se2.compose(found, odom_pose)
        if self._map_from_odom is None:
            assert self._initial_pose is not None
            self._map_from_odom = se2.compose(self._initial_pose, se2.inverse(odom_pose))
        pose = se2.compose(self._map_from_odom, odom_pose)
        if not self._localized:
            if self.localize_started is None:
                self.localize_started = obs.stamp
            found = self._relocalize(near, pose, everywhere=True)
            self.pose = pose
            if found is None:
                return None
            pose, self._localized, self.localized_at = found, True, obs.stamp
            self.localized_pose = pose.copy()
            self._map_from_odom = se2.compose(pose, se2.inverse(odom_pose))
        elif loc.enabled and self.localizer is not None and self._odometry.scans % loc.every_scans == 0:
            pose = self._fit(near, pose, odom_pose)
        self.pose = pose
        return pose

    def _fit(self, near: NDArray, pose: NDArray[np.float64], odom_pose: NDArray) -> NDArray[np.float64]:
        """The pose corrected by the map fit (or by the window search once lost); else ``pose``."""
        assert self.localizer is not None
        fit = self.localizer.fit(near, pose)
        if fit is None:
            self.counters["fits_rejected"] += 1
            self._rejections += 1
            self.rejected_in_row += 1
            if self._rejections >= self.relocalization.lost_after:  # lost: search the window again
                found = self._relocalize(near, pose, everywhere=False)
                self._rejections = 0
                if found is not None:
                    fit = (found, 1.0)
                else:
                    self.lost = True
        if fit is not None:
            self.counters["fits"] += 1
            self._rejections = 0
            self.rejected_in_row = 0
            self.lost = False
            pose = fit[0]
            self._map_from_odom = se2.compose(pose, se2.inverse(odom_pose))
        return pose

    def _kidnapped_look(self, points: NDArray, odom_pose: NDArray[np.float64]) -> NDArray[np.float64] | None:
        """A kidnapped start's look when due (the module docstring): ``map_from_odom`` once one
        hypothesis is left and confirmed, else None."""
        config = self.relocalization
        self._search_odometer.update(odom_pose)
        for h in self.hypotheses:
            h.odometer.update(odom_pose)
        if self._last_look is not None:
            step = se2.between(self._last_look, odom_pose)
            turned, moved = abs(float(step[2])), float(np.hypot(step[0], step[1]))
            if turned < np.radians(config.look_turn_deg) and moved < config.look_distance:
                return None
        self._last_look = odom_pose.copy()
        if self.relocalizer is None or self.localizer is None:
            raise RuntimeError("a kidnapped start needs a map (use_map) to search")
        self.counters["global_searches"] += 1
        places = [(share, pose) for share, pose in self.relocalizer.places(points) if share >= config.min_inlier_share]
        checks = [self._verify(h, points, odom_pose) for h in self.hypotheses]
        shares = [share for share, _ in places] + [check[0] for check in checks if check is not None]
        if not shares:
            self.counters["relocalizations_failed"] += 1
            return None  # the scan fits nowhere: no evidence for any place over another
        best = max(shares)
        verified = self._weigh(checks, best, odom_pose)
        self._add_places(places, best, odom_pose)
        self._looks.append(Look(odom_pose.copy(), points, best))
        if len(self.hypotheses) > config.max_hypotheses:
            self.hypotheses.sort(key=lambda h: (h.against, -h.support))
            self.hypotheses = self.hypotheses[: config.max_hypotheses]
        settle(self.hypotheses, self._search_odometer.metres)
        if len(self.hypotheses) != 1:
            return None
        h = self.hypotheses[0]
        return h.map_from_odom if h in verified and self._confirmed(h) else None

    def _weigh(self, checks: list[tuple[float, NDArray[np.float64]] | None], best: float, odom_pose: NDArray) -> list[Hypothesis]:
        """This look's evidence on the hypotheses (their ``checks`` by ``_verify``; ``best``: the best
        share of any place) by the ledger's rule (``navkit.hypotheses.weigh``): a hypothesis whose fit
        moved it too far (``_verify``) or falls short of the best place's by more than ``min_margin``
        is not verified, and that a place fits better counts against it. The dropped ones dropped;
        those the look was for, their ``map -> odom`` refitted (odometry drifts meanwhile)."""
        config = self.relocalization
        verified = [check is not None and check[0] >= best - config.min_margin for check in checks]
        before = len(self.hypotheses)
        fits = {id(h): check for h, check in zip(self.hypotheses, checks, strict=True)}
        self.hypotheses, looked_for = weigh(
            self.hypotheses, verified, [not ok for ok in verified], self._search_odometer.metres, config.drop_after
        )
        self.counters["hypotheses_dropped"] += before - len(self.hypotheses)
        for h in looked_for:
            fit = fits[id(h)]
            assert fit is not None  # a hypothesis the look was for was verified
            h.map_from_odom = se2.compose(fit[1], se2.inverse(odom_pose))
        return looked_for

    def _add_places(self, places: list[tuple[float, NDArray[np.float64]]], best: float, odom_pose: NDArray) -> None:
        """The global search's places (best first) about as good as ``best`` that no hypothesis explains
        become hypotheses; while others are followed, only if they explain the last looks too."""
        config = self.relocalization
        followed = bool(self.hypotheses)
        for share, pose in places:
            if share < best - config.min_margin:
                break
            here = [se2.compose(h.map_from_odom, odom_pose) for h in self.hypotheses]
            map_from_odom = se2.compose(pose, se2.inverse(odom_pose))
            if all(np.hypot(*(pose[:2] - p[:2])) >= config.distinct_distance for p in here) and (
                not followed or self._explains_past(map_from_odom)
            ):
                self.hypotheses.append(Hypothesis(map_from_odom, odom_pose))

    def _explains_past(self, map_from_odom: NDArray[np.float64]) -> bool:
        """Whether a place found while others are followed (``map_from_odom``) fits each of the last
        looks about as well as the best place then (a look-alike dropped where the views told it
        apart is found again where they do not: it must not come back)."""
        assert self.localizer is not None
        margin = self.relocalization.min_margin
        for look in self._looks:
            fitted = self.localizer.refine(look.points, se2.compose(map_from_odom, look.odom_pose))
            if self.localizer.inlier_share(look.points, fitted) < look.best - margin:
                return False
        return True

    def _verify(self, h: Hypothesis, points: NDArray, odom_pose: NDArray) -> tuple[float, NDArray[np.float64]] | None:
        """The scan fitted where odometry carried ``h``: (inlier share, pose) if the fit stays within
        ``confirm_xy`` and ``confirm_yaw_deg`` of it, else None."""
        assert self.localizer is not None
        config = self.relocalization
        predicted = se2.compose(h.map_from_odom, odom_pose)
        fitted = self.localizer.refine(points, predicted)
        off = se2.between(predicted, fitted)
        if np.hypot(off[0], off[1]) > config.confirm_xy or abs(float(np.degrees(off[2]))) > config.confirm_yaw_deg:
            return None
        return self.localizer.inlier_share(points, fitted), fitted

    def _relocalize(self, points: NDArray, guess: NDArray, everywhere: bool) -> NDArray[np.float64] | None:
        """The pose of the scan on the map: the window around ``guess``, then (if allowed) all of it."""
        config = self.relocalization
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
