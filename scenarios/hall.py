"""Open halls with rows of racks: warehouses and depots, the open floors that two of the bundled real
maps are and no corridor generator makes.

``hall_building(length, seed)`` is one open room ``length`` metres long and 0.6-0.9 of that deep,
with rows of racks across most of it (1.0-1.4 m deep, 2.0 m tall: the lidar sees them), aisles of
2.4-3.6 m between the rows, each row broken by one or two cross aisles of 2.4-3.2 m, a free strip
of 4-7 m along both ends (staging areas; pallets, 0.3-0.5 m tall, stand in them) and pillars on a
9-12 m grid wherever they keep 0.9 m from every rack. A robot finds its way across the open ends,
down the aisles and through the cross aisles: many ways between two places, few walls to tell them
apart, and locations strewn over a plane rather than along corridors. Same length and seed, same
hall. ``benchmarks/generate_scene.py hall`` (and ``slam-hall``, drawn as a robot's SLAM map).
"""

from __future__ import annotations

import numpy as np

from scenarios.generators import scenario_dict

RACK_HEIGHT_M = 2.0
PILLAR_M = 0.4
PILLAR_CLEAR_M = 0.9  # a pillar keeps this far from every rack (an aisle stays an aisle)


def hall_building(
    length: float,
    seed: int = 0,
    route_factor: float = 1.0,
    trials: int = 20,
    min_distance: float | None = None,
    name: str | None = None,
) -> dict:
    """A scenario dict (format 1) of a rack hall; ``scenarios.schema.parse_spec`` reads it."""
    if length < 20.0:
        raise ValueError(f"a hall needs a length of 20 m or more, not {length:g}")
    rng = np.random.default_rng(seed)
    width = float(length)
    depth = round(float(rng.uniform(0.6, 0.9)) * width, 2)
    racks = _racks(rng, width, depth)
    obstacles = racks + _pillars(rng, width, depth, racks) + _pallets(rng, width, depth, racks)
    room = {"center": [round(width / 2, 3), round(depth / 2, 3)], "size": [round(width, 3), round(depth, 3)]}
    aisles = sum(r["size"][0] for r in racks) + 2 * width
    return scenario_dict(
        name or f"hall_{int(round(length))}m_s{seed}",
        f"generated rack hall, {width:.0f} m x {depth:.0f} m, {len(racks)} rack segments, seed {seed}",
        seed,
        [],
        [room],
        obstacles,
        route_factor * aisles,
        trials,
        min_distance if min_distance is not None else 0.4 * (width + depth),
    )


def _racks(rng: np.random.Generator, width: float, depth: float) -> list[dict]:
    """Rows of racks along x between the two end strips, each broken by cross aisles."""
    ends = (float(rng.uniform(4.0, 7.0)), float(rng.uniform(4.0, 7.0)))  # free strips at x = 0 and x = width
    racks: list[dict] = []
    y = float(rng.uniform(2.4, 3.6))  # the first aisle, along the wall
    while True:
        rack = float(rng.uniform(1.0, 1.4))
        if y + rack + 2.4 > depth:
            break
        x0, x1 = ends[0], width - ends[1]
        gaps = sorted(rng.uniform(x0 + 3.0, x1 - 3.0, size=int(rng.integers(1, 3))).tolist())
        cuts = [x0]
        for gap in gaps:
            half = float(rng.uniform(1.2, 1.6))
            if gap - half - cuts[-1] >= 2.0:
                cuts += [gap - half, gap + half]
        cuts.append(x1)
        for a, b in zip(cuts[::2], cuts[1::2], strict=True):
            if b - a >= 2.0:
                racks.append(_box((a + b) / 2, y + rack / 2, b - a, rack, RACK_HEIGHT_M))
        y += rack + float(rng.uniform(2.4, 3.6))
    return racks


def _pillars(rng: np.random.Generator, width: float, depth: float, racks: list[dict]) -> list[dict]:
    step = float(rng.uniform(9.0, 12.0))
    pillars: list[dict] = []
    for x in np.arange(step, width - 1.0, step):
        for y in np.arange(step, depth - 1.0, step):
            if all(_distance(racks_box, float(x), float(y)) >= PILLAR_CLEAR_M + PILLAR_M / 2 for racks_box in racks):
                pillars.append(_box(float(x), float(y), PILLAR_M, PILLAR_M, 2.6))
    return pillars


def _pallets(rng: np.random.Generator, width: float, depth: float, racks: list[dict]) -> list[dict]:
    """A few pallets in the end strips, clear of the racks and the walls by 1.5 m."""
    pallets: list[dict] = []
    for _ in range(int(rng.integers(2, 6))):
        x = float(rng.choice([rng.uniform(1.5, 3.0), rng.uniform(width - 3.0, width - 1.5)]))
        y = float(rng.uniform(1.5, depth - 1.5))
        if all(_distance(box, x, y) >= 1.5 for box in racks + pallets):
            pallets.append(_box(x, y, 1.2, 1.0, round(float(rng.uniform(0.3, 0.5)), 2)))
    return pallets


def _box(cx: float, cy: float, sx: float, sy: float, height: float) -> dict:
    return {"center": [round(cx, 3), round(cy, 3)], "size": [round(sx, 3), round(sy, 3)], "height": height}


def _distance(box: dict, x: float, y: float) -> float:
    """From (x, y) to the axis-aligned box's edge (0 inside)."""
    (cx, cy), (sx, sy) = box["center"], box["size"]
    dx, dy = max(abs(x - cx) - sx / 2, 0.0), max(abs(y - cy) - sy / 2, 0.0)
    return float(np.hypot(dx, dy))
