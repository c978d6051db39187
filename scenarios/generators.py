"""Procedural scenarios: orthogonal corridor trees of a given total length, dressed as buildings.

``corridor_tree(total_length, seed)`` grows a tree of straight corridors (a trunk, then branches
at right angles off random points of existing corridors, kept apart so that no corridor touches
another except where it branches off) until the centre lines total ``total_length``; then
``dress`` adds structure every few metres — door niches, side rooms, furniture of several heights
against the walls, pillars — because a bare corridor is degenerate for every scan matcher and
place recogniser (DESIGN.md, "Scenario files"). Same seed, same scenario.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from shapely.geometry import LineString, Point, Polygon
from shapely.geometry.base import BaseGeometry
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


def dress(
    corridors: list[dict],
    rng: np.random.Generator,
    spacing: float = 4.5,
    keep_out: BaseGeometry | None = None,
    keep_clear: BaseGeometry | None = None,
) -> tuple[list[dict], list[dict]]:
    """Rooms (niches, side rooms) and obstacles (furniture, pillars) along the corridors.

    ``keep_out``: where no niche or side room may come (within 0.3 m), e.g. rooms already laid
    out; ``keep_clear``: where no furniture or pillar may come (within 1.2 m), e.g. doors. The
    same seed gives the same draws with or without them (a feature is just skipped)."""
    polygons = [corridor_polygon(c["points"], c["width"]) for c in corridors]
    rooms: list[dict] = []
    obstacles: list[dict] = []
    taken: list[BaseGeometry] = []  # footprints already used (keep features apart)
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
                ok = ok and (keep_out is None or not footprint.buffer(0.3).intersects(keep_out))
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
                ok = ok and (keep_clear is None or not footprint.buffer(1.2).intersects(keep_clear))
                if ok:
                    obstacles.append(feature)
                    taken.append(footprint)
            s += spacing * float(rng.uniform(0.7, 1.3))
    return rooms, obstacles


def grow_tree(total_length: float, rng: np.random.Generator, widths: tuple[float, float] = (1.8, 3.0)) -> list[dict]:
    """Straight corridors at right angles, centre lines totalling ``total_length`` metres."""
    trunk = min(total_length, max(20.0, total_length * 0.35))
    first = {"points": [[0.0, 0.0], [round(trunk, 3), 0.0]], "width": round(float(rng.uniform(*widths)), 2)}
    corridors: list[dict[str, Any]] = [first]
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


def scenario_dict(
    name: str,
    description: str,
    seed: int,
    corridors: list,
    rooms: list,
    obstacles: list,
    route_m: float,
    trials: int,
    min_distance: float,
) -> dict:
    """A generated world as a scenario dict (format 1): 0.05 m raster, 2.6 m walls, an auto mapping
    route of at least ``route_m``, ``trials`` generated trials whose ends are ``min_distance`` apart."""
    return {
        "format": "navtopo-scenario/1",
        "name": name,
        "description": description,
        "seed": seed,
        "world": {"resolution": 0.05, "wall_height": 2.6, "corridors": corridors, "rooms": rooms, "obstacles": obstacles},
        "mapping_route": {"auto": {"min_length": round(route_m, 1)}},
        "trials": {"generate": {"count": trials, "min_distance": round(min_distance, 1)}},
    }


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
    return scenario_dict(
        name or f"tree_{int(round(total_length))}m_s{seed}",
        f"generated corridor tree, {total_length:.0f} m of corridor, seed {seed}",
        seed,
        corridors,
        rooms,
        obstacles,
        route_factor * total_length,
        trials,
        min_distance if min_distance is not None else 0.3 * total_length,
    )


# ---------------------------------------------------------------------------------------------
# buildings whose corridors form loops

WALL_M = 0.2  # wall between a corridor and a room, and between two rooms
DOOR_CLEAR_M = 1.3  # furniture keeps this far from a door


@dataclass(frozen=True)
class _Strip:
    """A row of rooms along one side of a corridor. Rooms span ``span`` along ``axis`` ("x": the
    rooms' x-range is cut from the span; "y": their y-range) and ``room`` across it; a room's door
    spans ``door`` across (through the wall, overlapping corridor and room), its centre within
    ``straight`` (default: the span) along, away from the rounded corners of a ring."""

    axis: str
    span: tuple[float, float]
    room: tuple[float, float]
    door: tuple[float, float]
    straight: tuple[float, float] | None = None  # where along the corridor's edge is straight (doors go there)


def _rect(axis: str, along: tuple[float, float], across: tuple[float, float]) -> dict:
    (a0, a1), (c0, c1) = along, across
    if axis == "x":
        return {"center": [round((a0 + a1) / 2, 3), round((c0 + c1) / 2, 3)], "size": [round(a1 - a0, 3), round(c1 - c0, 3)]}
    return {"center": [round((c0 + c1) / 2, 3), round((a0 + a1) / 2, 3)], "size": [round(c1 - c0, 3), round(a1 - a0, 3)]}


def furnish(rng: np.random.Generator, room: Polygon, door: Polygon) -> list[dict]:
    """Furniture of several heights against a room's walls (none near the door), and a table in
    the middle of a big room; the room's middle and the way in stay free."""
    x0, y0, x1, y1 = room.bounds
    kinds = [  # (length range, depth range, heights)
        ((1.2, 1.6), (0.6, 0.8), (0.75,)),  # desk
        ((0.8, 2.0), (0.4, 0.5), (1.8, 2.0)),  # cabinet, shelf
        ((0.5, 0.9), (0.4, 0.6), (0.45, 1.1)),  # low cupboard, side table
    ]
    placed: list[Polygon] = []
    items: list[dict] = []
    for _ in range(int(rng.integers(1, 5))):
        (l0, l1), (d0, d1), heights = kinds[int(rng.integers(len(kinds)))]
        length, depth = float(rng.uniform(l0, l1)), float(rng.uniform(d0, d1))
        side = int(rng.integers(4))  # against the south, north, west or east wall
        if side < 2:
            if x1 - x0 < length + 0.4:
                continue
            cx = float(rng.uniform(x0 + 0.05 + length / 2, x1 - 0.05 - length / 2))
            cy = y0 + 0.05 + depth / 2 if side == 0 else y1 - 0.05 - depth / 2
            size = [length, depth]
        else:
            if y1 - y0 < length + 0.4:
                continue
            cy = float(rng.uniform(y0 + 0.05 + length / 2, y1 - 0.05 - length / 2))
            cx = x0 + 0.05 + depth / 2 if side == 2 else x1 - 0.05 - depth / 2
            size = [depth, length]
        footprint = rectangle((cx, cy), (size[0], size[1]), 0.0)
        if footprint.buffer(DOOR_CLEAR_M).intersects(door) or any(footprint.buffer(0.7).intersects(p) for p in placed):
            continue
        placed.append(footprint)
        items.append(
            {
                "center": [round(cx, 3), round(cy, 3)],
                "size": [round(size[0], 3), round(size[1], 3)],
                "height": float(rng.choice(heights)),
                "yaw": 0.0,
            }
        )
    if x1 - x0 >= 5.0 and y1 - y0 >= 5.0 and rng.random() < 0.7:  # a meeting table
        middle = ((x0 + x1) / 2, (y0 + y1) / 2)
        if not rectangle(middle, (1.6, 0.9), 0.0).buffer(1.3).intersects(unary_union([*placed, door])):
            items.append({"center": [round(middle[0], 3), round(middle[1], 3)], "size": [1.6, 0.9], "height": 0.75, "yaw": 0.0})
    return items


def _block_strips(x0: float, x1: float, y0: float, y1: float, depth: float, widths: tuple[float, float]) -> list[_Strip]:
    """Rows of rooms filling a block whose four sides face corridors (its edges one wall inside
    the corridors); a block too thin for two rows gets one, facing south."""
    strips: list[_Strip] = []
    if y1 - y0 < 2 * widths[0]:
        return strips
    if y1 - y0 < 2 * depth + WALL_M:
        strips.append(_Strip("x", (x0, x1), (y0, y1), (y0 - WALL_M - 0.05, y0 + 0.05)))
        return strips
    strips.append(_Strip("x", (x0, x1), (y0, y0 + depth), (y0 - WALL_M - 0.05, y0 + 0.05)))
    strips.append(_Strip("x", (x0, x1), (y1 - depth, y1), (y1 - 0.05, y1 + WALL_M + 0.05)))
    side = min(depth, (x1 - x0 - WALL_M) / 2)
    low, high = y0 + depth + WALL_M, y1 - depth - WALL_M
    if high - low >= widths[0] and side >= 2.0:
        strips.append(_Strip("y", (low, high), (x0, x0 + side), (x0 - WALL_M - 0.05, x0 + 0.05)))
        strips.append(_Strip("y", (low, high), (x1 - side, x1), (x1 - 0.05, x1 + WALL_M + 0.05)))
    return strips


def ring_building(
    length: float = 140.0,
    seed: int = 0,
    rings: int = 1,
    corridor_width: float = 2.2,
    room_depth: tuple[float, float] = (4.0, 6.0),
    room_width: tuple[float, float] = (3.5, 6.0),
    door_width: tuple[float, float] = (0.9, 1.0),
    repeated_rooms: int = 0,
    route_factor: float = 4.0,
    trials: int = 20,
    min_distance: float | None = None,
    name: str | None = None,
) -> dict:
    """A scenario dict (format 1) of a building whose corridors form loops.

    ``rings=1``: a rectangular ring corridor round a block; ``rings=2``: two rings sharing a cross
    corridor. Corridor centre lines total about ``length`` m. Rooms line both sides of the
    corridors (outside the ring and in the blocks it encloses), each a few metres wide and deep
    behind a door of ``door_width`` in a ``WALL_M`` wall, most furnished (desks, cabinets, low
    cupboards, tables: several heights); about one slot in five is left as wall, where ``dress``
    may add a niche or an open side room; ``dress`` adds furniture and pillars along the
    corridors (never in front of a door). ``repeated_rooms`` > 0 makes that many identical rooms
    (same size, door and furniture) side by side along the south side, in front of a bare
    stretch of corridor: the hard case for place recognition. Same seed, same scenario.
    """
    if rings not in (1, 2):
        raise ValueError("rings must be 1 or 2")
    rng = np.random.default_rng(seed)
    aspect = float(rng.uniform(0.35, 0.55))
    width = length / (2.0 * (1.0 + aspect)) if rings == 1 else length / (2.0 + 3.0 * aspect)
    width, height = round(width, 1), round(aspect * width, 1)
    cw = corridor_width
    corridors = [{"points": [[0.0, 0.0], [width, 0.0], [width, height], [0.0, height], [0.0, 0.0]], "width": cw}]
    cross_w = round(max(cw - 0.2, 1.6), 2)
    xc = round(width / 2 + float(rng.uniform(-0.1, 0.1)) * width, 1)
    if rings == 2:
        corridors.append({"points": [[xc, 0.0], [xc, height]], "width": cross_w})
    # rows of rooms: outside the ring, then the blocks inside it
    half = cw / 2
    d_out = float(rng.uniform(*room_depth))
    along_x, along_y = (-half, width + half), (-half, height + half)
    room_s, room_n = (-half - WALL_M - d_out, -half - WALL_M), (height + half + WALL_M, height + half + WALL_M + d_out)
    room_w, room_e = (-half - WALL_M - d_out, -half - WALL_M), (width + half + WALL_M, width + half + WALL_M + d_out)
    strips = [  # outside the ring: south, north, west, east
        _Strip("x", along_x, room_s, (-half - WALL_M - 0.05, -half + 0.05), (0.0, width)),
        _Strip("x", along_x, room_n, (height + half - 0.05, height + half + WALL_M + 0.05), (0.0, width)),
        _Strip("y", along_y, room_w, (-half - WALL_M - 0.05, -half + 0.05), (0.0, height)),
        _Strip("y", along_y, room_e, (width + half - 0.05, width + half + WALL_M + 0.05), (0.0, height)),
    ]
    blocks = (
        [(half + WALL_M, width - half - WALL_M)]
        if rings == 1
        else [
            (half + WALL_M, xc - cross_w / 2 - WALL_M),
            (xc + cross_w / 2 + WALL_M, width - half - WALL_M),
        ]
    )
    for bx0, bx1 in blocks:
        strips += _block_strips(bx0, bx1, half + WALL_M, height - half - WALL_M, float(rng.uniform(*room_depth)), room_width)
    rooms: list[dict] = []
    obstacles: list[dict] = []
    room_shapes: list[Polygon] = []
    door_shapes: list[Polygon] = []
    plain: list[Polygon] = []  # corridor stretches kept bare (in front of identical rooms)
    template: tuple[float, float, float, NDArray, list[dict]] | None = None  # width, door width and offset, centre, furniture
    for k, strip in enumerate(strips):
        a, end = strip.span
        slot = 0
        while end - a >= room_width[0]:
            identical = k == 0 and slot < repeated_rooms
            slot += 1
            if identical and template is not None:
                w, dw, offset = template[0], template[1], template[2]
                if end - a < w:
                    break
            else:
                w = float(rng.uniform(*room_width))
                if end - (a + w) < room_width[0] + WALL_M:  # the rest is too small for a room: take it
                    w = end - a if end - a <= room_width[1] * 1.4 else w
                w = min(w, end - a)
                if not identical and rng.random() < 0.2:  # this slot is left as wall
                    a += w + WALL_M
                    continue
                dw = float(rng.uniform(*door_width))
                lo, hi = strip.straight or strip.span
                lo, hi = max(lo, a) + 0.5 + dw / 2, min(hi, a + w) - 0.5 - dw / 2
                if hi < lo:  # no straight wall to put a door in (a ring's corner): leave it as wall
                    a += w + WALL_M
                    continue
                offset = float(rng.uniform(lo, hi)) - a
            room = _rect(strip.axis, (a, a + w), strip.room)
            door = _rect(strip.axis, (a + offset - dw / 2, a + offset + dw / 2), strip.door)
            room_poly = rectangle(room["center"], room["size"], 0.0)
            door_poly = rectangle(door["center"], door["size"], 0.0)
            if identical and template is not None:
                shift = np.asarray(room["center"]) - template[3]
                furniture = [
                    {**item, "center": [round(float(c + d), 3) for c, d in zip(item["center"], shift, strict=True)]}
                    for item in template[4]
                ]
            else:
                furniture = furnish(rng, room_poly, door_poly)
            if identical:
                template = template or (w, dw, offset, np.asarray(room["center"], float), furniture)
                plain.append(door_poly.buffer(w / 2 + 1.0))
            rooms += [room, door]
            obstacles += furniture
            room_shapes.append(room_poly)
            door_shapes.append(door_poly)
            a += w + WALL_M
    keep_out = unary_union(room_shapes + door_shapes)
    keep_clear = unary_union(door_shapes + plain)
    more_rooms, more_obstacles = dress(corridors, rng, spacing=3.5, keep_out=keep_out, keep_clear=keep_clear)
    total = sum(float(np.linalg.norm(np.diff(np.asarray(c["points"], float), axis=0), axis=1).sum()) for c in corridors)
    kind = "a ring of corridors" if rings == 1 else "two rings of corridors sharing one"
    return scenario_dict(
        name or f"ring{rings}_{int(round(total))}m_s{seed}",
        f"generated building: {kind}, {total:.0f} m of corridor, {len(room_shapes)} rooms behind doors"
        + (f" ({repeated_rooms} identical)" if repeated_rooms else "")
        + f", seed {seed}",
        seed,
        corridors,
        rooms + more_rooms,
        obstacles + more_obstacles,
        route_factor * total,
        trials,
        min_distance if min_distance is not None else 0.25 * total,
    )
