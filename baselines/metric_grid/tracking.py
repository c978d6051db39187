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

Kidnapped (the protocol's ``initial_pose: none``: no pose given): the whole map is searched at the
first scan and after every ``look_turn_deg`` of turning or ``look_distance`` of motion; a find that
agrees with the last one carried by odometry (``confirm_xy``, ``confirm_yaw_deg``) confirms it, one
that does not replaces it, a search that finds two places that fit about as well drops it (the
place is not told apart from here), and one that fits nowhere is no evidence. The pose is taken
after ``confirm_looks`` agreeing finds spread over ``confirm_turn_deg`` of turning and
``confirm_distance`` of motion: one view of a place can fit a look-alike elsewhere, and a building
symmetric under a half turn fits every view from one spot (on loop_office_door, with its door shut
since mapping, a start committed 19 m off after 90° of turning and a metre); NavTopo's start-up
asks for its places 3 m apart.

Poses are map-frame ``[x, y, yaw]`` float64; scans are (N, 2) obstacle points in the robot frame.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from navkit import geometry as se2
from navkit.odometer import Odometer
from navkit.odometry import LidarOdometry, OdometryConfig
from navkit.types import Observation

from .localization import RelocalizationConfig, Relocalizer, ScanToMap, ScanToMapConfig
from .occupancy import GridMap

#: the tracker's counters, in the order the system reports them
COUNTERS = ("fits", "fits_rejected", "relocalizations", "global_searches", "relocalizations_failed", "global_finds_replaced")


class Candidate:
    """A kidnapped start's pose as the global searches have found it: ``map_from_odom``, and how
    many finds have agreed, over how much turning and motion."""

    def __init__(self, map_from_odom: NDArray[np.float64], odom_pose: NDArray[np.float64]) -> None:
        self.map_from_odom = map_from_odom
        self.agreed = 1
        self.odometer = Odometer()  # since its first find
        self.odometer.update(odom_pose)

    @property
    def turned(self) -> float:
        """rad of odometry turning since its first find."""
        return self.odometer.radians

    @property
    def moved(self) -> float:
        """m of odometry motion since its first find."""
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
        self._candidate: Candidate | None = None  # a kidnapped start's global finds, confirmed over motion
        self._last_look: NDArray[np.float64] | None = None  # odometry at the last global search (kidnapped)
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
        """A kidnapped start's candidate that lacks only the turning to be taken (its finds agree, over
        enough motion): a drive straight on turns little; a turn in place completes it."""
        c, config = self._candidate, self.relocalization
        if c is None or self._localized:
            return False
        enough = c.agreed >= config.confirm_looks and c.moved >= config.confirm_distance
        return enough and c.turned < np.radians(config.confirm_turn_deg)

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
        """A kidnapped start's search when due (the module docstring): ``map_from_odom`` once the
        global finds have confirmed one, else None."""
        config = self.relocalization
        candidate = self._candidate
        if candidate is not None:
            candidate.odometer.update(odom_pose)
        if self._last_look is not None:
            step = se2.between(self._last_look, odom_pose)
            turned, moved = abs(float(step[2])), float(np.hypot(step[0], step[1]))
            if turned < np.radians(config.look_turn_deg) and moved < config.look_distance:
                return None
        self._last_look = odom_pose.copy()
        if self.relocalizer is None:
            raise RuntimeError("a kidnapped start needs a map (use_map) to search")
        self.counters["global_searches"] += 1
        found = self.relocalizer.everywhere(points)
        if found is None:
            self.counters["relocalizations_failed"] += 1
            if self.relocalizer.ambiguous:
                self._candidate = None  # two places fit about as well from here: the candidate is not told apart
            return None
        map_from_odom = se2.compose(found[0], se2.inverse(odom_pose))
        if candidate is not None:
            predicted = se2.compose(candidate.map_from_odom, odom_pose)
            off = se2.between(predicted, found[0])
            if float(np.hypot(off[0], off[1])) <= config.confirm_xy and abs(float(np.degrees(off[2]))) <= config.confirm_yaw_deg:
                candidate.agreed += 1
                candidate.map_from_odom = map_from_odom  # the latest find: odometry drifts meanwhile
            else:
                self.counters["global_finds_replaced"] += 1
                candidate = None
        if candidate is None:
            candidate = self._candidate = Candidate(map_from_odom, odom_pose)
        spread = candidate.turned >= np.radians(config.confirm_turn_deg) and candidate.moved >= config.confirm_distance
        if candidate.agreed >= config.confirm_looks and spread:
            return candidate.map_from_odom
        return None

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
