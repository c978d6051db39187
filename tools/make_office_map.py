"""A synthetic office floor as a robot would have mapped it: a ROS map_server map (PGM + YAML).

About 58 x 47 m at 0.05 m per pixel: corridors in a loop, rooms off them behind 0.8-0.9 m
doors (a few narrower than the robot), open door leaves, desks drawn as blocks or as their
legs, chairs and plants as blobs, cabinets; and what a lidar map has besides: rough walls,
speckles of occupied and unknown pixels in free space, unknown shadows in corners, stray free
pixels outside through the windows. The free space is the hard case for route generation:
narrow doors, clutter with gaps just wider than the robot, isolated blobs that split the
skeleton. Same seed, same map.

    .venv/bin/python tools/make_office_map.py OUT_DIR [--seed 3]

writes OUT_DIR/office.pgm, OUT_DIR/office.yaml (the map) and OUT_DIR/office_scenario.yaml (an
``auto`` mapping route and generated trials on it). Nothing is committed: tests generate it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import yaml
from numpy.typing import NDArray

from navkit.raster import GridFrame, write_map_server

FREE, OCCUPIED, UNKNOWN = 254, 0, 205  # map_saver's pixel values
RESOLUTION = 0.05
SIZE_M = (58.0, 47.0)


class Canvas:
    """Pixels in raster order (row 0 = lowest y); drawn in metres."""

    def __init__(self, size_m: tuple[float, float], resolution: float) -> None:
        self.res = resolution
        self.pixels = np.full((round(size_m[1] / resolution), round(size_m[0] / resolution)), UNKNOWN, np.uint8)

    def px(self, v: float) -> int:
        return int(round(v / self.res))

    def rect(self, x0: float, y0: float, x1: float, y1: float, value: int) -> None:
        c0, c1 = sorted((self.px(x0), self.px(x1)))
        r0, r1 = sorted((self.px(y0), self.px(y1)))
        self.pixels[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = value

    def disc(self, x: float, y: float, radius: float, value: int) -> None:
        cv2.circle(self.pixels, (self.px(x), self.px(y)), max(1, self.px(radius)), int(value), -1)

    def blob(self, rng: np.random.Generator, x: float, y: float, radius: float, value: int = OCCUPIED) -> None:
        """An irregular filled blob (a chair, a plant, a bin as a lidar sees it)."""
        angles = np.sort(rng.uniform(0, 2 * np.pi, 9))
        radii = radius * rng.uniform(0.6, 1.0, 9)
        pts = np.stack([x + radii * np.cos(angles), y + radii * np.sin(angles)], 1) / self.res
        cv2.fillPoly(self.pixels, [np.round(pts).astype(np.int32)], int(value))

    def free_at(self, x: float, y: float) -> bool:
        r, c = self.px(y), self.px(x)
        return 0 <= r < self.pixels.shape[0] and 0 <= c < self.pixels.shape[1] and self.pixels[r, c] == FREE


def _partition(rng: np.random.Generator, x0: float, x1: float, low: float = 3.0, high: float = 6.0) -> list[tuple[float, float]]:
    """Split [x0, x1] into room widths in [low, high] (the last absorbs the rest)."""
    cuts = [x0]
    while x1 - cuts[-1] > high:
        cuts.append(cuts[-1] + float(rng.uniform(low, high)))
    if x1 - cuts[-1] < low and len(cuts) > 1:
        cuts.pop()
    cuts.append(x1)
    return list(zip(cuts[:-1], cuts[1:], strict=True))


# the floor plan (metres): two long corridors joined by two cross corridors (two loops), rooms
# on both sides of them, an open-plan office in the centre block
WALL_M = 0.15  # the outer wall
X_IN0, X_IN1, Y_IN0, Y_IN1 = 1.25, 56.75, 1.25, 45.75  # inside of the outer wall
SOUTH = (11.0, 13.0)  # y-range of the south corridor
NORTH = (33.5, 35.3)
CROSS = [(19.0, 20.8), (40.0, 41.9)]  # x-ranges of the cross corridors
SPINE = 23.2  # wall between the rooms facing south and those facing north
BLOCKS_X = [(X_IN0, CROSS[0][0]), (CROSS[0][1], CROSS[1][0]), (CROSS[1][1], X_IN1)]  # between the cross corridors

Box = tuple[float, float, float, float]  # (x0, y0, x1, y1)
Room = tuple[float, float, float, float, str]  # (x0, y0, x1, y1, side of the door)


def office_map(seed: int = 3) -> tuple[NDArray[np.uint8], dict]:
    """The map image (image orientation: row 0 is the largest y) and its map_server YAML dict.

    Drawn in steps, each taking its draws from the one generator in turn (same seed, same map)."""
    rng = np.random.default_rng(seed)
    cv = Canvas(SIZE_M, RESOLUTION)
    # the building's inside is free; walls are drawn over it, doors cut back through them
    cv.rect(X_IN0, Y_IN0, X_IN1, Y_IN1, FREE)
    _walls(cv)
    rooms, doors = _rooms(cv, rng)
    doors += _open_plan_openings(rng)
    for x0, y0, x1, y1 in doors:
        cv.rect(x0, y0, x1, y1, FREE)
    near_door = _DoorDistance(np.array([[(x0 + x1) / 2, (y0 + y1) / 2] for x0, y0, x1, y1 in doors]))
    _door_leaves(cv, rng, doors)
    for room in rooms:
        _furnish(cv, rng, room, near_door)
    _open_plan_desks(cv, rng)
    _corridor_clutter(cv, rng, near_door)
    # what a lidar map has besides: rough walls, speckles, unknown shadows, free pixels outside
    _lidar_noise(cv, rng)
    _unknown_corners(cv, rng, rooms, near_door)
    _window_rays(cv, rng)
    image = cv.pixels[::-1].copy()  # image row 0 is the largest y
    meta = {
        "image": "office.pgm",
        "mode": "trinary",
        "resolution": RESOLUTION,
        "origin": [-1.0, -0.5, 0.0],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    return image, meta


def _hwall(cv: Canvas, x0: float, x1: float, y: float, t: float = 0.12) -> None:
    cv.rect(x0, y - t / 2, x1, y + t / 2, OCCUPIED)


def _vwall(cv: Canvas, y0: float, y1: float, x: float, t: float = 0.12) -> None:
    cv.rect(x - t / 2, y0, x + t / 2, y1, OCCUPIED)


def _walls(cv: Canvas) -> None:
    """The outer wall, the corridors' walls (rooms on both sides) cut by the cross corridors."""
    cv.rect(X_IN0 - WALL_M, Y_IN0 - WALL_M, X_IN1 + WALL_M, Y_IN0, OCCUPIED)
    cv.rect(X_IN0 - WALL_M, Y_IN1, X_IN1 + WALL_M, Y_IN1 + WALL_M, OCCUPIED)
    cv.rect(X_IN0 - WALL_M, Y_IN0 - WALL_M, X_IN0, Y_IN1 + WALL_M, OCCUPIED)
    cv.rect(X_IN1, Y_IN0 - WALL_M, X_IN1 + WALL_M, Y_IN1 + WALL_M, OCCUPIED)
    for y in (SOUTH[0], SOUTH[1], NORTH[0], NORTH[1]):
        for bx0, bx1 in [(X_IN0, X_IN1)] if y in (SOUTH[0], NORTH[1]) else BLOCKS_X:
            _hwall(cv, bx0, bx1, y)
    for cx0, cx1 in CROSS:
        _vwall(cv, SOUTH[1], NORTH[0], cx0)
        _vwall(cv, SOUTH[1], NORTH[0], cx1)


def _rooms(cv: Canvas, rng: np.random.Generator) -> tuple[list[Room], list[Box]]:
    """Rows of rooms along the corridors (the spine walls between the rows facing south and
    north drawn), each room's walls, and the doors to cut: the rooms and the doors."""
    rows = [(X_IN0, X_IN1, Y_IN0, SOUTH[0], "north"), (X_IN0, X_IN1, NORTH[1], Y_IN1, "south")]
    for i, (bx0, bx1) in enumerate(BLOCKS_X):
        if i == 1:
            continue  # the centre block is an open-plan office
        rows.append((bx0, bx1, SOUTH[1], SPINE, "south"))
        rows.append((bx0, bx1, SPINE, NORTH[0], "north"))
        _hwall(cv, bx0, bx1, SPINE)
    rooms: list[Room] = []
    doors: list[Box] = []
    for bx0, bx1, y0, y1, side in rows:
        for k, (rx0, rx1) in enumerate(_partition(rng, bx0, bx1)):
            _room(cv, rng, k, (rx0, y0, rx1, y1), side, rooms, doors)
    return rooms, doors


def _room(cv: Canvas, rng: np.random.Generator, k: int, box: Box, side: str, rooms: list[Room], doors: list[Box]) -> None:
    """Room ``k`` of a row (a deep one maybe split into a front and a back room), its door to the
    corridor (about one in eight narrower than the robot), maybe a door to its neighbour."""
    rx0, y0, rx1, y1 = box
    if k > 0:
        _vwall(cv, y0, y1, rx0)
    deep = y1 - y0 > 8.0
    if deep and rng.random() < 0.5:  # a deep room split into a front and a back room
        cut = (y0 + y1) / 2 + float(rng.uniform(-1, 1))
        _hwall(cv, rx0, rx1, cut)
        dx = float(rng.uniform(rx0 + 0.5, rx1 - 1.4))
        width = float(rng.uniform(0.8, 0.9))
        doors.append((dx, cut - 0.1, dx + width, cut + 0.1))
        rooms.append((rx0, y0, rx1, cut, side))
        rooms.append((rx0, cut, rx1, y1, side))
    else:
        rooms.append((rx0, y0, rx1, y1, side))
    # the door to the corridor; about one room in eight has one narrower than the robot
    width = float(rng.uniform(0.55, 0.62)) if rng.random() < 0.12 else float(rng.uniform(0.8, 0.9))
    dx = float(rng.uniform(rx0 + 0.35, rx1 - 0.35 - width))
    y_wall = y1 if side == "north" else y0
    doors.append((dx, y_wall - 0.1, dx + width, y_wall + 0.1))
    if k > 0 and rng.random() < 0.3:  # a door to the neighbouring room
        dy = float(rng.uniform(y0 + 0.5, y1 - 1.4))
        doors.append((rx0 - 0.1, dy, rx0 + 0.1, dy + float(rng.uniform(0.8, 0.9))))


def _open_plan_openings(rng: np.random.Generator) -> list[Box]:
    """The open-plan office: wide openings onto the corridors instead of doors."""
    openings = []
    ox0, ox1 = BLOCKS_X[1]
    for y_wall in (SOUTH[1], NORTH[0]):
        for k in range(2):
            gx = ox0 + 2.0 + k * (ox1 - ox0 - 5.6) + float(rng.uniform(0, 1.0))
            openings.append((gx, y_wall - 0.1, gx + float(rng.uniform(1.4, 1.8)), y_wall + 0.1))
    return openings


class _DoorDistance:
    """Whether a point is near a door (its opening's centre)."""

    def __init__(self, door_centres: NDArray[np.float64]) -> None:
        self.door_centres = door_centres

    def __call__(self, x: float, y: float, distance: float) -> bool:
        return bool(np.min(np.hypot(*(self.door_centres - [x, y]).T)) < distance)


def _door_leaves(cv: Canvas, rng: np.random.Generator, doors: list[Box]) -> None:
    """Open door leaves: a thin line at right angles to the wall at one jamb, into the room."""
    for x0, y0, x1, y1 in doors:
        if rng.random() < 0.4 and (x1 - x0) > (y1 - y0):  # doors in east-west walls
            y_mid = (y0 + y1) / 2
            into = -1.0 if any(lo <= y_mid + 0.6 <= hi for lo, hi in (SOUTH, NORTH)) else 1.0
            xj = x0 if rng.random() < 0.5 else x1
            cv.rect(xj - 0.02, y_mid + into * 0.1, xj + 0.03, y_mid + into * (0.1 + (x1 - x0)), OCCUPIED)


def _furnish(cv: Canvas, rng: np.random.Generator, room: Room, near_door: _DoorDistance) -> None:
    """Desks (a chair beside each) in a room, maybe a cabinet against a wall with an unknown
    shadow in the corner beside it."""
    x0, y0, x1, y1, _ = room
    for _ in range(int(rng.integers(2, 6))):
        _desk_with_chair(cv, rng, room, near_door)
    if rng.random() < 0.5:  # a cabinet against a wall, an unknown shadow in the corner beside it
        length = float(rng.uniform(0.8, 1.8))
        if x1 - x0 > length + 1.0:
            cx0 = float(rng.uniform(x0 + 0.3, x1 - 0.3 - length))
            top = rng.random() < 0.5
            cy0 = y1 - 0.12 - 0.45 if top else y0 + 0.12
            if not near_door(cx0 + length / 2, cy0, 1.5):
                cv.rect(cx0, cy0, cx0 + length, cy0 + 0.45, OCCUPIED)
                sx0 = cx0 + length
                cv.rect(sx0, cy0, min(sx0 + 0.3, x1 - 0.1), cy0 + 0.3, UNKNOWN)


def _desk_with_chair(cv: Canvas, rng: np.random.Generator, room: Room, near_door: _DoorDistance) -> None:
    """A desk against a wall or free-standing, clear of the doors, and a chair beside it."""
    x0, y0, x1, y1, _ = room
    w, d = float(rng.uniform(1.2, 1.6)), float(rng.uniform(0.6, 0.8))
    along_x = rng.random() < 0.5
    sx, sy = (w, d) if along_x else (d, w)
    if x1 - x0 < sx + 0.6 or y1 - y0 < sy + 0.6:
        return
    # against a wall or free-standing
    px = float(rng.uniform(x0 + 0.1, x1 - 0.1 - sx))
    py = float(rng.uniform(y0 + 0.1, y1 - 0.1 - sy))
    if rng.random() < 0.6:
        if along_x:
            py = y0 + 0.1 if rng.random() < 0.5 else y1 - 0.1 - sy
        else:
            px = x0 + 0.1 if rng.random() < 0.5 else x1 - 0.1 - sx
    if near_door(px + sx / 2, py + sy / 2, 1.2 + max(sx, sy) / 2):
        return
    _desk(cv, rng, px, py, sx, sy)
    # a chair beside it
    cx = px + sx / 2 + float(rng.uniform(-0.3, 0.3))
    cy = py + sy / 2 + (sy / 2 + 0.35) * (1 if rng.random() < 0.5 else -1)
    if not near_door(cx, cy, 1.0):
        cv.blob(rng, cx, cy, float(rng.uniform(0.2, 0.3)))


def _open_plan_desks(cv: Canvas, rng: np.random.Generator) -> None:
    """The open plan: rows of desk pairs with aisles of 0.9-1.4 m, chairs in the aisles."""
    ox0, ox1, oy0, oy1 = BLOCKS_X[1][0] + 1.5, BLOCKS_X[1][1] - 1.5, SOUTH[1] + 2.0, NORTH[0] - 2.0
    y = oy0
    while y + 1.4 < oy1:
        x = ox0
        while x + 1.6 < ox1:
            _desk(cv, rng, x, y, 1.6, 1.4)
            if rng.random() < 0.7:
                cv.blob(rng, x + 0.8 + float(rng.uniform(-0.4, 0.4)), y - 0.35, float(rng.uniform(0.2, 0.28)))
            x += 1.6 + float(rng.uniform(0.0, 0.25))  # desks side by side, sometimes a gap between
        y += 1.4 + float(rng.uniform(0.9, 1.4))


def _corridor_clutter(cv: Canvas, rng: np.random.Generator, near_door: _DoorDistance) -> None:
    """Bins and plants against the corridor walls, away from doors and junctions."""
    for y_lo, y_hi in (SOUTH, NORTH):
        for _ in range(10):
            x = float(rng.uniform(3.0, 55.0))
            if near_door(x, (y_lo + y_hi) / 2, 1.6) or any(abs(x - (a + b) / 2) < 2.5 for a, b in CROSS):
                continue
            top = rng.random() < 0.5
            cv.blob(rng, x, (y_hi - 0.3) if top else (y_lo + 0.3), float(rng.uniform(0.15, 0.25)))


def _lidar_noise(cv: Canvas, rng: np.random.Generator) -> None:
    """Rough walls, single occupied pixels in free space, small unknown patches."""
    pixels = cv.pixels
    free = pixels == FREE
    occ = pixels == OCCUPIED
    edge = free & (cv2.dilate(occ.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
    bumps = edge & (rng.random(pixels.shape) < 0.06)
    pixels[bumps] = OCCUPIED
    free_cells = np.argwhere(pixels == FREE)
    for r, c in free_cells[rng.integers(len(free_cells), size=60)]:
        pixels[r, c] = OCCUPIED  # single-pixel returns from nothing (lidar noise)
    for r, c in free_cells[rng.integers(len(free_cells), size=120)]:
        pixels[r : r + int(rng.integers(1, 3)), c : c + int(rng.integers(1, 3))] = UNKNOWN


def _unknown_corners(cv: Canvas, rng: np.random.Generator, rooms: list[Room], near_door: _DoorDistance) -> None:
    """Unknown corners of rooms (never seen), pixels adjacent to walls left unknown."""
    for x0, y0, x1, y1, _ in rooms:
        if rng.random() < 0.4:
            sx, sy = float(rng.uniform(0.3, 0.8)), float(rng.uniform(0.3, 0.8))
            corner_x = x0 + 0.06 if rng.random() < 0.5 else x1 - 0.06 - sx
            corner_y = y0 + 0.06 if rng.random() < 0.5 else y1 - 0.06 - sy
            if not near_door(corner_x + sx / 2, corner_y + sy / 2, 1.3):
                cv.rect(corner_x, corner_y, corner_x + sx, corner_y + sy, UNKNOWN)


def _window_rays(cv: Canvas, rng: np.random.Generator) -> None:
    """Rays through windows: free streaks outside the building."""
    for _ in range(25):
        x = float(rng.uniform(2, 56))
        cv.rect(x, 0.1, x + float(rng.uniform(0.1, 0.6)), float(rng.uniform(0.3, 0.9)), FREE)


def _desk(cv: Canvas, rng: np.random.Generator, x: float, y: float, sx: float, sy: float) -> None:
    """A desk as a lidar map shows it: a solid block (a modesty panel at scan height) or its legs."""
    if rng.random() < 0.5:
        cv.rect(x, y, x + sx, y + sy, OCCUPIED)
        return
    leg = 0.08
    for lx, ly in ((x, y), (x + sx - leg, y), (x, y + sy - leg), (x + sx - leg, y + sy - leg)):
        cv.rect(lx, ly, lx + leg, ly + leg, OCCUPIED)
    cv.rect(x + leg, y + leg, x + sx - leg, y + sy - leg, UNKNOWN if rng.random() < 0.3 else FREE)


def scenario_dict(name: str = "office", seed: int = 5, route_length: float = 700.0, trials: int = 12) -> dict:
    return {
        "format": "navtopo-scenario/1",
        "name": name,
        "description": "a synthetic office floor mapped by a robot (58 x 47 m, 0.05 m/px): rooms off corridors, clutter",
        "seed": seed,
        "world": {"wall_height": 2.6, "map": {"yaml": "office.yaml"}},
        "robot": {"radius": 0.3, "max_linear": 1.0, "max_angular": 1.5},
        "odometry": {"noise": None},
        "mapping_route": {"auto": {"min_length": route_length}},
        "trials": {"generate": {"count": trials, "min_distance": 15}},
    }


def write_office(out_dir: Path, seed: int = 3) -> Path:
    """Write the map and a scenario on it; returns the scenario file."""
    out_dir.mkdir(parents=True, exist_ok=True)
    image, meta = office_map(seed)
    frame = GridFrame(np.array(meta["origin"][:2], dtype=np.float64), meta["resolution"])
    write_map_server(out_dir / "office.yaml", image[::-1], frame, image_format="pgm", thresholds=(0.65, 0.196))
    scenario = out_dir / "office_scenario.yaml"
    scenario.write_text(yaml.safe_dump(scenario_dict(), sort_keys=False, default_flow_style=None))
    return scenario


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    print(f"wrote {write_office(args.out_dir, args.seed)}")


if __name__ == "__main__":
    main()
