"""Doors of a generated building as a SLAM-like map has them: every room behind a narrow door.

A door of a shape world is a free rectangle through one wall (at most ``DOOR_DEPTH_M`` deep and
``DOOR_LENGTH_M`` long, joining a corridor and a room: ``generators.ring_building``'s doors). Side
rooms that open onto their corridor along a whole side (``generators.dress``'s) get a front wall
``FRONT_WALL_M`` thick with a door in it, and furniture (``generators.furnish``). Every door is
then ``door_width_m`` wide (drawn per door), on whole pixels of the map: its jambs lie on pixel
edges, so the map's opening is exactly that wide. Axis-aligned rooms and doors only (the
generated buildings' corridors run along x and y); others are left as they are.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from shapely.geometry import Point
from shapely.ops import unary_union

from scenarios.generators import furnish
from scenarios.world import corridor_polygon, rectangle

DOOR_DEPTH_M = 0.35  # thicker than this, a free rectangle is a niche or a room, not a door
DOOR_LENGTH_M = 2.0
FRONT_WALL_M = 0.15  # the wall a side room gets between it and its corridor
DOOR_CLEAR_M = 1.3  # no furniture before a new door; no artefact this near a door's centre
MIN_ROOM_M = 2.0  # a room at least this deep and wide gets a door (smaller ones are niches)


@dataclass(frozen=True)
class Door:
    centre: tuple[float, float]  # metres, in the middle of the wall
    width_m: float  # the free opening
    axis: str  # "x": the opening runs along x (a door in a wall along x); "y" likewise


def slam_doors(spec: dict, rng: np.random.Generator, width_m: tuple[float, float], resolution: float) -> tuple[dict, list[Door]]:
    """The building with its open side rooms behind doors and every door narrowed, and its doors."""
    world = spec["world"]
    corridors = unary_union([corridor_polygon(c["points"], c["width"]) for c in world["corridors"]])
    footprints = [rectangle(o["center"], o["size"], o.get("yaw", 0.0)) for o in world["obstacles"]]
    sizes = _pixels(width_m, resolution)
    rooms: list[dict] = []
    furniture: list[dict] = []
    doors: list[Door] = []
    for room in world["rooms"]:
        box = _axis_box(room)
        if box is None:
            rooms.append(room)
            continue
        short = min(box[2] - box[0], box[3] - box[1])
        if is_door(room):
            door, record = _narrowed(box, int(rng.choice(sizes)), resolution)
            rooms.append(door)
            doors.append(record)
            continue
        closed = (
            _behind_a_door(box, corridors, footprints, rng, int(rng.choice(sizes)), resolution) if short >= MIN_ROOM_M else None
        )
        if closed is None:
            rooms.append(room)
            continue
        room_box, door, record = closed
        rooms += [_dict(room_box), door]
        doors.append(record)
        furniture += furnish(rng, rectangle(*_centre_size(room_box), 0.0), rectangle(door["center"], door["size"], 0.0))
    building = {**spec, "world": {**world, "rooms": rooms, "obstacles": [*world["obstacles"], *furniture]}}
    return building, doors


def _pixels(width_m: tuple[float, float], resolution: float) -> list[int]:
    """Door widths in whole pixels within ``width_m``."""
    low, high = math.ceil(width_m[0] / resolution - 1e-9), math.floor(width_m[1] / resolution + 1e-9)
    if high < low:
        raise ValueError(f"no whole number of {resolution} m pixels lies in the door widths {width_m}")
    return list(range(low, high + 1))


def is_door(room: dict) -> bool:
    """Whether a ``world.rooms`` entry is a door: an axis-aligned free rectangle through one wall, at
    most ``DOOR_DEPTH_M`` deep and ``DOOR_LENGTH_M`` long (``generators.ring_building``'s doors)."""
    box = _axis_box(room)
    if box is None:
        return False
    long, short = max(box[2] - box[0], box[3] - box[1]), min(box[2] - box[0], box[3] - box[1])
    return short <= DOOR_DEPTH_M and long <= DOOR_LENGTH_M


def _axis_box(room: dict) -> tuple[float, float, float, float] | None:
    """(x0, y0, x1, y1) of an axis-aligned room, None for one at another angle."""
    yaw = float(room.get("yaw", 0.0)) % 180.0
    if min(yaw, 180.0 - yaw) > 1e-6 and abs(yaw - 90.0) > 1e-6:
        return None
    (cx, cy), (sx, sy) = room["center"], room["size"]
    if abs(yaw - 90.0) <= 1e-6:
        sx, sy = sy, sx
    return (cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2)


def _centre_size(box: tuple[float, float, float, float]) -> tuple[tuple[float, float], tuple[float, float]]:
    x0, y0, x1, y1 = box
    return ((x0 + x1) / 2, (y0 + y1) / 2), (x1 - x0, y1 - y0)


def _dict(box: tuple[float, float, float, float]) -> dict:
    (cx, cy), (sx, sy) = _centre_size(box)
    return {"center": [round(cx, 3), round(cy, 3)], "size": [round(sx, 3), round(sy, 3)]}


def _snap(centre: float, pixels: int, resolution: float) -> tuple[float, float]:
    """An opening of ``pixels`` about ``centre`` with its ends on pixel edges (multiples of the
    resolution: a generated world's raster origin is one)."""
    low = round((centre - pixels * resolution / 2) / resolution) * resolution
    return low, low + pixels * resolution


def _narrowed(box: tuple[float, float, float, float], pixels: int, resolution: float) -> tuple[dict, Door]:
    x0, y0, x1, y1 = box
    if x1 - x0 >= y1 - y0:  # the opening runs along x
        a, b = _snap((x0 + x1) / 2, pixels, resolution)
        new, axis = (a, y0, b, y1), "x"
    else:
        a, b = _snap((y0 + y1) / 2, pixels, resolution)
        new, axis = (x0, a, x1, b), "y"
    (cx, cy), _ = _centre_size(new)
    return _dict(new), Door((round(cx, 3), round(cy, 3)), round(pixels * resolution, 3), axis)


def _behind_a_door(
    box: tuple[float, float, float, float],
    corridors,  # noqa: ANN001 - a shapely geometry
    footprints: list,
    rng: np.random.Generator,
    pixels: int,
    resolution: float,
) -> tuple[tuple[float, float, float, float], dict, Door] | None:
    """A side room open along one side onto a corridor: the room moved back behind a front wall,
    the door through it; None if no side or more than one is open, or no door place is clear."""
    x0, y0, x1, y1 = box
    sides = {  # the edge's midpoint, its outward normal
        "south": ((x0 + x1) / 2, y0, (0.0, -1.0)),
        "north": ((x0 + x1) / 2, y1, (0.0, 1.0)),
        "west": (x0, (y0 + y1) / 2, (-1.0, 0.0)),
        "east": (x1, (y0 + y1) / 2, (1.0, 0.0)),
    }
    open_sides = [s for s, (mx, my, _) in sides.items() if corridors.contains(Point(mx, my))]
    if len(open_sides) != 1:
        return None
    mx, my, (nx, ny) = sides[open_sides[0]]
    overlap = float(corridors.boundary.distance(Point(mx, my)))
    back = overlap + FRONT_WALL_M
    room = (
        x0 + back if nx < 0 else x0,
        y0 + back if ny < 0 else y0,
        x1 - back if nx > 0 else x1,
        y1 - back if ny > 0 else y1,
    )
    if min(room[2] - room[0], room[3] - room[1]) < MIN_ROOM_M - FRONT_WALL_M - 0.1:
        return None
    along = (room[0], room[2]) if ny != 0 else (room[1], room[3])
    width = pixels * resolution
    if along[1] - along[0] < width + 0.8:
        return None
    # across: from inside the corridor (0.05 m) through the wall into the room (0.05 m)
    edge = (my if ny != 0 else mx) + (-1 if (ny > 0 or nx > 0) else 1) * overlap  # the corridor's wall line
    inner = edge + (-1 if (ny > 0 or nx > 0) else 1) * FRONT_WALL_M
    across = (min(edge, inner) - 0.05, max(edge, inner) + 0.05)
    for _ in range(10):
        a, b = _snap(float(rng.uniform(along[0] + 0.4 + width / 2, along[1] - 0.4 - width / 2)), pixels, resolution)
        door_box = (a, across[0], b, across[1]) if ny != 0 else (across[0], a, across[1], b)
        door_poly = rectangle(*_centre_size(door_box), 0.0)
        if not any(door_poly.buffer(DOOR_CLEAR_M).intersects(f) for f in footprints):
            (cx, cy), _ = _centre_size(door_box)
            return room, _dict(door_box), Door((round(cx, 3), round(cy, 3)), round(width, 3), "x" if ny != 0 else "y")
    return None
