"""Location grids: a lidar point cloud in the robot frame -> a 2D occupancy grid around it.

NavTopo (Muravyev & Yakovlev, Sec. "Graph Structure") stores one such grid per location
(vertex); scan matching, the "still inside" test and local planning all read it.

The grids and how one is built from a cloud: ``navkit.scan_grid`` (its docstring has the layout).

Warping (``warp``) and overlap (``known_overlap``, ``overlap``; ``known_iou`` too) follow ``navkit.geometry``:
``warp(grid, T)`` is the grid as seen from the frame ``T`` (a pose given in the grid's frame), so a
grid taken at pose A, warped by ``between(A, B)``, lines up with the grid taken at pose B.

Storage: a 300 x 300 grid is 90 kB, but the known part of a location is usually much smaller
(a corridor stretch, a room). ``CroppedGrid`` keeps only the bounding box of the known cells
(corridor_150m: median 15 kB, p90 37 kB, max 57 kB), and ``encode_png`` / ``decode_png`` give a
lossless form (median 1.2 kB, max 2 kB) for files, or for memory if decoding on use (~0.2 ms)
is acceptable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from navkit.geometry import inverse
from navkit.raster import OCCUPIED, UNKNOWN
from navkit.scan_grid import Grid, GridConfig


def _warp_matrix(pose: ArrayLike, size_in: int, size_out: int, resolution: float) -> NDArray:
    """2x3 affine map from output pixel coordinates to input pixel coordinates (OpenCV's
    pixel centres at integers), for the output frame at ``pose`` in the input frame."""
    x, y, yaw = np.asarray(pose, dtype=np.float64)
    c, s = np.cos(yaw), np.sin(yaw)
    h_in = size_in / 2.0 - 0.5
    h_out = size_out / 2.0 - 0.5
    # input pixel = R (output pixel - h_out) + t / res + h_in; +0.5 because warpAffine's
    # nearest-neighbour lookup truncates rather than rounds
    return np.array(
        [
            [c, -s, x / resolution + h_in - (c - s) * h_out],
            [s, c, y / resolution + h_in - (s + c) * h_out],
        ]
    )


def warp(
    grid: Grid,
    pose: ArrayLike,
    config: GridConfig | None = None,
    size: int | None = None,
) -> Grid:
    """The grid as seen from the frame ``pose`` (``[x, y, yaw]`` given in the grid's frame).

    The output cell at point p of the new frame takes the value of the input cell at
    ``transform_points(pose, p)``; cells that fall outside the input are ``UNKNOWN``. So for
    grids taken at poses A and B, ``warp(grid_A, between(A, B))`` is in B's frame.
    Nearest-neighbour lookup keeps the three cell values. ``size`` sets the output side
    (default: the input's).
    """
    config = config or GridConfig()
    size_in = grid.shape[0]
    size_out = size or size_in
    matrix = _warp_matrix(pose, size_in, size_out, config.resolution)
    warped = cv2.warpAffine(
        grid,
        matrix,
        (size_out, size_out),
        flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=UNKNOWN,
    )
    return np.asarray(warped, dtype=np.uint8)


def warp_window(cropped: CroppedGrid, pose: ArrayLike, resolution: float, size: int, window: tuple[int, int, int, int]) -> Grid:
    """``warp(cropped.to_grid(), pose, size=size)[r0:r1, c0:c1]`` for ``window = (r0, r1, c0, c1)``,
    without making either full grid: the warp reads the cropped cells through a shifted affine map."""
    r0, r1, c0, c1 = window
    matrix = _warp_matrix(pose, cropped.size, size, resolution)
    # output pixel (x, y) of the window is (x + c0, y + r0) of the whole output; the input's pixel
    # (x, y) is (x - col0, y - row0) of the cropped cells
    matrix[:, 2] += matrix[:, :2] @ np.array([c0, r0], dtype=np.float64) - np.array([cropped.col0, cropped.row0])
    if cropped.cells.size == 0:
        return np.full((r1 - r0, c1 - c0), UNKNOWN, dtype=np.uint8)
    warped = cv2.warpAffine(
        cropped.cells,
        matrix,
        (c1 - c0, r1 - r0),
        flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=UNKNOWN,
    )
    return np.asarray(warped, dtype=np.uint8).reshape(r1 - r0, c1 - c0)


def warped_bounds(
    cropped: CroppedGrid, pose: ArrayLike, resolution: float, size: int, margin: int = 1
) -> tuple[int, int, int, int]:
    """``(r0, r1, c0, c1)``: the part of ``warp(cropped.to_grid(), pose, size=size)`` that can hold
    the cropped cells' values (their corners mapped into the output, ``margin`` cells wider, clipped
    to the output); an empty box when there are none."""
    height, width = cropped.cells.shape
    if height == 0 or width == 0:
        return 0, 0, 0, 0
    (a, b, tx), (c, d, ty) = _warp_matrix(pose, cropped.size, size, resolution).tolist()  # output pixel -> input pixel
    # its inverse (a rotation's is its transpose) at the crop's four corners, in plain floats
    xs, ys = (cropped.col0 - 1, cropped.col0 + width), (cropped.row0 - 1, cropped.row0 + height)
    corners = [(x - tx, y - ty) for x in xs for y in ys]
    cols = [a * x + c * y for x, y in corners]
    rows = [b * x + d * y for x, y in corners]

    def clip(value: float) -> int:
        return min(max(int(value), 0), size)

    c0, c1 = clip(math.floor(min(cols)) - margin), clip(math.ceil(max(cols)) + 1 + margin)
    r0, r1 = clip(math.floor(min(rows)) - margin), clip(math.ceil(max(rows)) + 1 + margin)
    return r0, max(r1, r0), c0, max(c1, c0)


def wall_direction(cells: Grid) -> tuple[float, float]:
    """The direction the walls of a grid (any ``(H, W)`` cells, ``OCCUPIED`` the walls) run along,
    modulo 90°, in the grid's frame: ``(angle, weight)``, angle in radians in [-45°, 45°) from +x
    (a wall along +x or +y gives 0), weight the summed strength of the evidence (0: no walls).

    Rooms, corridors and doors mostly meet at right angles: each wall cell's edge direction (the
    gradient of the blurred wall cells) is taken with its angle times four, so that directions 90°
    apart agree, and averaged (the mean of directions on the circle, as a structure tensor does for
    180°). Weights of several grids add up when their angles, turned into one frame, are averaged
    the same way (``mean_direction``)."""
    walls = (np.asarray(cells) == OCCUPIED).astype(np.float32)
    if walls.shape[0] < 3 or walls.shape[1] < 3 or not walls.any():
        return 0.0, 0.0
    walls = cv2.GaussianBlur(walls, (5, 5), 1.0)
    gx = cv2.Sobel(walls, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(walls, cv2.CV_32F, 0, 1, ksize=3)
    magnitude = np.hypot(gx, gy)
    quadrupled = 4.0 * np.arctan2(gy, gx)
    c, s = float((magnitude * np.cos(quadrupled)).sum()), float((magnitude * np.sin(quadrupled)).sum())
    return _quarter(np.arctan2(s, c) / 4.0), float(np.hypot(c, s))


def mean_direction(angles: ArrayLike, weights: ArrayLike) -> float:
    """The weighted mean modulo 90° of wall directions (radians, each in any frame turned into one),
    in [-45°, 45°); 0 without weight."""
    quadrupled = 4.0 * np.asarray(angles, dtype=np.float64)
    w = np.asarray(weights, dtype=np.float64)
    c, s = float((w * np.cos(quadrupled)).sum()), float((w * np.sin(quadrupled)).sum())
    return _quarter(np.arctan2(s, c) / 4.0) if np.hypot(c, s) > 0 else 0.0


def _quarter(angle: float) -> float:
    return float((angle + np.pi / 4) % (np.pi / 2) - np.pi / 4)


def known_iou(grid_a: Grid, grid_b: Grid) -> float:
    """Intersection over union of the known (free or occupied) cells of two grids in one frame."""
    known_a = grid_a != UNKNOWN
    known_b = grid_b != UNKNOWN
    union = np.count_nonzero(known_a | known_b)
    return float(np.count_nonzero(known_a & known_b)) / union if union else 0.0


def known_overlap(grid_a: Grid, grid_b: Grid) -> float:
    """Shared known cells over the smaller known area (the overlap coefficient) of two grids in one
    frame. Unlike the IoU it does not fall when one scan also sees far into rooms through doors
    that the other does not: it asks whether the two look at the same place, not the same much."""
    known_a = grid_a != UNKNOWN
    known_b = grid_b != UNKNOWN
    smaller = min(np.count_nonzero(known_a), np.count_nonzero(known_b))
    return float(np.count_nonzero(known_a & known_b)) / smaller if smaller else 0.0


def overlap(reference: Grid, query: Grid, pose: ArrayLike, config: GridConfig | None = None) -> float:
    """``known_overlap`` of two grids, the query's observation point lying at ``pose`` in the
    reference frame (the convention of ``scan_matching.match``: ``between(A, B)`` for a
    reference taken at A and a query at B)."""
    in_reference = warp(query, inverse(pose), config, size=reference.shape[0])
    return known_overlap(reference, in_reference)


@dataclass(frozen=True)
class CroppedGrid:
    """The bounding box of a grid's known cells: what a graph vertex keeps in memory.

    ``cells[r, c]`` is cell ``(row0 + r, col0 + c)`` of the full ``(size, size)`` grid.
    """

    cells: Grid
    row0: int
    col0: int
    size: int

    @classmethod
    def from_grid(cls, grid: Grid) -> CroppedGrid:
        rows = np.flatnonzero((grid != UNKNOWN).any(axis=1))
        cols = np.flatnonzero((grid != UNKNOWN).any(axis=0))
        if rows.size == 0:
            return cls(np.zeros((0, 0), dtype=np.uint8), 0, 0, grid.shape[0])
        r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        return cls(np.ascontiguousarray(grid[r0:r1, c0:c1]), int(r0), int(c0), grid.shape[0])

    def to_grid(self) -> Grid:
        grid = np.zeros((self.size, self.size), dtype=np.uint8)
        h, w = self.cells.shape
        grid[self.row0 : self.row0 + h, self.col0 : self.col0 + w] = self.cells
        return grid

    @cached_property
    def wall_axis(self) -> tuple[float, float]:
        """``wall_direction`` of the cells (the grid is never changed once made): a union grid turns
        to its members' walls, and a loaded map has each location's made as it loads."""
        return wall_direction(self.cells)

    @property
    def nbytes(self) -> int:
        """Bytes of the cells plus the three integers and the wall direction's two floats."""
        return int(self.cells.nbytes) + 5 * 8


def encode_png(grid: Grid) -> bytes:
    """Lossless PNG bytes of a grid (cell values 0/1/2 stored as they are)."""
    ok, buffer = cv2.imencode(".png", np.ascontiguousarray(grid, dtype=np.uint8))
    if not ok:
        raise ValueError("could not encode the grid as PNG")
    return buffer.tobytes()


def decode_png(data: bytes) -> Grid:
    """The grid of ``encode_png``; raises ``ValueError`` on bytes that are not such a PNG."""
    grid = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if grid is None or grid.ndim != 2 or grid.dtype != np.uint8:
        raise ValueError("not a single-channel 8-bit PNG grid")
    if grid.size and grid.max() > OCCUPIED:
        raise ValueError(f"grid PNG holds a cell value above {OCCUPIED}")
    return np.asarray(grid, dtype=np.uint8)
