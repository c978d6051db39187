r"""What a changed world costs a robot that trusts its map until it sees otherwise: the efficiency of
the best such policy, from the ground truth, for each trial of a scene with ``world.changes``.

The policy: follow the shortest path in the world as mapped; the moment any cell of a change comes
into the lidar's sight (``sensor.max_range``, a straight line through free space of the world as it
is now), know that whole change (a shut door seen is known shut) and follow the shortest path in
the world as mapped plus the changes known; repeat to the goal. It perceives perfectly, at the
lidar's full range, and drives the any-angle shortest paths exactly, so a system that learns of a
change by seeing it, as NavTopo and the metric baseline do, can hardly do better; a system that
guesses which doors are shut before seeing them could, by luck. Its mean efficiency is the ceiling
of issue 30's loop_office_door target for such systems (BENCHMARKS.md, "Loops and changed worlds").

    .venv/bin/python benchmarks/changed_world_bound.py loop_office_door [--trials 20] [--step 0.1]

Scenario: a bundled name or a YAML file. Prints one row per trial (the true shortest path, the
policy's metres, its efficiency, the changes it saw) and the mean efficiency. ``--range R``: changes
seen from R metres only (how near a system must come to see a shut door, and what that costs).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

from navkit.errors import BenchError
from navkit.grid_planning import densify
from scenarios import load_scenario
from scenarios.route_space import polyline_length, shortest_path
from scenarios.scenario import Scenario
from scenarios.world import World


def arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("scenario", help="a bundled scenario's name or a YAML file, with world.changes")
    parser.add_argument("--trials", type=int, default=None, help="the first N trials (default: all)")
    parser.add_argument("--step", type=float, default=0.1, help="m between the points where sight is checked")
    parser.add_argument(
        "--range", type=float, default=None, dest="sight", help="m a change is seen from (default: the lidar's max_range)"
    )
    return parser


def change_cells(world: World, now: World) -> list[NDArray[np.int64]]:
    """Each change's cells (K, 2) [row, col]: free in the world as mapped, not free now."""
    labels, count = ndimage.label(world.free & ~now.free, structure=np.ones((3, 3), bool))
    return [np.argwhere(labels == k + 1) for k in range(count)]


def in_sight(now: World, at: NDArray, cells: NDArray[np.int64], max_range: float) -> bool:
    """Whether any of ``cells`` is seen from ``at`` (2,): within ``max_range``, and the straight line
    to it crossing only free cells of the world as it is now (the cell itself aside)."""
    targets = now.to_world(cells)
    distance = np.hypot(*(targets - at).T)
    near = distance <= max_range
    if not near.any():
        return False
    targets, distance = targets[near], distance[near]
    samples = np.linspace(0.0, 1.0, max(int(distance.max() / (now.resolution / 2)), 2))
    # stop a cell short of the target: the ray ends on the change's own cell
    fractions = samples[None, :] * np.clip((distance - now.resolution) / distance, 0.0, 1.0)[:, None]
    points = at + fractions[..., None] * (targets - at)[:, None, :]
    rows_cols = now.to_cell(points.reshape(-1, 2))
    inside = now.inside(rows_cols)
    free = np.zeros(len(rows_cols), bool)
    free[inside] = now.free[rows_cols[inside, 0], rows_cols[inside, 1]]
    return bool(free.reshape(points.shape[:2]).all(axis=1).any())


def known_world(world: World, changes: list[NDArray[np.int64]], known: set[int], radius: float) -> NDArray[np.bool_]:
    """Where the robot may plan: the world as mapped less the known changes, eroded by ``radius``."""
    free = world.free.copy()
    for k in known:
        free[changes[k][:, 0], changes[k][:, 1]] = False
    return replace(world, free=free).eroded(radius)


def policy_metres(scenario: Scenario, start: NDArray, goal: NDArray, step: float, sight: float) -> tuple[float, int] | None:
    """Metres the map-trusting policy drives from ``start`` to ``goal`` seeing changes from ``sight``
    metres, and how many changes it saw."""
    world, now = scenario.world, scenario.navigation_world
    radius, max_range = scenario.spec.robot.radius, sight
    changes = change_cells(world, now)
    known: set[int] = set()
    driven, at = 0.0, np.asarray(start, dtype=np.float64)
    while True:
        path = shortest_path(world, known_world(world, changes, known, radius), at, goal)
        if path is None:
            return None
        seen_here = None
        points = densify(path, step)
        for i, point in enumerate(points):
            seen = [k for k in range(len(changes)) if k not in known and in_sight(now, point, changes[k], max_range)]
            if seen:
                seen_here = (i, seen)
                break
        if seen_here is None:
            return driven + polyline_length(path), len(known)
        i, seen = seen_here
        driven += polyline_length(points[: i + 1])
        at = points[i]
        known.update(seen)


def main() -> int:
    args = arguments().parse_args()
    try:
        scenario = load_scenario(args.scenario)
    except BenchError as exc:  # the scenario refused: one line naming file and key
        print(exc, file=sys.stderr)
        return 2
    if scenario.navigation_world is scenario.world:
        print(f"{args.scenario}: no world.changes: the policy is the shortest path (efficiency 1)", file=sys.stderr)
        return 2
    trials = scenario.trials[: args.trials] if args.trials is not None else scenario.trials
    sight = args.sight if args.sight is not None else scenario.spec.sensor.max_range
    print(f"changes seen from {sight:g} m")
    print("| trial | shortest now (m) | policy (m) | efficiency | changes seen |")
    print("|---|---|---|---|---|")
    efficiencies = []
    for index, trial in enumerate(trials):
        result = policy_metres(scenario, trial.start[:2], trial.goal, args.step, sight)
        if result is None:
            print(f"| {index} | {trial.shortest_m:.1f} | no path | – | – |")
            continue
        metres, seen = result
        value = min(trial.shortest_m / metres, 1.0)
        efficiencies.append(value)
        print(f"| {index} | {trial.shortest_m:.1f} | {metres:.1f} | {value:.3f} | {seen} |")
    print(f"\nmean efficiency over {len(efficiencies)} trials: {np.mean(efficiencies):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
