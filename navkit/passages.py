"""A narrow passage of a path (a door at the robot's width and a little more), checked against the
scan as the robot nears it: moved sideways to where the returns leave the robot most room, or shut
when the robot does not fit there (both systems: the map's cells place a jamb within a cell of
where it is, and the pose on the map is off by a few centimetres, where such a door leaves ten a
side).

``PassageCheck`` is the check between plans: a system hands it each new path with the follower
(``follow``: the narrow part found by ``narrow_part``, driven at the follower's ``passage_speed``)
and, at each tick, the pose and a way to the scan's returns near the passage (``step``); it answers
follow on, follow the moved path (handed to the follower already), or shut (the returns to mark as
obstacles). Points and paths are (N, 2) in the frame the system plans in.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from navkit.follower import PathFollower
from navkit.geometry import arc_lengths, distance_to_polyline, point_at_arc
from navkit.grid_planning import densify

#: metres of the path before and after a narrow passage checked with it against the scan (the way in
#: and out: a line through a door that turns at its mouth comes near the jambs' corners)
PASSAGE_LEAD = 0.5


class PassageConfig(BaseModel):
    """How a narrow passage of the path is checked against the scan (``PassageCheck``)."""

    model_config = ConfigDict(extra="forbid")

    check_range: float = Field(
        3.0,
        ge=0,
        description="m along the path: a narrow passage this near ahead is checked against the scan's returns, "
        "moved sideways to their middle or, if the robot does not fit, shut (0: never)",
    )
    margin: float = Field(
        0.04,
        ge=0,
        description="m beyond the robot radius the scan must leave in a passage (its returns sample a jamb's corner "
        "a few centimetres apart)",
    )
    mouth_margin: float | None = Field(
        None,
        ge=0,
        description="m beyond the robot radius the scan must leave where the robot stands at the passage's mouth (its "
        "entry within a radius ahead: the fit can move only the exit, the way in is where the robot is); None: margin. "
        "A robot at a door's mouth 0.1 m off its middle, 0.337 m from a jamb by the scan where the margin asks 0.34, "
        "had the door shut, planned the same way again and shut it at every check until the recoveries ran out "
        "(no_path on a generated SLAM-like ring, noisy); 0 asks what the scan guard asks, no contact",
    )
    block_range: float = Field(1.5, ge=0, description="m along the path: a passage this near is shut if the robot does not fit")
    period: float = Field(0.2, ge=0, description="s of simulated time between checks of a passage")
    max_shift: float = Field(0.3, ge=0, description="m a passage may be moved sideways to the scan's middle")


def returns_near(returns: NDArray, segment: NDArray, reach: float) -> NDArray[np.float64]:
    """The returns (N, 2) within ``reach`` of ``segment`` (2, 2), one a centimetre cell."""
    returns = np.asarray(returns, dtype=np.float64)[:, :2]
    returns = returns[distance_to_polyline(returns, segment) <= reach]
    return np.unique(np.round(returns / 0.01), axis=0) * 0.01


@dataclass
class Verdict:
    """A check's answer: ``path`` the path to follow from now (None: as it is); ``shut`` the
    returns (N, 2) to mark as obstacles when the robot does not fit (then drop the path, plan again)."""

    path: NDArray[np.float64] | None = None
    shut: NDArray[np.float64] | None = None


class PassageCheck:
    """The narrow part of the path being followed, checked every ``period`` once within
    ``check_range`` ahead: its ends move to where the scan leaves the robot most room
    (``fit_passage``) or, if that is less than ``margin`` a side with the passage within
    ``block_range``, it is shut."""

    def __init__(self, config: PassageConfig, robot_radius: float) -> None:
        self.config = config
        self.robot_radius = robot_radius
        self.passage: Passage | None = None
        self.checked = -np.inf  # when it was last

    def clear(self) -> None:
        self.passage, self.checked = None, -np.inf

    def set_path(self, path: NDArray, roomy: Callable[[NDArray], NDArray[np.bool_]] | None) -> None:
        """A new path and its passable test (None: no passage to check on it)."""
        self.passage = None if roomy is None else narrow_part(path, roomy)

    def follow(self, follower: PathFollower, path: NDArray, roomy: Callable[[NDArray], NDArray[np.bool_]] | None) -> None:
        """The follower's new ``path`` (K, 2), its narrow part (``set_path``) checked from now on and
        driven at the follower's ``passage_speed``."""
        follower.set_path(path)
        self.set_path(follower.path, roomy)
        self._slow(follower)

    def step(
        self, follower: PathFollower, stamp: float, pose: NDArray, returns_near: Callable[[NDArray, float], NDArray]
    ) -> Verdict:
        """The check of this tick, if one is ``due`` (else follow on): the follower's progress
        advanced to ``pose`` (3,), ``returns_near(segment (2, 2), reach)`` the scan's returns within
        ``reach`` of the passage's line; a moved path is handed to the follower here, a shut passage
        left to the system (its returns to mark, its path to drop)."""
        progress = follower.advance(pose[:2])
        if not self.due(stamp, progress):
            return Verdict()
        assert self.passage is not None
        inside = self.passage.entry_arc <= progress + self.robot_radius
        returns = returns_near(np.vstack([self.passage.entry, self.passage.exit]), self.reach())
        verdict = self.check(stamp, follower.path, progress, returns, pose)
        if verdict.path is not None:
            follower.set_path(verdict.path)
            self._slow(follower, inside)
        return verdict

    def _slow(self, follower: PathFollower, inside: bool = False) -> None:
        """The follower slowed over the passage, from a radius before its entry (the robot's front
        is there when its centre is), from where it is if it is in the passage already (a moved
        path's passage starts a radius ahead of the robot)."""
        if self.passage is not None:
            start = 0.0 if inside else max(self.passage.entry_arc - self.robot_radius, 0.0)
            follower.slow_between(start, self.passage.exit_arc)

    def reach(self) -> float:
        """Metres either side of the passage's line whose returns the check needs (plus the radius)."""
        return PASSAGE_LEAD + self.config.max_shift + self.robot_radius

    def due(self, stamp: float, progress: float) -> bool:
        """Is a check due now, the robot ``progress`` metres along the path? (False: follow on.)"""
        passage, config = self.passage, self.config
        if passage is None:
            return False
        if progress > passage.exit_arc or config.check_range <= 0:
            self.passage = None
            return False
        return passage.entry_arc - progress <= config.check_range and stamp - self.checked >= config.period

    def check(self, stamp: float, path: NDArray, progress: float, returns: NDArray, position: NDArray) -> Verdict:
        """The check (when ``due``): ``returns`` (N, 2) the scan's obstacle returns within ``reach``
        of the passage's line, the robot at ``position`` (2,), ``progress`` metres along ``path``."""
        passage, config = self.passage, self.config
        assert passage is not None
        self.checked = stamp
        if not len(returns):
            return Verdict()
        # the way ahead, not where the robot is: from a radius on (a robot beside a jamb in the
        # doorway is past the choice)
        ahead = progress + self.robot_radius
        moves, clearance = fit_passage(path, passage, returns, PASSAGE_LEAD, config.max_shift, from_arc=ahead)
        need = self.robot_radius + config.margin
        # at the mouth (the way in fixed where the robot stands) a shut is judged by ``mouth_margin``
        shut_need = need
        if config.mouth_margin is not None and passage.entry_arc <= ahead + 1e-6:  # a moved path's entry: a radius ahead
            shut_need = self.robot_radius + config.mouth_margin
        # shut only where the passage itself lacks room: the way before and after it (``lead``) is
        # not moved by the fit, and a way that bends round a jamb just past a door the robot fits
        # through came 0.19 m from it by the scan (the pose 0.1 m off): shut, the goal's door was lost
        if (
            clearance < shut_need
            and 0 < passage.entry_arc - progress <= config.block_range
            and line_clearance(path, passage, moves, returns, ahead) < shut_need
        ):
            # the robot does not fit where the map showed a passage (narrower than the map's cells
            # showed it, or the pose off by more than a side's room): shut it
            moved = shifted_path(path, passage, moves)
            self.passage = None
            return Verdict(shut=returns[distance_to_polyline(returns, moved) < shut_need])
        inside = passage.entry_arc <= ahead < passage.exit_arc
        # the fit's best way, where it leaves the robot room; in the passage already, where it leaves
        # more than the path does (no shutting it from there: a path re-planned at a door's mouth
        # straight through it, 0.1 m off its middle, was kept at 0.31 m from the jamb and met it)
        if (clearance >= need or inside) and float(np.abs(moves).max()) >= 0.01:
            if inside:
                # in the passage already: the fit kept the way on to ``ahead`` and moved the exit alone,
                # so the path goes there first (straight from the robot to the moved exit would cut
                # the corner of a passage that bends, which the fit did not check)
                passage = Passage(point_at_arc(path, arc_lengths(path), ahead), passage.exit, ahead, passage.exit_arc)
            moved, self.passage = moved_passage(path, passage, moves, progress, np.asarray(position, dtype=np.float64)[:2])
            return Verdict(path=moved)
        return Verdict()


@dataclass(frozen=True)
class Passage:
    """The narrow part of a local path found on a medial level (v_cur's frame): from the first to
    the last of its points (every ``step`` along it) nearer the walls' cells than the margin rule
    allows; ``entry_arc`` and ``exit_arc`` are their arc lengths along the path."""

    entry: NDArray[np.float64]  # (2,)
    exit: NDArray[np.float64]  # (2,)
    entry_arc: float
    exit_arc: float


def narrow_part(
    path: NDArray,
    roomy: Callable[[NDArray], NDArray[np.bool_]],
    extend: float = 0.25,
    longest: float = 1.5,
    step: float = 0.05,
) -> Passage | None:
    """The first stretch of ``path`` (K, 2) whose points are not ``roomy`` (points (N, 2) -> (N,)
    bool: on the passable cells of the planner's first level, the margin kept; True off the grid),
    ``extend`` longer at each end (a door's mouth, where the way in bends toward its axis); None if
    there is none, or if it is longer than ``longest`` (a narrow corridor, not a door: no straight
    line through it stands for the path)."""
    samples = densify(path, step)  # on the path's segments: their arc lengths are the path's
    sample_arcs = arc_lengths(samples)
    narrow = ~roomy(samples)
    if not narrow.any():
        return None
    first = int(np.argmax(narrow))
    wide_after = np.flatnonzero(~narrow[first:])
    last = first + (int(wide_after[0]) - 1 if len(wide_after) else len(narrow) - 1 - first)
    entry_arc = max(float(sample_arcs[first]) - extend, 0.0)
    exit_arc = min(float(sample_arcs[last]) + extend, float(sample_arcs[-1]))
    if exit_arc - entry_arc > longest:
        return None
    arcs = arc_lengths(path)
    return Passage(point_at_arc(path, arcs, entry_arc), point_at_arc(path, arcs, exit_arc), entry_arc, exit_arc)


def fit_passage(
    path: NDArray, passage: Passage, returns: NDArray, lead: float = 0.5, max_shift: float = 0.3, from_arc: float = 0.0
) -> tuple[NDArray[np.float64], float]:
    """Where the scan leaves the robot most room through the passage: ``(moves (2, 2), clearance)``,
    how far to move the passage's entry and its exit (v_cur's frame, each across the passage's
    direction by at most ``max_shift``: so the line through it can turn to the door's axis as well
    as move to its middle; the least moves among the best) and the least distance from ``returns``
    (N, 2: the scan's obstacle points in v_cur's frame) to the path so moved, from ``lead`` before
    the passage (not before ``from_arc``: where the robot is, plus a little, is no choice) to
    ``lead`` after it. The walls a map's cells place within a cell of where they are, and the
    robot's pose in its location, each move the path off a door's middle by a few centimetres,
    where a door at the robot's width leaves it ten a side."""
    arcs = arc_lengths(path)
    direction = passage.exit - passage.entry
    if float(np.hypot(*direction)) < 1e-6:
        direction = point_at_arc(path, arcs, passage.exit_arc + 0.1) - point_at_arc(path, arcs, passage.entry_arc - 0.1)
    normal = np.array([-direction[1], direction[0]]) / max(float(np.hypot(*direction)), 1e-9)
    start, end = max(passage.entry_arc - lead, from_arc), passage.exit_arc + lead
    inside = start >= passage.entry_arc  # in the passage already: the way on starts where the robot is
    entry = point_at_arc(path, arcs, start) if inside else passage.entry
    head = (
        np.zeros((0, 2))
        if inside
        else np.vstack([point_at_arc(path, arcs, start), path[(arcs > start) & (arcs < passage.entry_arc)]])
    )
    tail = np.vstack([path[(arcs > passage.exit_arc) & (arcs < end)], point_at_arc(path, arcs, end)])
    if not len(returns):
        return np.zeros((2, 2)), float("inf")
    fixed = float(distance_to_polyline(returns, tail).min())
    if len(head) > 1:
        fixed = min(fixed, float(distance_to_polyline(returns, head).min()))

    def clearances(entry_shifts: NDArray, exit_shifts: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        d_in, d_out = (grid.ravel() for grid in np.meshgrid(entry_shifts, exit_shifts, indexing="ij"))
        moved_in = entry[None] + d_in[:, None] * normal
        moved_out = passage.exit[None] + d_out[:, None] * normal
        nearest = segment_distances(moved_in, moved_out, returns).min(axis=1)
        nearest = np.minimum(nearest, segment_distances(moved_out, np.repeat(tail[:1], len(d_out), 0), returns).min(axis=1))
        if len(head):
            nearest = np.minimum(nearest, segment_distances(np.repeat(head[-1:], len(d_in), 0), moved_in, returns).min(axis=1))
        return np.minimum(nearest, fixed), d_in, d_out

    def best_of(entry_shifts: NDArray, exit_shifts: NDArray) -> tuple[float, float, float]:
        values, d_in, d_out = clearances(entry_shifts, exit_shifts)
        k = int(np.argmax(values - 1e-4 * (np.abs(d_in) + np.abs(d_out))))  # the least moves among the best
        return float(values[k]), float(d_in[k]), float(d_out[k])

    # coarse, then fine round the best: 13 x 13 and 9 x 9 moves, not 61 x 61
    coarse = np.linspace(-max_shift, max_shift, 13)
    _, d_in, d_out = best_of(np.zeros(1) if inside else coarse, coarse)
    step = max_shift / 6
    fine = np.linspace(-step, step, 9)
    in_shifts = np.zeros(1) if inside else np.clip(d_in + fine, -max_shift, max_shift)
    clearance, d_in, d_out = best_of(in_shifts, np.clip(d_out + fine, -max_shift, max_shift))
    return np.array([d_in * normal, d_out * normal]), clearance


def line_clearance(path: NDArray, passage: Passage, moves: NDArray, returns: NDArray, from_arc: float) -> float:
    """The least distance from ``returns`` (N, 2) to the passage's line alone, its ends moved by
    ``moves`` (2, 2) as ``fit_passage`` found them (from ``from_arc`` on, if the robot is in it already)."""
    entry = point_at_arc(path, arc_lengths(path), from_arc) if from_arc >= passage.entry_arc else passage.entry
    line = segment_distances((entry + moves[0])[None], (passage.exit + moves[1])[None], returns)
    return float(line.min()) if line.size else float("inf")


def shifted_path(path: NDArray, passage: Passage, moves: NDArray) -> NDArray[np.float64]:
    """``path`` (K, 2) with its passage's entry and exit moved by ``moves`` (2, 2) and the points
    between them left out."""
    arcs = arc_lengths(path)
    ends = np.vstack([passage.entry + moves[0], passage.exit + moves[1]])
    return np.vstack([path[arcs < passage.entry_arc], ends, path[arcs > passage.exit_arc]])


def moved_passage(
    path: NDArray, passage: Passage, moves: NDArray, progress: float, position: NDArray
) -> tuple[NDArray[np.float64], Passage]:
    """The path to follow from ``position`` (2,) on, the robot ``progress`` metres along ``path``
    (K, 2), with the passage's ends moved by ``moves`` (2, 2) (``shifted_path``), and the moved
    passage along it (its entry at the robot if the robot is in it already)."""
    arcs = arc_lengths(path)
    before, after = arcs < passage.entry_arc, arcs > passage.exit_arc
    ends = np.vstack([passage.entry + moves[0], passage.exit + moves[1]])
    points = np.vstack([path[before], ends, path[after]])
    along = np.concatenate([arcs[before], [passage.entry_arc, passage.exit_arc], arcs[after]])
    keep = along > progress
    moved = np.vstack([np.asarray(position, dtype=np.float64)[None, :2], points[keep]])
    moved_arcs = arc_lengths(moved)
    exit_index = int(np.count_nonzero(keep[: int(before.sum()) + 2]))  # moved[0] is the robot
    entry_index = exit_index - 1 if keep[int(before.sum())] else 0
    return moved, Passage(
        moved[entry_index].copy(), moved[exit_index].copy(), float(moved_arcs[entry_index]), float(moved_arcs[exit_index])
    )


def segment_distances(starts: NDArray, ends: NDArray, points: NDArray) -> NDArray[np.float64]:
    """(C, N) the distance from each of ``points`` (N, 2) to each segment ``starts`` (C, 2) -> ``ends`` (C, 2)."""
    vectors = ends - starts
    lengths2 = np.maximum((vectors**2).sum(axis=1), 1e-12)
    rel = points[None, :, :] - starts[:, None, :]
    along = np.clip((rel * vectors[:, None, :]).sum(axis=2) / lengths2[:, None], 0.0, 1.0)
    return np.hypot(*(rel - along[..., None] * vectors[:, None, :]).transpose(2, 0, 1))
