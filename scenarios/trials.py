"""Start-goal navigation trials: given in the file, or sampled from the scenario's seed.

Each trial carries its reference: the any-angle ground-truth shortest path from start to goal
in free space eroded by the robot radius (``shortest_m``, the numerator of efficiency), in the
navigation stage's world (``Scenario.navigation_world``: with ``world.changes`` in place).
Generated ends keep ``SAMPLE_MARGIN_M`` more than the radius from walls and, in a scenario,
are joined to the mapping route through space the robot fits in with the route's pass margin.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from scenarios.route_space import polyline_length, shortest_path
from scenarios.schema import GOAL_TOLERANCE_M
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

    def to_json(self) -> dict:
        return {
            "trial": self.index,
            "start": [float(self.start[0]), float(self.start[1]), float(np.degrees(self.start[2]))],
            "goal": [float(self.goal[0]), float(self.goal[1])],
            "shortest_m": self.shortest_m,
        }


def make_trial(
    world: World, passable: NDArray[np.bool_], index: int, start_deg: tuple[float, float, float], goal: tuple[float, float]
) -> Trial | None:
    path = shortest_path(world, passable, np.array(start_deg[:2]), np.array(goal))
    if path is None:
        return None
    start = np.array([start_deg[0], start_deg[1], np.radians(start_deg[2])], dtype=np.float64)
    return Trial(index, start, np.array(goal, dtype=np.float64), path, polyline_length(path))


def generate_trials(
    world: World,
    passable: NDArray[np.bool_],
    count: int,
    min_distance: float,
    rng: np.random.Generator,
    max_distance: float | None = None,
    within: NDArray[np.bool_] | None = None,
) -> list[Trial]:
    """Sample ``count`` trials; both ends in the (margin-)eroded free space (and in ``within`` if
    given), shortest path length in ``passable`` in [min_distance, max_distance]."""
    sample_space = passable & (world.clearance >= (world.clearance[passable].min() if passable.any() else 0) + SAMPLE_MARGIN_M)
    if within is not None:
        sample_space &= within
    cells = np.argwhere(sample_space)
    if len(cells) == 0:
        raise ValueError("no free space to sample trials from")
    trials: list[Trial] = []
    tries = 0
    while len(trials) < count:
        tries += 1
        if tries > MAX_TRIES_PER_TRIAL * count:
            raise ValueError(f"could not sample {count} trials with min_distance {min_distance} m")
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
        trials.append(trial)
    return trials
