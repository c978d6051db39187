"""Worlds that change after mapping: a corridor stretch shut (a fire door closed, a stretch blocked
by pallets) and trials that meet it.

``shut_stretch`` picks where a corridor of a building spec (``world.corridors``) is closed: a box
across one leg, clear of the doors that open onto it and of the leg's ends (a junction shut is a
different building). ``change_trials`` then draws trials in the mapped building, some whose
shortest way there runs through a change (the way round with the change in place at least
``detour_m`` longer, and at most ``max_detour`` times as long) and some whose way does not: what a
system pays for discovering a change is measured on the first kind, what the change costs it
elsewhere on the second. ``tools/make_loop_office.py`` made the bundled ``loop_office_door`` so;
``benchmarks/generate_scene.py --shut`` makes generated buildings so, to tune on.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from shapely.geometry import LineString

from scenarios.route_space import route_space
from scenarios.scenario import build_scenario
from scenarios.schema import parse_spec
from scenarios.slam_doors import is_door
from scenarios.trials import make_trial
from scenarios.world import rectangle

#: a box this thick (m) across the corridor, this much wider than it, this tall
BOX_THICKNESS_M = 0.3
BOX_OVERHANG_M = 0.3
BOX_HEIGHT_M = 2.1
#: m kept from a door's centre along the corridor, and from a leg's ends
DOOR_CLEARANCE_M = 1.6
END_CLEARANCE_M = 3.0


def door_centres(spec: dict) -> list[tuple[float, float]]:
    """Centres of the spec's doors (``world.rooms`` entries that ``slam_doors.is_door``)."""
    return [tuple(r["center"]) for r in spec["world"].get("rooms", []) if is_door(r)]


def stretch_candidates(spec: dict, corridor: int, leg: int) -> list[dict]:
    """Boxes across leg ``leg`` of corridor ``corridor`` in its middle third, from its middle outward,
    each clear of the doors near the corridor (``DOOR_CLEARANCE_M`` along it) and of the leg's ends."""
    entry = spec["world"]["corridors"][corridor]
    a, b = (np.asarray(p, dtype=np.float64) for p in entry["points"][leg : leg + 2])
    length = float(np.hypot(*(b - a)))
    if length <= 2 * END_CLEARANCE_M:
        return []
    along = (b - a) / length
    width = float(entry["width"])
    yaw = float(np.degrees(np.arctan2(along[1], along[0]))) + 90.0
    doors = [np.asarray(d) for d in door_centres(spec)]
    side = np.array([-along[1], along[0]])
    near = [float((d - a) @ along) for d in doors if abs(float((d - a) @ side)) < width / 2 + 0.5]
    out = []
    for offset in np.linspace(0.0, length / 3, 41):  # the middle third, from its middle outward
        for s in (length / 2 + offset, length / 2 - offset):
            if min(s, length - s) >= END_CLEARANCE_M and all(abs(s - other) > DOOR_CLEARANCE_M for other in near):
                c = a + s * along
                out.append(
                    {
                        "center": [round(float(c[0]), 3), round(float(c[1]), 3)],
                        "size": [round(width + BOX_OVERHANG_M, 3), BOX_THICKNESS_M],
                        "height": BOX_HEIGHT_M,
                        "yaw": round(yaw % 180.0, 3),
                    }
                )
    return out


def shut_stretch(spec: dict, rng: np.random.Generator, taken: list[dict] | None = None) -> dict:
    """A box across one leg of one of the spec's corridors (a leg picked by ``rng``, none of those
    ``taken`` already shut), at the middle-most place clear of doors; ValueError if none has room."""
    taken_legs = {(c["_corridor"], c["_leg"]) for c in taken or []}
    legs = [
        (i, k)
        for i, entry in enumerate(spec["world"]["corridors"])
        for k in range(len(entry["points"]) - 1)
        if (i, k) not in taken_legs
    ]
    for index in rng.permutation(len(legs)):
        corridor, leg = legs[int(index)]
        candidates = stretch_candidates(spec, corridor, leg)
        if candidates:
            return {**candidates[0], "_corridor": corridor, "_leg": leg}
    raise ValueError("no corridor leg has a stretch clear of doors to shut")


def change_trials(
    spec: dict,
    origin: Path,
    changes: list[dict],
    crossing: int,
    others: int,
    rng: np.random.Generator,
    length_m: tuple[float, float] = (30.0, 60.0),
    detour_m: float = 5.0,
    max_detour: float = 2.5,
    max_draws: int = 200_000,
) -> list[dict]:
    """Explicit trials (``{"start": [x, y, yaw deg], "goal": [x, y]}``) in ``spec``'s building:
    ``crossing`` whose GT shortest way in the mapped building (``length_m`` long) runs through one of
    ``changes`` and whose way with them in place is at least ``detour_m`` longer, then ``others``
    whose way meets none; every one keeps a way round at most ``max_detour`` times as long.
    ``origin``: the file the spec will be (relative map paths). ValueError if ``max_draws`` random
    pairs do not give them."""
    parsed = parse_spec({**spec, "world": {**spec["world"], "changes": changes}, "trials": []}, origin)
    scenario = build_scenario(parsed, origin, with_trials=False)
    world, nav, radius = scenario.world, scenario.navigation_world, parsed.robot.radius
    space, nav_space = route_space(world, radius), route_space(nav, radius)
    ends = np.argwhere(space.roomy & nav_space.roomy & (world.clearance >= radius + 0.3))
    shut = [rectangle(tuple(c["center"]), tuple(c["size"]), float(c["yaw"])) for c in changes]
    chosen: dict[bool, list[dict]] = {True: [], False: []}
    wanted = {True: crossing, False: others}
    for _ in range(max_draws):
        if all(len(chosen[k]) >= wanted[k] for k in chosen):
            return chosen[True] + chosen[False]
        a, b = ends[rng.integers(len(ends), size=2)]
        start, goal = world.to_world(a), world.to_world(b)
        yaw = round(float(rng.uniform(-180, 180)), 1)
        mapped = make_trial(world, space.passable, 0, (*start, yaw), tuple(goal))
        if mapped is None or not length_m[0] <= mapped.shortest_m <= length_m[1]:
            continue
        line = LineString(mapped.shortest_path)
        through = any(line.intersects(box) for box in shut)
        if len(chosen[through]) >= wanted[through]:
            continue
        navigated = make_trial(nav, nav_space.passable, 0, (*start, yaw), tuple(goal))
        if navigated is None or navigated.shortest_m > max_detour * mapped.shortest_m:
            continue
        if through and navigated.shortest_m < mapped.shortest_m + detour_m:
            continue  # the way round is hardly longer: the change would not matter
        chosen[through].append(
            {
                "start": [round(float(start[0]), 3), round(float(start[1]), 3), yaw],
                "goal": [round(float(goal[0]), 3), round(float(goal[1]), 3)],
            }
        )
    raise ValueError(
        f"{max_draws} random pairs gave {len(chosen[True])} of {crossing} trials through the change(s) "
        f"and {len(chosen[False])} of {others} past them ({length_m[0]:g}-{length_m[1]:g} m)"
    )


def with_shut_stretches(spec: dict, origin: Path, count: int, seed: int, trials: int, crossing_share: float = 0.75) -> dict:
    """``spec`` with ``count`` corridor stretches shut after mapping (``world.changes``) and
    ``trials`` explicit trials, ``crossing_share`` of them through a change (``change_trials``; their
    length between the spec's ``trials.generate.min_distance`` and twice that, or 30-60 m)."""
    rng = np.random.default_rng(seed)
    changes: list[dict] = []
    for _ in range(count):
        changes.append(shut_stretch(spec, rng, changes))
    boxes = [{k: v for k, v in c.items() if not k.startswith("_")} for c in changes]
    shortest = float(spec.get("trials", {}).get("generate", {}).get("min_distance", 30.0))
    crossing = int(round(trials * crossing_share))
    chosen = change_trials(spec, origin, boxes, crossing, trials - crossing, rng, (shortest, 2 * shortest))
    return {**spec, "world": {**spec["world"], "changes": boxes}, "trials": chosen}
