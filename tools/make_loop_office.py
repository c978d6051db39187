"""Writes scenarios/bundled/loop_office.yaml and loop_office_door.yaml: a building with loops.

``loop_office``: ``scenarios.generators.ring_building`` with a fixed seed, two rings of
corridors sharing a cross corridor (150 m of corridor), 30-odd furnished rooms behind
0.9-1.0 m doors. The auto mapping route tours every branch, round each ring and back the
other way (loop closures), several hundred metres; 20 generated trials at least 30 m apart
(GT shortest path); exact odometry.

``loop_office_door``: the same building, route and robot, with one navigation-time change: the
cross corridor closed half-way (a fire door shut after mapping). Its 20 trials are explicit:
16 whose shortest way in the mapped building runs through the closed stretch (their GT
``shortest_m``, computed with the door shut, goes round a ring instead) and 4 it does not touch.
Every trial keeps a way round. Run once; the YAML files are the artifacts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from shapely.geometry import LineString

from scenarios.generators import ring_building
from scenarios.route_space import route_space
from scenarios.scenario import build_scenario
from scenarios.schema import parse_spec
from scenarios.trials import make_trial
from scenarios.world import rectangle

SEED = 12
LENGTH_M = 150.0
DETOUR_M = 5.0  # a trial the change cuts off goes at least this much further round
BUNDLED = Path(__file__).resolve().parent.parent / "scenarios" / "bundled"
SENSOR = {
    "channels": 16,
    "vertical_fov": [-15, 15],
    "horizontal_resolution": 1.0,
    "max_range": 15.0,
    "mount_height": 0.6,
    "rate_hz": 5,
    "range_noise": 0.0,
}


def loop_office() -> dict:
    spec = ring_building(LENGTH_M, SEED, rings=2, route_factor=4.0, trials=20, min_distance=30.0, name="loop_office")
    return {
        "format": spec["format"],
        "name": "loop_office",
        "description": "an office floor with two rings of corridors (150 m) and 30-odd furnished rooms behind doors",
        "seed": 21,
        "world": {**spec["world"], "ceiling": True},
        "robot": {"radius": 0.3, "max_linear": 1.0, "max_angular": 1.5},
        "sensor": SENSOR,
        "odometry": {"noise": None},
        "mapping_route": spec["mapping_route"],
        "trials": spec["trials"],
    }


def closing_box(spec: dict) -> dict:
    """A box across the cross corridor half-way along it, clear of the doors that open onto it."""
    cross = spec["world"]["corridors"][1]
    (x, y0), (_, y1) = cross["points"]
    width = cross["width"]
    doors = [r for r in spec["world"]["rooms"] if abs(min(r["size"]) - 0.3) < 1e-6]
    near = [d["center"][1] for d in doors if abs(d["center"][0] - x) < width / 2 + 0.5]
    for offset in np.linspace(0.0, (y1 - y0) / 3, 41):
        for y in ((y0 + y1) / 2 + offset, (y0 + y1) / 2 - offset):
            if all(abs(y - other) > 1.6 for other in near):
                return {
                    "center": [round(x, 3), round(float(y), 3)],
                    "size": [round(width + 0.3, 3), 0.3],
                    "height": 2.1,
                    "yaw": 0.0,
                }
    raise SystemExit("no stretch of the cross corridor clear of doors")


def door_trials(spec: dict, change: dict, crossing: int = 16, others: int = 4) -> list[dict]:
    """Trials 30-60 m long in the mapped building: ``crossing`` whose shortest way there runs
    through the change (the way round at least ``DETOUR_M`` longer), then ``others`` whose does
    not; each with a way round (at most 2.5 times as long) once the change stands."""
    origin = BUNDLED / "loop_office_door.yaml"
    scenario = build_scenario(parse_spec({**spec, "trials": []}, origin), origin, with_trials=False)
    world, nav = scenario.world, scenario.navigation_world
    radius = spec["robot"]["radius"]
    space, nav_space = route_space(world, radius), route_space(nav, radius)
    ends = np.argwhere(space.roomy & nav_space.roomy & (world.clearance >= radius + 0.3))
    shut = rectangle(change["center"], change["size"], change["yaw"])
    rng = np.random.default_rng(SEED)
    chosen: dict[bool, list[dict]] = {True: [], False: []}
    wanted = {True: crossing, False: others}
    while any(len(chosen[k]) < wanted[k] for k in chosen):
        a, b = ends[rng.integers(len(ends), size=2)]
        start, goal = world.to_world(a), world.to_world(b)
        yaw = round(float(rng.uniform(-180, 180)), 1)
        mapped = make_trial(world, space.passable, 0, (*start, yaw), tuple(goal))
        if mapped is None or not 30.0 <= mapped.shortest_m <= 60.0:
            continue
        through = bool(LineString(mapped.shortest_path).intersects(shut))
        if len(chosen[through]) >= wanted[through]:
            continue
        navigated = make_trial(nav, nav_space.passable, 0, (*start, yaw), tuple(goal))
        if navigated is None or navigated.shortest_m > 2.5 * mapped.shortest_m:
            continue
        if through and navigated.shortest_m < mapped.shortest_m + DETOUR_M:
            continue  # the way round is hardly longer: the change would not matter
        chosen[through].append(
            {
                "start": [round(float(start[0]), 3), round(float(start[1]), 3), yaw],
                "goal": [round(float(goal[0]), 3), round(float(goal[1]), 3)],
            }
        )
    return chosen[True] + chosen[False]


def write(spec: dict, name: str, header: str) -> Path:
    out = BUNDLED / f"{name}.yaml"
    out.write_text(header + yaml.safe_dump(spec, sort_keys=False, default_flow_style=None, width=120))
    return out


def main() -> None:
    office = loop_office()
    out = write(office, "loop_office", f"# generated by tools/make_loop_office.py (ring_building, seed {SEED})\n")
    rooms = sum(1 for r in office["world"]["rooms"] if abs(min(r["size"]) - 0.3) < 1e-6)
    print(f"wrote {out}: {rooms} rooms behind doors, {len(office['world']['obstacles'])} obstacles")
    change = closing_box(office)
    door = {
        **office,
        "name": "loop_office_door",
        "description": "loop_office with the cross corridor closed after mapping (a change at navigation time)",
        "world": {**office["world"], "changes": [change]},
    }
    door["trials"] = door_trials(door, change)
    out = write(
        door,
        "loop_office_door",
        "# generated by tools/make_loop_office.py: loop_office with world.changes closing the cross corridor;\n"
        "# trials 0-15 would go through the closed stretch in the mapped building, 16-19 would not\n",
    )
    print(f"wrote {out}: change {change}, {len(door['trials'])} trials")


if __name__ == "__main__":
    main()
