"""Procedural scenarios: orthogonal corridor trees of a given total length, dressed as buildings.

``corridor_tree(total_length, seed)`` grows a tree of straight corridors (a trunk, then branches
at right angles off random points of existing corridors, kept apart so that no corridor touches
another except where it branches off) until the centre lines total ``total_length``; then
``dress`` adds structure every few metres — door niches, side rooms, furniture of several heights
against the walls, pillars — because a bare corridor is degenerate for every scan matcher and
place recogniser (DESIGN.md, "Scenario files"). Same seed, same scenario.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from shapely.geometry import LineString, Point
from shapely.ops import unary_union

from scenarios.world import corridor_polygon, rectangle

CLEAR_PASSAGE_M = 1.3  # furniture never narrows a corridor below this


def _segments(corridors: list[dict]) -> list[tuple[np.ndarray, np.ndarray, float, int]]:
    out = []
    for ci, c in enumerate(corridors):
        pts = np.asarray(c["points"], float)
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            out.append((a, b, float(c["width"]), ci))
    return out


def dress(corridors: list[dict], rng: np.random.Generator, spacing: float = 4.5) -> tuple[list[dict], list[dict]]:
    """Rooms (niches, side rooms) and obstacles (furniture, pillars) along the corridors."""
    polygons = [corridor_polygon(c["points"], c["width"]) for c in corridors]
    rooms: list[dict] = []
    obstacles: list[dict] = []
    taken = []  # footprints already used (keep features apart)
    for a, b, width, ci in _segments(corridors):
        direction = b - a
        length = float(np.linalg.norm(direction))
        if length < 3.0:
            continue
        along = direction / length
        normal = np.array([-along[1], along[0]])
        yaw = float(np.degrees(np.arctan2(along[1], along[0])))
        # other corridors: features keep clear of them (no shortcuts between corridors, no clutter
        # in junctions); the corridor's own neighbours in a chain count as others too, but only
        # near the junction itself, which the 2 m margin at each segment end already avoids
        others = unary_union([p for j, p in enumerate(polygons) if j != ci])
        s = 2.0 + rng.uniform(0, spacing / 2)
        while s < length - 2.0:
            centre = a + along * s
            side = rng.choice([-1.0, 1.0])
            kind = rng.choice(["niche", "niche", "room", "furniture", "furniture", "pillar"], p=[0.25, 0.1, 0.15, 0.2, 0.2, 0.1])
            feature: dict[str, Any]
            if kind in ("niche", "room"):
                if kind == "niche":
                    size = (float(rng.uniform(1.0, 1.8)), float(rng.uniform(0.4, 0.7)))
                else:
                    size = (float(rng.uniform(2.5, 4.0)), float(rng.uniform(2.0, 3.5)))
                offset = width / 2.0 + size[1] / 2.0 - 0.05
                c = centre + normal * side * offset
                feature = {
                    "center": [round(float(c[0]), 3), round(float(c[1]), 3)],
                    "size": [round(size[0], 3), round(size[1], 3)],
                    "yaw": round(yaw, 3),
                }
                footprint = rectangle(feature["center"], feature["size"], feature["yaw"])
                ok = not footprint.buffer(0.8).intersects(others) and not any(footprint.buffer(0.6).intersects(t) for t in taken)
                if ok:
                    rooms.append(feature)
                    taken.append(footprint)
            else:
                if kind == "pillar":
                    size = (0.35, 0.35)
                    height = 2.6
                else:
                    depth = min(float(rng.uniform(0.3, 0.6)), width - CLEAR_PASSAGE_M)
                    if depth < 0.25:
                        s += spacing
                        continue
                    size = (float(rng.uniform(0.5, 1.4)), depth)
                    height = float(rng.choice([0.3, 0.45, 0.8, 1.1, 1.6, 2.0]))
                offset = width / 2.0 - size[1] / 2.0 - 0.02
                c = centre + normal * side * offset
                feature = {
                    "center": [round(float(c[0]), 3), round(float(c[1]), 3)],
                    "size": [round(size[0], 3), round(size[1], 3)],
                    "height": height,
                    "yaw": round(yaw, 3),
                }
                footprint = rectangle(feature["center"], feature["size"], feature["yaw"])
                ok = not footprint.buffer(1.5).intersects(others) and not any(footprint.buffer(1.0).intersects(t) for t in taken)
                if ok:
                    obstacles.append(feature)
                    taken.append(footprint)
            s += spacing * float(rng.uniform(0.7, 1.3))
    return rooms, obstacles


def grow_tree(total_length: float, rng: np.random.Generator, widths: tuple[float, float] = (1.8, 3.0)) -> list[dict]:
    """Straight corridors at right angles, centre lines totalling ``total_length`` metres."""
    trunk = min(total_length, max(20.0, total_length * 0.35))
    corridors = [{"points": [[0.0, 0.0], [round(trunk, 3), 0.0]], "width": round(float(rng.uniform(*widths)), 2)}]
    remaining = total_length - trunk
    attempts = 0
    while remaining > 1e-6 and attempts < 5000:
        attempts += 1
        parent = corridors[int(rng.integers(len(corridors)))]
        a, b = (np.asarray(p, float) for p in parent["points"])
        span = float(np.linalg.norm(b - a))
        if span < 8.0:
            continue
        start = a + (b - a) * rng.uniform(3.0 / span, 1.0 - 3.0 / span)
        along = (b - a) / span
        normal = np.array([-along[1], along[0]]) * rng.choice([-1.0, 1.0])
        length = min(float(rng.uniform(8.0, 25.0)), remaining)
        if remaining - length < 6.0:  # do not leave a stub too short to branch
            length = remaining
        end = start + normal * length
        width = round(float(rng.uniform(*widths)), 2)
        new = LineString([start, end])
        clash = False
        for other in corridors:
            line = LineString(other["points"])
            if other is parent:
                if line.distance(Point(end)) < 3.0:
                    clash = True
            elif line.distance(new) < 4.0 + (width + other["width"]) / 2.0:
                clash = True
        if clash:
            continue
        corridors.append(
            {
                "points": [
                    [round(float(start[0]), 3), round(float(start[1]), 3)],
                    [round(float(end[0]), 3), round(float(end[1]), 3)],
                ],
                "width": width,
            }
        )
        remaining -= float(np.linalg.norm(np.round(end, 3) - np.round(start, 3)))
    return corridors


def corridor_tree(
    total_length: float,
    seed: int = 0,
    route_factor: float = 6.0,
    trials: int = 20,
    min_distance: float | None = None,
    name: str | None = None,
) -> dict:
    """A scenario dict (format 1) of a dressed corridor tree; ``scenarios.schema.parse_spec`` reads it."""
    rng = np.random.default_rng(seed)
    corridors = grow_tree(total_length, rng)
    rooms, obstacles = dress(corridors, rng)
    return {
        "format": "navtopo-scenario/1",
        "name": name or f"tree_{int(round(total_length))}m_s{seed}",
        "description": f"generated corridor tree, {total_length:.0f} m of corridor, seed {seed}",
        "seed": seed,
        "world": {"resolution": 0.05, "wall_height": 2.6, "corridors": corridors, "rooms": rooms, "obstacles": obstacles},
        "mapping_route": {"auto": {"min_length": round(route_factor * total_length, 1)}},
        "trials": {
            "generate": {
                "count": trials,
                "min_distance": round(min_distance if min_distance is not None else 0.3 * total_length, 1),
            }
        },
    }
