"""Worlds that change after mapping (``scenarios.changes``): the shut stretch lies across a corridor
clear of its doors, and the trials meet it as they say, by their ground-truth shortest paths."""

from __future__ import annotations

import numpy as np
from shapely.geometry import LineString

from scenarios.changes import stretch_candidates, with_shut_stretches
from scenarios.generators import ring_building
from scenarios.scenario import build_scenario
from scenarios.schema import parse_spec
from scenarios.trials import make_trial
from scenarios.world import rectangle


def test_a_shut_stretch_lies_across_its_corridor_clear_of_doors_and_the_trials_meet_it_as_they_say(tmp_path):
    spec = ring_building(100.0, seed=433, rings=1, trials=4, min_distance=20.0, name="shut433")
    origin = tmp_path / "shut433.yaml"
    shut = with_shut_stretches(spec, origin, count=1, seed=433, trials=4)
    (change,) = shut["world"]["changes"]
    corridors = spec["world"]["corridors"]
    on_leg = [
        (i, k) for i, c in enumerate(corridors) for k in range(len(c["points"]) - 1) if change in stretch_candidates(spec, i, k)
    ]
    assert on_leg, "the box is one of a leg's candidates"
    i, k = on_leg[0]
    a, b = (np.asarray(p) for p in corridors[i]["points"][k : k + 2])
    along = (b - a) / np.hypot(*(b - a))
    box = rectangle(tuple(change["center"]), tuple(change["size"]), change["yaw"])
    across = LineString(
        [a + along * np.dot(np.asarray(change["center"]) - a, along) + s * np.array([-along[1], along[0]]) for s in (-5, 5)]
    )
    assert box.intersection(across).length >= corridors[i]["width"]  # spans the corridor's width
    scenario = build_scenario(parse_spec({**shut, "trials": []}, origin), origin, with_trials=False)
    world, nav = scenario.world, scenario.navigation_world
    radius = parse_spec(shut, origin).robot.radius
    for n, trial in enumerate(shut["trials"]):
        start, goal = (*trial["start"][:2], trial["start"][2]), tuple(trial["goal"])
        mapped = make_trial(world, world.clearance >= radius, 0, start, goal)
        navigated = make_trial(nav, nav.clearance >= radius, 0, start, goal)
        assert mapped is not None and navigated is not None
        through = LineString(mapped.shortest_path).intersects(box)
        assert through == (n < 3)  # three in four through it
        if through:
            assert navigated.shortest_m >= mapped.shortest_m + 5.0  # the way round is longer
        assert navigated.shortest_m <= 2.5 * mapped.shortest_m
