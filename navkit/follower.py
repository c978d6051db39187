"""The path follower of NavTopo, shared by every compared system.

After K. Muravyev et al. 2021, cited by the NavTopo paper as ``muravyev2021enhancing``
("Enhancing exploration algorithms for navigation with visual SLAM"), as used in the paper's
section "Path Following": compare the robot's heading with the
direction to the next point of the path; if the difference is large, turn in place toward it,
otherwise drive forward. Additions, each small and documented:

* the next point is a pure-pursuit lookahead point, ``lookahead`` metres along the path from
  the robot's progress on it, so gentle bends are taken smoothly;
* the lookahead point never passes a *corner* (a vertex where the path turns by more than
  ``corner_angle``) until the robot has come within ``corner_tolerance`` of it or moved past
  it. Any-angle paths bend at vertices right next to (inflated) obstacles, and a lookahead
  chord across such a bend would cut toward the wall;
* corners are driven as the paper's follower drives every bend: slow down over the last
  ``corner_slowdown`` metres before one, then, past it, turn in place until the heading error
  to the next stretch is below ``turn_in_place_until`` (a turn in place that starts above the
  threshold ends there too). At 5 Hz a robot at full speed moves 0.2 m a tick: it jumped over
  a 0.15 m corner disc and passed by projection beside it, then arced round, swinging 0.06 m
  off the path onto door jambs that the planner passes with a few centimetres to spare
  (BENCHMARKS.md, "Design choices: the follower's corner rules"); with these, 0.02-0.03 m;
* optionally, over a narrow passage of the path (a door at the robot's width and a little more;
  the system marks it, ``slow_between``), the speed is capped at ``passage_speed``: a heading a
  few degrees off at full speed drifts the robot sideways by centimetres before the angular
  correction catches it, where such a door leaves ten a side (measured, off by default:
  BENCHMARKS.md, "Design choices: slow through a door");
* while driving, a proportional angular correction, and a linear speed that falls smoothly to
  zero as the heading error reaches the turn-in-place threshold (no jump between the modes)
  and slows over the last ``slowdown_distance`` metres of the path.

The follower is frame-agnostic (path and poses only need to share a frame) and holds no state
but whether it is turning in place (kept over a new path) and the progress along the current
path: an arc length that never decreases, found by projecting the robot onto a window of the
path just ahead of it, so the progress cannot jump back, nor forward onto a later part of a path
that doubles back.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import BaseModel, ConfigDict, Field

from navkit.geometry import distance_to_polyline, wrap_angle
from navkit.types import Command


class FollowerConfig(BaseModel):
    """Path follower parameters; defaults reproduce the paper's robot (1 m/s, 1.5 rad/s)."""

    model_config = ConfigDict(extra="forbid")

    max_linear: float = Field(default=1.0, gt=0, description="forward speed limit, m/s")
    max_angular: float = Field(default=1.5, gt=0, description="turn rate limit, rad/s")
    turn_in_place_threshold: float = Field(
        default=0.5, gt=0, le=math.pi, description="heading error above which the robot turns in place, rad"
    )
    turn_in_place_until: float = Field(
        default=0.1,
        ge=0,
        le=math.pi,
        description="once turning in place, keep turning until the heading error is below this, rad (0: the threshold)",
    )
    angular_gain: float = Field(default=2.0, ge=0, description="turn rate per heading error, 1/s")
    lookahead: float = Field(default=0.6, gt=0, description="distance of the target along the path, m")
    goal_tolerance: float = Field(
        default=0.35,
        gt=0,
        description="reached within this of the last point, m; in a benchmark run the protocol's stop tolerance",
    )
    slowdown_distance: float = Field(default=1.0, ge=0, description="path length before the end over which the speed falls, m")
    min_linear: float = Field(default=0.1, ge=0, description="speed floor while slowing near the end, m/s")
    corner_angle: float = Field(default=0.35, ge=0, le=math.pi, description="a vertex turning more than this is a corner, rad")
    corner_tolerance: float = Field(default=0.05, gt=0, description="a corner is passed once the robot is this close to it, m")
    corner_slowdown: float = Field(
        default=0.5, ge=0, description="distance before a corner over which the speed falls to min_linear, m (0: none)"
    )
    progress_window: float = Field(default=1.5, gt=0, description="how far ahead of the progress the robot is projected, m")
    passage_speed: float = Field(
        default=0.0,
        ge=0,
        description="speed limit over a narrow passage of the path (``slow_between``), m/s (0: none; 0.3 measured, "
        "off by default: BENCHMARKS.md, 'Design choices: slow through a door')",
    )

    def for_robot(self, context: Any) -> FollowerConfig:
        """This config with what the run fixes filled in, in one place for every system: the
        robot's speed limits (``context.robot``) and the protocol's stop tolerance
        (``context.stop_tolerance``). ``context`` is the runner's ``SystemContext`` (or None)."""
        if context is None:
            return self
        return self.model_copy(
            update={
                "max_linear": float(context.robot.max_linear),
                "max_angular": float(context.robot.max_angular),
                "goal_tolerance": float(getattr(context, "stop_tolerance", self.goal_tolerance)),
            }
        )


class PathFollower:
    """Turn-in-place-then-drive follower of a 2-D polyline.

    Usage: ``set_path(waypoints)`` then ``command(pose)`` every tick; ``reached`` becomes True
    (and commands become zero) once the robot is within ``goal_tolerance`` of the last waypoint
    and has followed the path to near its end (so a closed route is driven all the way round).
    """

    def __init__(self, config: FollowerConfig | None = None) -> None:
        self.config = config if config is not None else FollowerConfig()
        self.clear()

    # ---------------------------------------------------------------------------------------
    # path and state
    # ---------------------------------------------------------------------------------------

    def set_path(self, waypoints: ArrayLike) -> None:
        """Follow a new path: (K, 2) float64 points, K >= 1, in the frame of later poses.

        Resets the progress; a turn in place under way goes on. Repeated consecutive points are dropped.
        """
        points = np.asarray(waypoints, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 2 or points.shape[0] == 0:
            raise ValueError(f"waypoints must be (K, 2) with K >= 1, got shape {points.shape}")
        if not np.isfinite(points).all():
            raise ValueError("waypoints must be finite")
        keep = np.ones(len(points), dtype=bool)
        keep[1:] = np.hypot(*np.diff(points, axis=0).T) > 1e-9
        points = points[keep]
        segments = np.diff(points, axis=0)
        lengths = np.hypot(segments[:, 0], segments[:, 1])
        self._points = points
        self._arc = np.concatenate([[0.0], np.cumsum(lengths)])
        if len(points) > 2:
            headings = np.arctan2(segments[:, 1], segments[:, 0])
            turns = np.abs(wrap_angle(np.diff(headings)))
            self._corner_arc = self._arc[1:-1][turns > self.config.corner_angle]
        else:
            self._corner_arc = np.zeros(0, dtype=np.float64)
        self._progress = 0.0
        self._next_corner = 0
        self._reached = False
        self._slow: tuple[float, float] | None = None  # arc lengths of a narrow passage, driven at passage_speed
        # a turn in place under way goes on toward the new path until ``turn_in_place_until``: a plan
        # replaced mid-turn left the robot 14 degrees off the new way, under the threshold, and it
        # drove off so into a door's jamb beside it (a generated slam-ring, noisy)

    def clear(self) -> None:
        """Forget the path; commands are zero until the next ``set_path``."""
        self._points = np.zeros((0, 2), dtype=np.float64)
        self._arc = np.zeros(0, dtype=np.float64)  # arc length at each point
        self._corner_arc = np.zeros(0, dtype=np.float64)  # arc length of each corner, ascending
        self._progress = 0.0
        self._next_corner = 0  # index into _corner_arc of the first corner not yet passed
        self._reached = False
        self._turning = False  # turning in place (until the heading error is below turn_in_place_until)
        self._slow = None

    def slow_between(self, start: float, end: float) -> None:
        """Drive the path from arc length ``start`` to ``end`` (a narrow passage) at ``passage_speed``
        at most; until the next ``set_path``."""
        self._slow = (float(start), float(end))

    @property
    def has_path(self) -> bool:
        return len(self._points) > 0

    @property
    def path(self) -> NDArray[np.float64]:
        """(K, 2) the path being followed (consecutive duplicates removed)."""
        return self._points.copy()

    @property
    def path_length(self) -> float:
        return float(self._arc[-1]) if self.has_path else 0.0

    @property
    def progress(self) -> float:
        """Arc length along the path reached so far, m; never decreases."""
        return self._progress

    @property
    def reached(self) -> bool:
        """True once ``command`` found the robot within ``goal_tolerance`` of the path's end,
        with its progress along the path within ``goal_tolerance + progress_window`` of it."""
        return self._reached

    def path_ahead(self, distance: float) -> NDArray[np.float64]:
        """(K, 2) the path from the progress point to ``distance`` metres further along it."""
        if not self.has_path:
            return np.zeros((0, 2))
        end = min(self._progress + distance, self.path_length)
        inner = self._points[(self._arc > self._progress) & (self._arc < end)]
        return np.vstack([self._point_at(self._progress)[None], inner, self._point_at(end)[None]])

    def path_ahead_blocked(self, points: ArrayLike, pose: ArrayLike, clearance: float, distance: float) -> bool:
        """Does any of ``points`` (N, 2+) come within ``clearance`` of the way ahead: from the robot's
        position (``pose`` (2+,)) along the path to ``distance`` metres beyond the progress point?

        The rule every system replans by when it sees an obstacle its map lacks (``clearance``: the
        robot radius plus a margin). No points or no path: False.
        """
        points = np.asarray(points, dtype=np.float64)
        if not len(points) or not self.has_path:
            return False
        ahead = np.vstack([np.asarray(pose, dtype=np.float64)[None, :2], self.path_ahead(distance)])
        return bool(distance_to_polyline(points[:, :2], ahead).min() < clearance)

    def at_goal(self, pose: ArrayLike) -> bool:
        """Is the pose (3,) [x, y, yaw] within ``goal_tolerance`` of the last waypoint?"""
        if not self.has_path:
            return False
        x, y = np.asarray(pose, dtype=np.float64)[:2]
        end_x, end_y = self._points[-1]
        return math.hypot(end_x - x, end_y - y) <= self.config.goal_tolerance

    # ---------------------------------------------------------------------------------------
    # control
    # ---------------------------------------------------------------------------------------

    def command(self, pose: ArrayLike) -> Command:
        """Velocity command for the robot at pose (3,) [x, y, yaw] (the path's frame)."""
        if not self.has_path or self._reached:
            return Command(0.0, 0.0)
        pose = np.asarray(pose, dtype=np.float64)
        position = pose[:2]
        self._advance(position)
        # The end counts only once the progress is near it: a closed route (a mapping tour)
        # starts at its own end point, and a path that doubles back may pass close to its end.
        cfg = self.config
        near_end = self.path_length - self._progress <= cfg.goal_tolerance + cfg.progress_window
        if near_end and self.at_goal(pose):
            self._reached = True
            self._progress = self.path_length
            return Command(0.0, 0.0)
        target = self._point_at(self._target_arc())
        dx, dy = target - position
        heading_error = float(wrap_angle(math.atan2(dy, dx) - pose[2]))
        turn_rate = cfg.angular_gain * heading_error
        angular = max(-cfg.max_angular, min(cfg.max_angular, turn_rate))
        threshold = cfg.turn_in_place_threshold
        if self._turning and cfg.turn_in_place_until > 0.0:
            threshold = min(threshold, cfg.turn_in_place_until)
        self._turning = abs(heading_error) >= threshold
        if self._turning:
            if angular == 0.0:  # zero gain: still turn, at full rate
                angular = math.copysign(cfg.max_angular, heading_error)
            return Command(0.0, angular)

        # full speed when aligned, falling to zero at the turn-in-place threshold
        alignment = 1.0 - (heading_error / cfg.turn_in_place_threshold) ** 2
        remaining = self.path_length - self._progress
        factor = 1.0
        if cfg.slowdown_distance > 0.0:
            factor = min(factor, remaining / cfg.slowdown_distance)
        if cfg.corner_slowdown > 0.0 and self._next_corner < len(self._corner_arc):
            to_corner = math.hypot(*(self._point_at(self._corner_arc[self._next_corner]) - position))
            factor = min(factor, to_corner / cfg.corner_slowdown)
        speed = max(cfg.max_linear * factor, min(cfg.min_linear, cfg.max_linear))
        if cfg.passage_speed > 0.0 and self._slow is not None and self._slow[0] <= self._progress <= self._slow[1]:
            speed = min(speed, cfg.passage_speed)
        return Command(speed * alignment, angular)

    def advance(self, position: ArrayLike) -> float:
        """The progress with the robot at ``position`` (2+,): moved to its projection onto the path
        just ahead, as ``command`` moves it (the same position twice moves it once). A check between
        two commands asks it here: the progress of the last command lags the robot by a tick (0.2 m
        at full speed), and a point kept as still ahead by it lay behind the robot."""
        if self.has_path:
            self._advance(np.asarray(position, dtype=np.float64)[:2])
        return self._progress

    def _advance(self, position: NDArray[np.float64]) -> None:
        """Move the progress to the robot's projection onto the path window just ahead."""
        cfg = self.config
        window_end = self._progress + cfg.progress_window
        if self._next_corner < len(self._corner_arc):
            corner_arc = self._corner_arc[self._next_corner]
            # projection may reach the next unpassed corner but not go beyond it
            window_end = min(window_end, corner_arc)
        first = max(int(np.searchsorted(self._arc, self._progress, side="right")) - 1, 0)
        last = min(int(np.searchsorted(self._arc, window_end, side="left")), len(self._arc) - 1)
        if last > first:
            starts = self._points[first:last]
            vectors = self._points[first + 1 : last + 1] - starts
            lengths = self._arc[first + 1 : last + 1] - self._arc[first:last]
            along = np.einsum("ij,ij->i", position - starts, vectors) / lengths
            low = np.maximum(self._progress - self._arc[first:last], 0.0)
            high = np.minimum(window_end - self._arc[first:last], lengths)
            along = np.clip(along, low, np.maximum(low, high))
            closest = starts + vectors * (along / lengths)[:, None]
            distances = np.hypot(*(closest - position).T)
            best = int(np.argmin(distances))
            self._progress = max(self._progress, float(self._arc[first + best] + along[best]))

        # corners the robot has come close to, or moved past, are done
        while self._next_corner < len(self._corner_arc):
            corner_arc = self._corner_arc[self._next_corner]
            corner = self._point_at(corner_arc)
            close = math.hypot(*(corner - position)) <= cfg.corner_tolerance
            if not (close or self._progress >= corner_arc - 1e-9):
                break
            self._progress = max(self._progress, corner_arc)
            self._next_corner += 1
            # face the next stretch before driving on (an arc from the corner swings outside it)
            self._turning = cfg.turn_in_place_until > 0.0

    def _target_arc(self) -> float:
        target = min(self._progress + self.config.lookahead, self.path_length)
        if self._next_corner < len(self._corner_arc):
            target = min(target, self._corner_arc[self._next_corner])
        return target

    def _point_at(self, arc: float) -> NDArray[np.float64]:
        """The path point at arc length ``arc`` (clamped to the path)."""
        if len(self._points) == 1 or arc <= 0.0:
            return self._points[0].copy()
        if arc >= self._arc[-1]:
            return self._points[-1].copy()
        i = int(np.searchsorted(self._arc, arc, side="right")) - 1
        fraction = (arc - self._arc[i]) / (self._arc[i + 1] - self._arc[i])
        return self._points[i] + fraction * (self._points[i + 1] - self._points[i])


class ProgressCheck:
    """Whether the robot makes progress: it has moved ``distance`` metres from its last checkpoint
    within ``period`` seconds (Nav2's ``SimpleProgressChecker``: 0.5 m in 10 s by default). Positions
    are the odometry's (any frame that does not jump); a move past ``distance`` sets a new checkpoint,
    and so does a stall once reported, so that the next is reported ``period`` later."""

    def __init__(self, distance: float, period: float) -> None:
        self.distance = distance
        self.period = period
        self.reset()

    def reset(self) -> None:
        self._stamp: float | None = None
        self._xy = np.zeros(2)

    def stalled(self, stamp: float, xy: ArrayLike) -> bool:
        """True when ``period`` has passed at ``stamp`` without ``distance`` of travel from the
        checkpoint (position ``xy``, (2+,))."""
        xy = np.asarray(xy, dtype=np.float64)[:2]
        if self._stamp is None or math.hypot(*(xy - self._xy)) > self.distance:
            self._stamp, self._xy = stamp, xy.copy()
            return False
        if stamp - self._stamp < self.period:
            return False
        self._stamp, self._xy = stamp, xy.copy()
        return True
