"""Start-goal navigation trials: given in the file, or sampled from the scenario's seed.

Each trial carries its reference: the any-angle ground-truth shortest path from start to goal
in free space eroded by the robot radius (``shortest_m``, the numerator of efficiency), in the
navigation stage's world (``Scenario.navigation_world``: with ``world.changes`` in place).
Generated ends keep ``SAMPLE_MARGIN_M`` more than the radius from walls and, in a scenario,
are joined to the mapping route through space the robot fits in with the route's pass margin.

Each trial also carries its narrowest gap (``narrowest_gap_m``, ``scenarios.gaps``): the room its
shortest path leaves the robot beyond its radius, on each side, in the narrowest passage it goes
through (a door of free width w: w / 2 - r; capped at 1 m). A generated trial is kept only if that
is at least the scenario's margin (``trials.generate.margin``, default ``TRIAL_MARGIN_M``, 0.1 m),
so no generated trial passes a gap the robot could only scrape through; ``shortest_m`` stays the
length of the shortest path in space eroded by the radius alone (DESIGN.md, "Measurement
definitions"), the path whose gap is measured. A listed trial narrower than the margin is refused
by the scenario unless it says ``allow_narrow``; it then runs marked ``narrow``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from scenarios.gaps import GapGauge
from scenarios.route_space import polyline_length, shortest_path
from scenarios.schema import GOAL_TOLERANCE_M, TRIAL_MARGIN_M
from scenarios.world import World

SAMPLE_MARGIN_M = 0.1  # generated ends keep this much more than the robot radius from walls
MAX_TRIES_PER_TRIAL = 400


@dataclass(frozen=True)
class Trial:
    index: int
    start: NDArray[np.float64]  # (3,) x, y, yaw (radians) in the scenario frame
    goal: NDArray[np.float64]  # (2,) x, y in the scenario frame
    shortest_path: NDArray[np.float64]  # (K, 2) GT any-angle shortest path
    shortest_m: float
    narrowest_gap_m: float | None = None  # room beyond the radius on each side in its narrowest gap (None: not measured)
    gap_at: tuple[float, float] | None = None  # (x, y) of that gap; None when wide open (>= 1 m)
    narrow: bool = False  # narrower than the margin, run because the file allows it (``allow_narrow``)

    def to_json(self) -> dict:
        gap = {} if self.narrowest_gap_m is None else {"narrowest_gap_m": round(self.narrowest_gap_m, 4), "narrow": self.narrow}
        return {
            "trial": self.index,
            "start": [float(self.start[0]), float(self.start[1]), float(np.degrees(self.start[2]))],
            "goal": [float(self.goal[0]), float(self.goal[1])],
            "shortest_m": self.shortest_m,
            **gap,
        }


def make_trial(
    world: World,
    passable: NDArray[np.bool_],
    index: int,
    start_deg: tuple[float, float, float],
    goal: tuple[float, float],
    gauge: GapGauge | None = None,
) -> Trial | None:
    """The trial from ``start_deg`` (x, y, yaw in degrees) to ``goal`` with its GT shortest path in
    ``passable``, and its narrowest gap measured by ``gauge`` (if given); None if they are not joined."""
    path = shortest_path(world, passable, np.array(start_deg[:2]), np.array(goal))
    if path is None:
        return None
    start = np.array([start_deg[0], start_deg[1], np.radians(start_deg[2])], dtype=np.float64)
    trial = Trial(index, start, np.array(goal, dtype=np.float64), path, polyline_length(path))
    return trial if gauge is None else measured(trial, gauge)


def measured(trial: Trial, gauge: GapGauge) -> Trial:
    """The trial with its narrowest gap measured by ``gauge``."""
    gap = gauge.measure(trial.shortest_path)
    return replace(trial, narrowest_gap_m=gap.gap_m, gap_at=gap.where)


def below_margin(trial: Trial, margin: float) -> bool:
    """Whether the trial's narrowest gap leaves the robot less than ``margin`` (m) on a side (to a
    micrometre: a door exactly at the margin passes)."""
    return trial.narrowest_gap_m is not None and trial.narrowest_gap_m < margin - 1e-6


def generate_trials(
    world: World,
    passable: NDArray[np.bool_],
    count: int,
    min_distance: float,
    rng: np.random.Generator,
    max_distance: float | None = None,
    within: NDArray[np.bool_] | None = None,
    margin: float = TRIAL_MARGIN_M,
    radius: float | None = None,
) -> list[Trial]:
    """Sample ``count`` trials; both ends in the (margin-)eroded free space (and in ``within`` if
    given), shortest path length in ``passable`` in [min_distance, max_distance], narrowest gap
    along it at least ``margin`` beyond the robot ``radius`` (default: the least clearance in
    ``passable``, the radius to a cell)."""
    least = float(world.clearance[passable].min()) if passable.any() else 0.0
    gauge = GapGauge(world, least if radius is None else radius)
    sample_space = passable & (world.clearance >= least + SAMPLE_MARGIN_M)
    if within is not None:
        sample_space &= within
    cells = np.argwhere(sample_space)
    if len(cells) == 0:
        raise ValueError("no free space to sample trials from")
    trials: list[Trial] = []
    tries = narrow = 0
    while len(trials) < count:
        tries += 1
        if tries > MAX_TRIES_PER_TRIAL * count:
            kept_out = f" whose narrowest gap is at least the margin {margin:g} m ({narrow} narrower ones left out)"
            raise ValueError(f"could not sample {count} trials with min_distance {min_distance} m" + (kept_out if narrow else ""))
        a, b = cells[rng.integers(len(cells), size=2)]
        start_xy = world.to_world(a) + rng.uniform(-0.5, 0.5, 2) * world.resolution
        goal_xy = world.to_world(b) + rng.uniform(-0.5, 0.5, 2) * world.resolution
        yaw_deg = float(rng.uniform(-180.0, 180.0))
        if np.hypot(*(goal_xy - start_xy)) > (max_distance if max_distance is not None else np.inf):
            continue
        trial = make_trial(
            world,
            passable,
            len(trials),
            (float(start_xy[0]), float(start_xy[1]), yaw_deg),
            (float(goal_xy[0]), float(goal_xy[1])),
        )
        if trial is None or trial.shortest_m < min_distance:
            continue
        if np.hypot(*(goal_xy - start_xy)) <= GOAL_TOLERANCE_M:
            continue  # it would succeed without moving
        if max_distance is not None and trial.shortest_m > max_distance:
            continue
        trial = measured(trial, gauge)  # last: the costliest check
        if below_margin(trial, margin):
            narrow += 1  # its shortest way squeezes through a gap: the systems would be judged on it
            continue
        trials.append(trial)
    return trials
