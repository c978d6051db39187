"""scenarios.hall: open rack halls (warehouses) against their own geometry: racks in rows inside the
hall with aisles the robot fits through, pillars clear of the racks, seeded; they load as scenarios
whose route runs down every aisle between two rows of racks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from scenarios.hall import hall_building
from scenarios.scenario import build_scenario
from scenarios.schema import parse_spec


def _boxes(spec: dict, height: float | None = None) -> list[tuple[float, float, float, float]]:
    out = []
    for box in spec["world"]["obstacles"]:
        if height is None or box["height"] == height:
            (cx, cy), (sx, sy) = box["center"], box["size"]
            out.append((cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2))
    return out


def test_a_hall_is_seeded_and_refuses_a_length_too_short():
    assert hall_building(40, seed=5) == hall_building(40, seed=5) != hall_building(40, seed=6)
    with pytest.raises(ValueError):
        hall_building(10, seed=5)


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_racks_stand_in_rows_inside_the_hall_with_aisles_a_robot_passes(seed):
    spec = hall_building(40, seed=seed)
    (width, depth) = spec["world"]["rooms"][0]["size"]
    racks = _boxes(spec, 2.0)
    assert len(racks) >= 6
    for x0, y0, x1, y1 in racks:
        assert 0 < x0 < x1 < width and 0 < y0 < y1 < depth
    rows = sorted({(y0, y1) for _, y0, _, y1 in racks})
    assert len(rows) >= 3
    gaps = [b[0] - a[1] for a, b in zip(rows[:-1], rows[1:], strict=True)]
    assert min(gaps) >= 2.4 and rows[0][0] >= 2.4  # aisles between rows and along the wall
    for px0, py0, px1, py1 in _boxes(spec, 2.6):  # pillars
        for x0, y0, x1, y1 in racks:
            dx, dy = max(x0 - px1, px0 - x1, 0.0), max(y0 - py1, py0 - y1, 0.0)
            assert np.hypot(dx, dy) >= 0.9


def test_a_hall_loads_as_a_scenario_whose_route_runs_down_every_aisle():
    spec = hall_building(30, seed=8, trials=3)
    path = Path(f"<generated {spec['name']}>")
    scenario = build_scenario(parse_spec(spec, path), path)
    assert len(scenario.trials) == 3
    route = scenario.route
    dense = np.vstack([a + np.linspace(0, 1, 50)[:, None] * (b - a) for a, b in zip(route[:-1], route[1:], strict=True)])
    rows = sorted({(y0, y1) for _, y0, _, y1 in _boxes(spec, 2.0)})
    for (_, top), (bottom, _) in zip(rows[:-1], rows[1:], strict=True):
        assert ((dense[:, 1] > top) & (dense[:, 1] < bottom)).any(), (top, bottom)
