"""Aliased buildings: look-alike places, the hard case for place recognition and loop closure.

Three kinds, each a scenario dict (format 1) of a shape world, seeded (same arguments, same dict):

* ``aliased_wing``: a hotel or hospital wing. One room (size, door, furniture) repeated ``rooms``
  times along each side of a corridor (``corridors=1``), or along both sides of two parallel
  corridors joined at their ends into a ring (``corridors=2``, the issue's hospital wing); the rooms
  on a corridor's two sides are mirror images of each other, and a bench stands in front of every
  room at the same place. Only the wing's ends tell places apart: a lobby at the west end, and
  (one corridor) a turn north to a stair room or (two corridors) a stair room behind a door.
* ``aliased_ring``: a ring of corridors whose sides look the same. ``sides=4``: a square ring, one
  side's rooms, doors, furniture and corridor dressing repeated on every side turned by 90°;
  ``sides=2``: a rectangle whose opposite sides are the same turned by 180°.
* ``mirror_floor``: a ``generators.ring_building`` made mirror-symmetric about its vertical centre
  line: its west half and that half mirrored, with (``cross=True``) a cross corridor on the axis
  (two rings, one the mirror image of the other).

Every edge lies on the 0.05 m grid of the ground-truth raster (whose origin is a multiple of it),
so look-alike places have identical rasters, not just similar ones: ``look_alike_groups`` finds
them by comparing the rasters of the rooms (each room with half its walls, under the eight turns
and mirrors of the square).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from shapely.geometry import Polygon, box
from shapely.ops import unary_union

from scenarios.generators import WALL_M, dress, furnish, ring_building, scenario_dict
from scenarios.world import World, corridor_polygon

GRID_M = 0.05  # every edge on this grid (the generated worlds' raster)
Box = tuple[float, float, float, float]  # x0, y0, x1, y1
Transform = Callable[[float, float], tuple[float, float]]


def snap(value: float) -> float:
    return round(round(value / GRID_M) * GRID_M, 3)


@dataclass(frozen=True)
class Item:
    """A free rectangle (``height`` None: a room, a door, a niche) or an obstacle of ``height``."""

    box: Box
    height: float | None = None

    def moved(self, transform: Transform) -> Item:
        (ax, ay), (bx, by) = transform(*self.box[:2]), transform(*self.box[2:])
        return Item((snap(min(ax, bx)), snap(min(ay, by)), snap(max(ax, bx)), snap(max(ay, by))), self.height)

    def as_dict(self) -> dict:
        x0, y0, x1, y1 = self.box
        out: dict = {"center": [round((x0 + x1) / 2, 3), round((y0 + y1) / 2, 3)], "size": [round(x1 - x0, 3), round(y1 - y0, 3)]}
        if self.height is not None:
            out["height"] = self.height
        return out

    @property
    def polygon(self) -> Polygon:
        return box(*self.box)


def _snapped(x0: float, y0: float, x1: float, y1: float, height: float | None = None) -> Item:
    a, b, c, d = snap(x0), snap(y0), snap(x1), snap(y1)
    c, d = max(c, a + GRID_M), max(d, b + GRID_M)  # never empty
    return Item((a, b, c, d), height)


def _from_dict(item: dict) -> Item:
    """An axis-aligned room or obstacle dict (yaw a multiple of 90°) as a snapped item."""
    (cx, cy), (sx, sy) = item["center"], item["size"]
    if round(float(item.get("yaw", 0.0))) % 180 == 90:
        sx, sy = sy, sx
    return _snapped(cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2, item.get("height"))


def _furniture(rng: np.random.Generator, room: Item, door: Item) -> list[Item]:
    return [_from_dict(f) for f in furnish(rng, room.polygon, door.polygon)]


def _uniform(rng: np.random.Generator, low: float, high: float) -> float:
    return snap(float(rng.uniform(low, high)))


def _scenario(name: str, description: str, seed: int, corridors: list[dict], items: list[Item], route_m: float, **trials) -> dict:
    rooms = [i.as_dict() for i in items if i.height is None]
    obstacles = [i.as_dict() for i in items if i.height is not None]
    return scenario_dict(name, description, seed, corridors, rooms, obstacles, route_m, trials["trials"], trials["min_distance"])


def _corridor_length(corridors: list[dict]) -> float:
    return sum(float(np.linalg.norm(np.diff(np.asarray(c["points"], float), axis=0), axis=1).sum()) for c in corridors)


# ---------------------------------------------------------------------------------------------
# a wing of identical rooms


def _room_module(rng: np.random.Generator, width: float, depth: float, door: float) -> list[Item]:
    """One room in its own frame: the room over [0, width] x [0, depth], its wall to the corridor
    over y in [-WALL_M, 0] with the door through it, furniture, and a bench in the corridor before
    the wall (y < -WALL_M) away from the door."""
    offset = _uniform(rng, 0.5, width - 0.5 - door)
    room = Item((0.0, 0.0, width, depth))
    doorway = Item((offset, snap(-WALL_M - 0.05), snap(offset + door), 0.05))
    items = [room, doorway, *_furniture(rng, room, doorway)]
    free_wall = max((0.2, offset - 0.6), (snap(offset + door + 0.6), width - 0.2), key=lambda s: s[1] - s[0])
    if free_wall[1] - free_wall[0] >= 1.2:
        start = _uniform(rng, free_wall[0], free_wall[1] - 1.2)
        items.append(Item((start, snap(-WALL_M - 0.45), snap(start + 1.2), -WALL_M), 0.45))
    return items


def aliased_wing(
    rooms: int = 8,
    seed: int = 0,
    corridors: int = 1,
    corridor_width: float = 2.4,
    room_width: tuple[float, float] = (3.4, 4.2),
    room_depth: tuple[float, float] = (4.5, 5.5),
    door_width: tuple[float, float] = (0.9, 1.0),
    route_factor: float = 2.0,
    trials: int = 20,
    min_distance: float | None = None,
    name: str | None = None,
) -> dict:
    """A wing of ``rooms`` identical rooms along each side of one corridor, or of two corridors in a
    ring (``corridors=2``): ``2 * corridors * rooms`` look-alike rooms (module docstring)."""
    if corridors not in (1, 2) or rooms < 2:
        raise ValueError("an aliased wing needs corridors 1 or 2 and at least 2 rooms a row")
    rng = np.random.default_rng(seed)
    cw = snap(corridor_width)
    width, depth = _uniform(rng, *room_width), _uniform(rng, *room_depth)
    module = _room_module(rng, width, depth, _uniform(rng, *door_width))
    pitch = snap(width + WALL_M)
    start = snap(cw / 2 + WALL_M)
    end = snap(start + rooms * pitch - WALL_M)  # the rows' east end
    length = snap(end + WALL_M + cw / 2)  # the corridors' east end (centre line)
    half = cw / 2
    if corridors == 1:
        north_y, rows = 0.0, [(-half - WALL_M, -1.0), (half + WALL_M, 1.0)]
        stair_y = snap(half + WALL_M + depth + 3.0)
        corridor_list = [{"points": [[0.0, 0.0], [length, 0.0], [length, stair_y]], "width": cw}]
        ends = _wing_ends_one(rng, length, stair_y, cw, depth)
    else:
        north_y = snap(cw + 3 * WALL_M + 2 * depth)
        rows = [
            (-half - WALL_M, -1.0),
            (half + WALL_M, 1.0),
            (north_y - half - WALL_M, -1.0),
            (north_y + half + WALL_M, 1.0),
        ]
        corridor_list = [{"points": [[0.0, 0.0], [length, 0.0], [length, north_y], [0.0, north_y], [0.0, 0.0]], "width": cw}]
        ends = _wing_ends_two(rng, length, north_y, cw)
    items: list[Item] = []
    for wall_y, sign in rows:
        for k in range(rooms):
            x_off = start + k * pitch

            def place(
                x: float, y: float, x_off: float = x_off, wall_y: float = wall_y, sign: float = sign
            ) -> tuple[float, float]:
                return (x_off + x, wall_y + sign * y)

            items += [item.moved(place) for item in module]
    items += ends
    total = _corridor_length(corridor_list)
    look_alikes = len(rows) * rooms
    return _scenario(
        name or f"wing{corridors}_{rooms}r_s{seed}",
        f"generated aliased wing: {look_alikes} identical rooms along {corridors} corridor(s) "
        f"({rooms} a row, mirror images across a corridor), {total:.0f} m of corridor, seed {seed}",
        seed,
        corridor_list,
        items,
        route_factor * total,
        trials=trials,
        min_distance=min_distance if min_distance is not None else 0.4 * length,
    )


def _wing_ends_one(rng: np.random.Generator, length: float, stair_y: float, cw: float, depth: float) -> list[Item]:
    """One corridor: a furnished lobby at the west end, a stair room where it turns north."""
    lobby = _snapped(-_uniform(rng, 5.0, 7.0), -_uniform(rng, 2.5, 4.0), 0.05, _uniform(rng, 2.5, 4.0))
    mouth = Item((0.0, -cw / 2, 0.05, cw / 2))
    stair = _snapped(length - 2.0, stair_y - 0.05, length + 2.0, stair_y + 3.0)
    pillar = _snapped(lobby.box[0] + 2.0, -0.2, lobby.box[0] + 2.4, 0.2, 2.6)
    return [
        lobby,
        *_furniture(rng, lobby, mouth),
        pillar,
        stair,
        *_furniture(rng, stair, Item((length - cw / 2, stair_y - 1, length + cw / 2, stair_y))),
    ]


def _wing_ends_two(rng: np.random.Generator, length: float, north_y: float, cw: float) -> list[Item]:
    """Two corridors: a lobby west of the west cross corridor, a stair room behind a door east."""
    half = cw / 2
    lobby = _snapped(
        -half - _uniform(rng, 5.0, 7.0),
        north_y / 2 - _uniform(rng, 2.0, 3.5),
        -half + 0.05,
        north_y / 2 + _uniform(rng, 2.0, 3.5),
    )
    mouth = Item((-half, lobby.box[1], -half + 0.05, lobby.box[3]))
    stair = _snapped(length + half + WALL_M, north_y / 2 - 2.5, length + half + WALL_M + 3.5, north_y / 2 + 1.0)
    door = _snapped(length + half - 0.05, north_y / 2 - 1.5, length + half + WALL_M + 0.05, north_y / 2 - 0.55)
    return [lobby, *_furniture(rng, lobby, mouth), stair, door, *_furniture(rng, stair, door)]


# ---------------------------------------------------------------------------------------------
# a ring whose sides look the same


def _partition(rng: np.random.Generator, a: float, b: float, widths: tuple[float, float]) -> list[tuple[float, float]]:
    """Rooms of ``widths`` side by side over [a, b], a wall between each; the rest is wall."""
    out: list[tuple[float, float]] = []
    while True:
        width = _uniform(rng, *widths)
        if a + width > b:
            return out
        out.append((a, snap(a + width)))
        a = snap(a + width + WALL_M)


def _side(rng: np.random.Generator, half_along: float, half_across: float, cw: float, depth: tuple[float, float]) -> list[Item]:
    """The south side of a ring centred on the origin (its corridor's centre line at
    y = -half_across from x = -half_along to half_along): a row of rooms outside, a shorter row
    inside (clear of the corners, where the other sides' rows go), doors, furniture, dressing."""
    half = cw / 2
    corner = snap(half + WALL_M + 0.5)
    items: list[Item] = []
    outer_depth, inner_depth = _uniform(rng, *depth), _uniform(rng, *depth)
    rows = [
        (-half_along + corner, half_along - corner, -half_across - half - WALL_M, -1.0, outer_depth),
        # inside, clear of the other sides' inner rows (at most depth[1] deep)
        (
            -half_along + half + 2 * WALL_M + depth[1],
            half_along - half - 2 * WALL_M - depth[1],
            -half_across + half + WALL_M,
            1.0,
            inner_depth,
        ),
    ]
    for a, b, wall_y, sign, row_depth in rows:
        for x0, x1 in _partition(rng, a, b, (3.5, 5.5)):
            door_x = _uniform(rng, x0 + 0.5, x1 - 1.5)
            room = _snapped(x0, wall_y + sign * row_depth if sign < 0 else wall_y, x1, wall_y if sign < 0 else wall_y + row_depth)
            door = _snapped(
                door_x, min(wall_y, wall_y - sign * WALL_M) - 0.05, door_x + 0.95, max(wall_y, wall_y - sign * WALL_M) + 0.05
            )
            items += [room, door, *_furniture(rng, room, door)]
    corridor = [{"points": [[-half_along + corner, -half_across], [half_along - corner, -half_across]], "width": cw}]
    keep_out = unary_union([i.polygon for i in items if i.height is None])
    keep_clear = unary_union(
        [i.polygon for i in items if i.height is None and min(i.box[2] - i.box[0], i.box[3] - i.box[1]) < 0.5]
    )
    niches, obstacles = dress(corridor, rng, spacing=3.5, keep_out=keep_out, keep_clear=keep_clear)
    return items + [_from_dict(d) for d in niches + obstacles]


def _turned(quarter_turns: int) -> Transform:
    def turn(x: float, y: float) -> tuple[float, float]:
        for _ in range(quarter_turns % 4):
            x, y = -y, x
        return (x, y)

    return turn


def aliased_ring(
    rooms_per_side: int = 4,
    seed: int = 0,
    sides: int = 4,
    corridor_width: float = 2.2,
    room_depth: tuple[float, float] = (4.0, 5.0),
    route_factor: float = 2.0,
    trials: int = 20,
    min_distance: float | None = None,
    name: str | None = None,
) -> dict:
    """A ring of corridors whose ``sides`` (4: a square, 2: a rectangle's opposite sides) are the
    same building turned about the ring's centre: every place has ``sides`` look-alikes."""
    if sides not in (2, 4) or rooms_per_side < 1:
        raise ValueError("an aliased ring has 2 or 4 look-alike sides and at least one room a side")
    rng = np.random.default_rng(seed)
    cw = snap(corridor_width)
    corner = cw / 2 + WALL_M + 0.5
    inner_rows = (cw + 3 * WALL_M + 2 * room_depth[1]) / 2  # half the ring that holds two inner rows
    along = snap(max((rooms_per_side * (4.5 + WALL_M) + 2 * corner) / 2, inner_rows))  # half the side, about
    across = along if sides == 4 else snap(max(along * 0.6, inner_rows + 1.0))
    south = _side(rng, along, across, cw, room_depth)
    items = [i.moved(_turned(q)) for q in (0, 2) for i in south]
    if sides == 4:
        items += [i.moved(_turned(q)) for q in (1, 3) for i in south]
    else:
        east_side = _side(rng, across, along, cw, room_depth)  # built as a south side, turned to the east
        items += [i.moved(_turned(q)) for q in (1, 3) for i in east_side]
    h = cw / 2
    corridors = [
        {"points": [[-along - h, -across], [along + h, -across]], "width": cw},
        {"points": [[-along - h, across], [along + h, across]], "width": cw},
        {"points": [[-along, -across - h], [-along, across + h]], "width": cw},
        {"points": [[along, -across - h], [along, across + h]], "width": cw},
    ]
    total = 4 * (along + across)
    return _scenario(
        name or f"aliased_ring{sides}_{rooms_per_side}r_s{seed}",
        f"generated aliased ring: {sides} look-alike sides ({'turned by 90°' if sides == 4 else 'opposite, turned by 180°'}), "
        f"about {rooms_per_side} rooms a side, {total:.0f} m of corridor, seed {seed}",
        seed,
        corridors,
        items,
        route_factor * total,
        trials=trials,
        min_distance=min_distance if min_distance is not None else 0.5 * (along + across),
    )


# ---------------------------------------------------------------------------------------------
# a mirror-symmetric floor


def mirror_floor(
    length: float = 140.0,
    seed: int = 0,
    cross: bool = True,
    route_factor: float = 2.0,
    trials: int = 20,
    min_distance: float | None = None,
    name: str | None = None,
) -> dict:
    """A ring building of ``length`` m of ring corridor whose east half is its west half mirrored
    about x = width / 2 (and, ``cross``, a cross corridor on that axis): every place has one
    look-alike, its mirror image."""
    source = ring_building(length, seed=seed, rings=1, trials=trials)
    ring = source["world"]["corridors"][0]
    width = float(max(p[0] for p in ring["points"]))
    height = float(max(p[1] for p in ring["points"]))
    axis, cw = snap(width / 2), snap(ring["width"])
    corridors = [{"points": ring["points"], "width": cw}]
    cross_w = snap(max(cw - 0.2, 1.6))
    if cross:
        corridors.append({"points": [[axis, 0.0], [axis, height]], "width": cross_w})
    # what may stay of the west half: nothing reaching the axis, nothing within a wall of the cross corridor
    blocked = box(axis - 1e-6, -1e9, 1e9, 1e9)
    if cross:
        blocked = blocked.union(
            corridor_polygon([(axis, 0.0), (axis, height)], cross_w).buffer(WALL_M + 0.05, join_style="mitre")
        )
    rooms = [_from_dict(r) for r in source["world"]["rooms"]]
    big = [r for r in rooms if min(r.box[2] - r.box[0], r.box[3] - r.box[1]) > 0.35]
    kept_big = [r for r in big if not r.polygon.intersects(blocked)]
    kept = [
        r
        for r in rooms
        if r in kept_big
        or (r not in big and not r.polygon.intersects(blocked) and any(r.polygon.intersects(k.polygon) for k in kept_big))
    ]
    corridor_shape = unary_union([corridor_polygon(c["points"], c["width"]) for c in corridors])
    structure = unary_union([corridor_shape, *[k.polygon for k in kept]])
    clear = (
        corridor_polygon([(axis, 0.0), (axis, height)], cross_w).buffer(1.5) if cross else box(axis - 1.5, -1e9, axis + 1.5, 1e9)
    )
    obstacles = [
        o for o in map(_from_dict, source["world"]["obstacles"])
        if o.box[2] <= axis and structure.contains(o.polygon) and not o.polygon.intersects(clear)
    ]  # fmt: skip
    west = kept + obstacles
    items = west + [i.moved(lambda x, y: (2 * axis - x, y)) for i in west]
    total = _corridor_length(corridors)
    return _scenario(
        name or f"mirror_{int(round(length))}m_s{seed}",
        f"generated mirror-symmetric floor: a ring building of {length:.0f} m whose east half mirrors its west half"
        + (" about a cross corridor" if cross else "")
        + f", {total:.0f} m of corridor, seed {seed}",
        seed,
        corridors,
        items,
        route_factor * total,
        trials=trials,
        min_distance=min_distance if min_distance is not None else 0.25 * total,
    )


# ---------------------------------------------------------------------------------------------
# measuring look-alikes


def room_boxes(spec: dict, least_m: float = 2.0) -> list[Box]:
    """The axis-aligned rooms of a scenario dict at least ``least_m`` wide and deep (not doors or niches)."""
    out = []
    for room in spec["world"]["rooms"]:
        item = _from_dict(room)
        x0, y0, x1, y1 = item.box
        if min(x1 - x0, y1 - y0) >= least_m:
            out.append(item.box)
    return out


def room_raster(world: World, room: Box, margin_m: float = 0.1) -> NDArray[np.bool_]:
    """The world's free cells over a room and ``margin_m`` round it (half its walls)."""
    x0, y0, x1, y1 = room
    (r0, c0), (r1, c1) = world.to_cell(
        np.array([[x0 - margin_m + 1e-6, y0 - margin_m + 1e-6], [x1 + margin_m - 1e-6, y1 + margin_m - 1e-6]])
    )
    return world.free[r0 : r1 + 1, c0 : c1 + 1]


def canonical(cells: NDArray[np.bool_]) -> bytes:
    """The same bytes for a raster and its turns and mirrors (the dihedral group of the square)."""
    forms = []
    for flipped in (cells, cells[:, ::-1]):
        for quarter in range(4):
            turned = np.rot90(flipped, quarter)
            forms.append(bytes(str(turned.shape), "ascii") + np.packbits(turned).tobytes())
    return min(forms)


def look_alike_groups(world: World, rooms: list[Box]) -> list[int]:
    """Sizes of the groups of rooms whose rasters are identical up to turns and mirrors, largest
    first, groups of one left out: ``[12, 12]`` is two kinds of room, twelve of each."""
    groups: dict[bytes, int] = {}
    for room in rooms:
        key = canonical(room_raster(world, room))
        groups[key] = groups.get(key, 0) + 1
    return sorted((n for n in groups.values() if n > 1), reverse=True)
