"""A* and any-angle Lazy Theta* on 2-D occupancy grids, compiled with numba.

References
    P. E. Hart, N. J. Nilsson, B. Raphael. "A Formal Basis for the Heuristic Determination of
    Minimum Cost Paths". IEEE Trans. SSC 4(2), 1968 (A*).
    K. Daniel, A. Nash, S. Koenig, A. Felner. "Theta*: Any-Angle Path Planning on Grids".
    Journal of Artificial Intelligence Research 39, 2010.
    A. Nash, S. Koenig, C. Tovey. "Lazy Theta*: Any-Angle Path Planning and Path Length
    Analysis in 3D". AAAI 2010.

Grid convention (used by every function here):

* ``free`` is a bool array ``(H, W)`` indexed ``[row, col]``; True means the robot's centre may
  be there. Rows go with y, columns with x, both increasing with the index.
* A cell is an int pair ``(row, col)``. The centre of cell ``(r, c)`` is at world
  ``(origin_x + (c + 0.5) * resolution, origin_y + (r + 0.5) * resolution)``, so ``origin`` is
  the world position of the outer corner of cell ``(0, 0)``.
* Paths are ``(K, 2)`` int64 arrays of cells, start first; path lengths are Euclidean between
  consecutive cell centres. Everything outside the array is blocked.

Motion rules, identical in A*, Theta* and ``line_of_sight``: a step may go to any of the 8
neighbours, but a diagonal step needs both cells beside it free (no cutting a wall corner);
a straight segment between two cell centres must cross only free cells, and where it passes
exactly through a grid corner all four cells at that corner must be free.

Theta* here is Lazy Theta* (one line-of-sight check per expansion instead of one per generated
neighbour), then a greedy shortcut pass and a local vertex refinement. Path vertices are cell
centres and segments keep off blocked cells entirely, so around a rounded (inflated) corner a
path runs up to about a cell wide of the eroded boundary; on a raster made from shapes (a cell
is free iff its centre is in free space) that offsets the half cell by which the raster's
walls stand inside the true ones, and the tests find lengths within 0.3 % of the exact
continuous shortest path around an inflated wall (the contract is 1 %). A path starts and ends
at the centres of the start and goal cells: a caller following it in the world replaces its
ends with the exact start and goal points (each within half a cell of them).

Speed: one search allocates its per-cell arrays with ``np.empty`` (only a uint8 state array is
zero-filled), the open list is an indexed binary heap, and line of sight leaps across open
ground using a Chebyshev clearance map computed once per ``theta_star`` call. Planners return
``None`` (never raise) when the start or goal is blocked or outside the grid, or when no path
exists. ``benchmarks/bench_grid_search.py`` measures plan times on 1000^2 and 3000^2 grids.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

from navkit.raster import TILE, TILE_SHIFT, TiledRaster

Cell = tuple[int, int]
CellPath = NDArray[np.int64]

SQRT2 = math.sqrt(2.0)
SQRT1_2 = math.sqrt(0.5)
FIELD_PER_CELL = 8.0  # a goal field's steps a cell (lengths kept to 1/16 cell), fewer on huge maps
FIELD_UNREACHED = 65535  # a goal field's value where no way leads


# --------------------------------------------------------------------------------------------
# Grid preparation and coordinates
# --------------------------------------------------------------------------------------------


def inflate_free(free: ArrayLike, radius_m: float, resolution: float) -> NDArray[np.bool_]:
    """Erode free space by a robot radius.

    free: (H, W) bool. Returns (H, W) bool: the free cells whose centre is at least ``radius_m``
    from the centre of every non-free cell; outside the array counts as non-free. This is
    ``scipy.ndimage.distance_transform_edt(free) * resolution >= radius_m`` (tested equal), but
    computed with ``clearance_squared``'s compiled exact transform, faster than scipy's and
    OpenCV's. The wall surface lies about half a cell nearer than a non-free cell's centre: pass
    ``radius + resolution / 2`` for a clearance that holds to the cell boundary.
    """
    free = np.asarray(free, dtype=bool)
    if free.ndim != 2:
        raise ValueError(f"free must be a 2-D bool array, got shape {free.shape}")
    if radius_m <= 0.0:
        return free.copy()
    return clear_of(clearance_squared(free), radius_m, resolution)


def clearance_squared(free: ArrayLike) -> NDArray[np.int32]:
    """(H, W) int32 squared distance, in cells, from each cell's centre to the nearest non-free
    cell's centre (outside the array counts as non-free); 0 on non-free cells. Exact, in integers
    (``_squared_distance_kernel``: no cell at exactly a radius flips with rounding); ``clear_of``
    thresholds it for a radius: one transform serves every radius."""
    free = np.asarray(free, dtype=bool)
    if free.ndim != 2:
        raise ValueError(f"free must be a 2-D bool array, got shape {free.shape}")
    return np.asarray(_squared_distance_kernel(np.ascontiguousarray(free), True))


def squared_distance_to(blocked: ArrayLike) -> NDArray[np.int32]:
    """(H, W) int32 squared distance in cells from each cell's centre to the nearest cell of
    ``blocked`` (bool; the outside of the array not counted; with none in the array (H + W)^2),
    exact: the kernel of ``clearance_squared``."""
    blocked = np.asarray(blocked, dtype=bool)
    return np.asarray(_squared_distance_kernel(np.ascontiguousarray(~blocked), False))


def far_from(
    blocked: NDArray[np.bool_], cells: ArrayLike, radius_m: float, resolution: float, outside: bool
) -> NDArray[np.bool_]:
    """Whether each cell (N, 2) [row, col] lies at least ``radius_m`` from the centre of every cell
    of ``blocked`` (H, W), centre to centre (``outside``: the answer for a cell off the grid):
    ``squared_distance_to(blocked) >= (radius_m / resolution)^2`` there, from the cells round each
    alone (no transform of the whole grid for a few points)."""
    cells = np.asarray(cells, dtype=np.int64).reshape(-1, 2)
    radius_cells = radius_m / resolution
    threshold = radius_cells * radius_cells - 1e-6
    return np.asarray(_far_from_kernel(np.ascontiguousarray(blocked, dtype=np.bool_), cells, threshold, outside))


@njit(cache=True, nogil=True)
def _far_from_kernel(blocked, cells, threshold, outside):
    height, width = blocked.shape
    reach = int(math.ceil(math.sqrt(max(threshold, 0.0))))
    out = np.empty(cells.shape[0], np.bool_)
    for i in range(cells.shape[0]):
        r, c = cells[i, 0], cells[i, 1]
        if r < 0 or r >= height or c < 0 or c >= width:
            out[i] = outside
            continue
        clear = True
        for dr in range(max(-reach, -r), min(reach, height - 1 - r) + 1):
            for dc in range(max(-reach, -c), min(reach, width - 1 - c) + 1):
                if dr * dr + dc * dc < threshold and blocked[r + dr, c + dc]:
                    clear = False
                    break
            if not clear:
                break
        out[i] = clear
    return out


def without_disks(passable: NDArray[np.bool_], cells: ArrayLike, radius_m: float, resolution: float) -> NDArray[np.bool_]:
    """A copy of ``passable`` (H, W) bool without the cells whose centre lies within ``radius_m`` of
    the centre of one of ``cells`` (N, 2) [row, col] (a cell off the grid too: its disk may reach
    onto it): new obstacles grown by a radius. Within: (rows² + cols²) resolution² <= radius_m², in
    floats (3 cells at 0.1 m is not within 0.3 m). The same cells as dilating a stamp of them by a disk
    (OpenCV), written disk by disk (compiled): a scan's hundred-odd obstacles cost a few
    microseconds, where a dilation costs its box of the grid."""
    offsets = _disk_offsets(radius_m, resolution)
    out = np.array(passable, dtype=np.bool_, copy=True)
    _clear_disks(out, np.ascontiguousarray(np.asarray(cells, dtype=np.int64).reshape(-1, 2)), offsets)
    return out


@functools.lru_cache(maxsize=16)
def _disk_offsets(radius_m: float, resolution: float) -> NDArray[np.int64]:
    """(K, 2) [row, col] offsets of the cells whose centre lies within ``radius_m`` of a cell's."""
    reach = int(np.ceil(radius_m / resolution))
    rows, cols = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    inside = (rows * rows + cols * cols) * resolution**2 <= radius_m * radius_m
    offsets = np.stack([rows[inside], cols[inside]], axis=1).astype(np.int64)
    offsets.flags.writeable = False  # kept (``lru_cache``): one array for every caller
    return offsets


@njit(cache=True, nogil=True)
def _clear_disks(out, cells, offsets):
    height, width = out.shape
    for i in range(cells.shape[0]):
        for k in range(offsets.shape[0]):
            r = cells[i, 0] + offsets[k, 0]
            c = cells[i, 1] + offsets[k, 1]
            if 0 <= r < height and 0 <= c < width:
                out[r, c] = False


def clear_of(squared: NDArray, radius_m: float, resolution: float) -> NDArray[np.bool_]:
    """The cells of ``clearance_squared`` at least ``radius_m`` from every non-free cell."""
    radius_cells = radius_m / resolution
    return squared >= radius_cells * radius_cells - 1e-6


def medial_axis(squared: NDArray) -> NDArray[np.bool_]:
    """(H, W) the cells of a clearance raster (``clearance_squared``, any monotone form)
    on the medial axis of the free space: at least as clear as both neighbours on some line through
    the cell (along a row, a column or a diagonal) and clearer than one of them. Across a passage
    that is its middle cell, or its middle two; along a passage, where the clearance is level, no
    cell counts by that line. Non-free cells (clearance 0) never count."""
    clearance = np.asarray(squared).astype(np.int32)
    padded = np.pad(clearance, 1, mode="constant", constant_values=0)
    height, width = clearance.shape
    centre = padded[1:-1, 1:-1]
    on_axis = np.zeros(clearance.shape, bool)
    for (r1, c1), (r2, c2) in (((0, 1), (2, 1)), ((1, 0), (1, 2)), ((0, 0), (2, 2)), ((0, 2), (2, 0))):
        a = padded[r1 : r1 + height, c1 : c1 + width]
        b = padded[r2 : r2 + height, c2 : c2 + width]
        on_axis |= (centre >= a) & (centre >= b) & ((centre > a) | (centre > b))
    return on_axis & (clearance > 0)


def passable(squared: NDArray, radius_m: float, resolution: float, medial_m: float | None = None) -> NDArray[np.bool_]:
    """The cells a robot's centre may take on a clearance raster (``clearance_squared``): those
    ``radius_m`` clear of every non-free cell's centre; with ``medial_m``, also the cells of the free
    space's medial axis (``medial_axis``) that far clear: a passage narrower than the radius allows
    (a door of the robot's width and a little more whose jambs the map drew a cell into it), passed
    along its middle. Where two of these cells touch only diagonally, which the search never steps
    (no corner cut), the clearer side cell joins them (``four_connected``): a passage on a slant,
    whose medial axis steps diagonally from cell to cell, is passable along it."""
    mask = clear_of(squared, radius_m, resolution)
    least = radius_m
    if medial_m is not None:
        mask |= medial_axis(squared) & clear_of(squared, medial_m, resolution)
        least = min(radius_m, medial_m)
    return four_connected(mask, squared, least / resolution)


def bridge_clearance(threshold_cells: float) -> float:
    """Cells: the clearance (to a non-free cell's centre) a side cell needs to join two cells at
    least ``threshold_cells`` clear that touch only diagonally (``four_connected``).

    For two such cells a and b, and any non-free cell w, |m - w|^2 = (|a - w|^2 + |b - w|^2) / 2 - 1/2
    at the corner m they share (in cells), so m is at least sqrt(t^2 - 1/2) clear, and each side
    cell, 1/sqrt(2) from m, at least sqrt(t^2 - 1/2) - 1/sqrt(2): the value returned, t less 0.79
    cell at t = 3, less 0.75 at t = 6. So for t above one cell every diagonal touch is joined, and
    never across a wall corner: a non-free side cell would leave m within 1/sqrt(2) of it (the
    robot's centre passed that corner as clear as the two cells). On the raster (squared
    clearances are integers) the side is clearer than this bound: at the benchmark robot's
    0.3 m on 0.1 m cells (t = 3, the medial level) at least sqrt(8) = 2.83 cells, 0.283 m; at
    t = 3.5 (the radius plus half a cell) the same. For t of one cell or less (a level of bare free
    cells) the bound is 0 and a side cell must still be free: a wall corner stays shut."""
    return max(math.sqrt(max(threshold_cells * threshold_cells - 0.5, 0.0)) - SQRT1_2, 0.0)


def four_connected(mask: NDArray[np.bool_], squared: NDArray, threshold_cells: float) -> NDArray[np.bool_]:
    """``mask`` (H, W) with every two of its cells that touch only diagonally (both cells beside the
    step outside it) joined through the clearer of those two side cells, if that cell is free and at
    least ``bridge_clearance(threshold_cells)`` clear on ``squared`` (``clearance_squared``); the
    mask's cells are assumed at least ``threshold_cells`` clear. What the 8-connected parts of the
    mask were become 4-connected, as the search moves (``_allowed_moves``), so a path between them
    exists and a 4-connected labelling of the mask agrees with it. The bridge cell keeps the robot's
    centre at most 0.8 cell nearer a wall cell's centre than the level's threshold (t >= 3; on the
    raster at the benchmark's radius 0.17 cell). One pass: a bridge cell's own diagonal touches,
    rare, are not joined. Returns ``mask`` itself when it has no such touch, else a new array."""
    top_left, top_right = mask[:-1, :-1], mask[:-1, 1:]
    bottom_left, bottom_right = mask[1:, :-1], mask[1:, 1:]
    # the 2 x 2 blocks set like a chessboard (by their top-left cell): a touch along one diagonal
    chessboard = top_left ^ top_right
    chessboard &= top_left == bottom_right
    chessboard &= top_right == bottom_left
    corners = np.flatnonzero(chessboard)
    if not len(corners):
        return mask
    rows, cols = np.divmod(corners, mask.shape[1] - 1)
    # the side cells: top-right and bottom-left where the touch is along the main diagonal, else
    # top-left and bottom-right
    step = mask[rows, cols].astype(np.intp)
    first = (rows, cols + step)
    second = (rows + 1, cols + 1 - step)
    first_clear, second_clear = squared[first], squared[second]
    take_first = first_clear >= second_clear
    clearance = np.where(take_first, first_clear, second_clear)
    floor = bridge_clearance(threshold_cells)
    ok = (clearance > 0) & (clearance >= floor * floor - 1e-6)
    joined = mask.copy()
    joined[np.where(take_first, first[0], second[0])[ok], np.where(take_first, first[1], second[1])[ok]] = True
    return joined


def path_length(cells: ArrayLike | None, resolution: float) -> float:
    """Length in metres of a (K, 2) cell path (Euclidean between centres); 0 for K < 2 or None."""
    if cells is None:
        return 0.0
    cells = np.asarray(cells, dtype=np.float64)
    if cells.shape[0] < 2:
        return 0.0
    return float(np.hypot(*np.diff(cells, axis=0).T).sum() * resolution)


# --------------------------------------------------------------------------------------------
# Compiled kernels
# --------------------------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _inside(height: int, width: int, r: int, c: int) -> bool:
    return 0 <= r < height and 0 <= c < width


# The 8 moves are numbered k = 3 * (dr + 1) + (dc + 1), k != 4 (k = 4 is staying put).


@njit(cache=True, inline="always")
def _allowed_moves(passable, r, c) -> int:
    """Bit mask of the moves allowed from cell (r, c): bit k for move (k // 3 - 1, k % 3 - 1).

    passable: the free grid or the clearance grid (nonzero = free). A straight move needs its
    target free; a diagonal move also needs both straight cells beside it free, so no step cuts
    a wall corner. The rule is symmetric (a -> b iff b -> a).
    """
    height, width = passable.shape
    north = r > 0 and passable[r - 1, c] != 0
    south = r < height - 1 and passable[r + 1, c] != 0
    west = c > 0 and passable[r, c - 1] != 0
    east = c < width - 1 and passable[r, c + 1] != 0
    mask = 0
    if north:
        mask |= 1 << 1
        if west and passable[r - 1, c - 1] != 0:
            mask |= 1 << 0
        if east and passable[r - 1, c + 1] != 0:
            mask |= 1 << 2
    if south:
        mask |= 1 << 7
        if west and passable[r + 1, c - 1] != 0:
            mask |= 1 << 6
        if east and passable[r + 1, c + 1] != 0:
            mask |= 1 << 8
    if west:
        mask |= 1 << 3
    if east:
        mask |= 1 << 5
    return mask


@njit(cache=True)
def _squared_distance_kernel(free, outside_blocked):
    """(H, W) int32 the exact squared Euclidean distance transform of the non-free cells (with
    ``outside_blocked`` the outside of the array counts as non-free; else a cell with no non-free
    cell in the array gets (H + W)^2), in two separable passes (P. F. Felzenszwalb, D. P.
    Huttenlocher, "Distance Transforms of Sampled Functions", Theory of Computing 8, 2012): along
    each column the distance to the nearest non-free cell, then along each row the lower envelope of
    the parabolas (c - q)^2 + column(q)^2, the outside's cells at q = -1 and q = W. Linear in the
    cells, integer throughout; the same values as OpenCV's exact transform, 1.5x faster
    (``benchmarks/bench_grid_search.py``)."""
    height, width = free.shape
    far = height + width  # farther than any cell of the array
    column = _column_distances(free, 1 if outside_blocked else far + 1, far)
    out = np.empty((height, width), np.int32)
    sites = np.empty(width + 2, np.int64)  # the envelope's parabolas (their q) and where each starts
    starts = np.empty(width + 3, np.float64)
    heights = np.empty(width + 2, np.int64)  # f(q) = column(q)^2 of each q in -1 .. W
    for r in range(height):
        heights[0] = 0 if outside_blocked else np.int64(far) * far * 4  # a parabola that never wins
        heights[width + 1] = heights[0]
        for c in range(width):
            heights[c + 1] = np.int64(column[r, c]) * column[r, c]
        k = 0
        sites[0] = -1
        starts[0] = -np.inf
        starts[1] = np.inf
        for q in range(0, width + 1):
            f_q = heights[q + 1] + q * q
            while True:
                v = sites[k]
                s = (f_q - (heights[v + 1] + v * v)) / (2.0 * (q - v))
                if s <= starts[k]:
                    k -= 1
                else:
                    break
            k += 1
            sites[k] = q
            starts[k] = s
            starts[k + 1] = np.inf
        k = 0
        for c in range(width):
            while starts[k + 1] < c:
                k += 1
            v = sites[k]
            out[r, c] = min((c - v) * (c - v) + heights[v + 1], np.int64(far) * far)
    return out


@njit(cache=True)
def _column_distances(free, edge, far):
    """(H, W) int32 cells from each cell to the nearest non-free cell of its column (``edge`` from
    the first or last row to the outside; at most ``far``)."""
    height, width = free.shape
    column = np.empty((height, width), np.int32)  # row by row, as the array lies in memory
    for c in range(width):
        column[0, c] = edge if free[0, c] else 0
    for r in range(1, height):
        for c in range(width):
            column[r, c] = column[r - 1, c] + 1 if free[r, c] else 0
    for c in range(width):
        if column[height - 1, c] > edge:
            column[height - 1, c] = edge
    for r in range(height - 2, -1, -1):
        for c in range(width):
            below = column[r + 1, c] + 1
            if below < column[r, c]:
                column[r, c] = below
    for r in range(height):
        for c in range(width):
            if column[r, c] > far:
                column[r, c] = far
    return column


@njit(cache=True)
def _line_of_sight(free, r0, c0, r1, c1) -> bool:
    """Supercover walk over the cells pierced by the segment between two cell centres.

    Both endpoints must be inside the grid. The segment leaves the current cell through a column
    boundary at parameter (ic + 0.5) / n_cols and through a row boundary at (ir + 0.5) / n_rows;
    comparing the two in integers decides the next cell exactly. A tie is a grid corner: the
    segment touches both side cells there, so both must be free.
    """
    if not free[r0, c0] or not free[r1, c1]:
        return False
    n_rows = abs(r1 - r0)
    n_cols = abs(c1 - c0)
    step_r = 1 if r1 > r0 else -1
    step_c = 1 if c1 > c0 else -1
    r = r0
    c = c0
    ir = 0
    ic = 0
    while ir < n_rows or ic < n_cols:
        decision = (2 * ic + 1) * n_rows - (2 * ir + 1) * n_cols
        if decision == 0:
            if not free[r, c + step_c] or not free[r + step_r, c]:
                return False
            r += step_r
            c += step_c
            ir += 1
            ic += 1
        elif decision < 0:
            c += step_c
            ic += 1
        else:
            r += step_r
            ir += 1
        if not free[r, c]:
            return False
    return True


@njit(cache=True)
def _chebyshev_clearance(free):
    """(H, W) uint8: Chebyshev distance in cells from each cell to the nearest blocked cell.

    Blocked cells are 0 and outside the grid counts as blocked, so a cell with clearance k has
    every cell within Chebyshev radius k - 1 free. Two-pass chamfer transform, exact for the
    chessboard metric up to 255 (larger distances saturate: a lower bound is still safe). Lets
    line of sight leap across open ground instead of walking it; one byte a cell keeps the
    random reads of long sight lines in cache.
    """
    height, width = free.shape
    clear = np.empty((height, width), np.uint8)
    cap = 255
    for r in range(height):
        for c in range(width):
            if not free[r, c]:
                clear[r, c] = 0
                continue
            best = 0  # a cell on the border touches the blocked outside
            if r > 0 and 0 < c < width - 1:
                above = min(clear[r - 1, c - 1], clear[r - 1, c], clear[r - 1, c + 1])
                best = min(above, clear[r, c - 1])
            clear[r, c] = min(best + 1, cap)
    for r in range(height - 1, -1, -1):
        for c in range(width - 1, -1, -1):
            value = clear[r, c]
            if value <= 1:
                continue
            best = 0
            if r < height - 1 and 0 < c < width - 1:
                below = min(clear[r + 1, c - 1], clear[r + 1, c], clear[r + 1, c + 1])
                best = min(below, clear[r, c + 1])
            if best + 1 < value:
                clear[r, c] = best + 1
    return clear


@njit(cache=True)
def _clear_line_of_sight(clear, r0, c0, r1, c1) -> bool:
    """``_line_of_sight`` on a clearance grid, with the same answer, leaping over open ground.

    Where the current cell has clearance k >= 3, the next k - 2 crossings of the major axis
    (and so at most k - 1 of the minor one) stay within the free square around it; the walk
    jumps there and recomputes the exact crossing counts in integers, then carries on.
    """
    if clear[r0, c0] == 0 or clear[r1, c1] == 0:
        return False
    n_rows = abs(r1 - r0)
    n_cols = abs(c1 - c0)
    step_r = 1 if r1 > r0 else -1
    step_c = 1 if c1 > c0 else -1
    r = r0
    c = c0
    ir = 0
    ic = 0
    while ir < n_rows or ic < n_cols:
        leap = np.int64(clear[r, c]) - 2
        if leap >= 1 and (ic < n_cols if n_cols >= n_rows else ir < n_rows):
            if n_cols >= n_rows:
                ic = min(ic + leap, n_cols)
                # row crossings at or before the ic-th column crossing (a corner counts as both)
                ir = ((2 * ic - 1) * n_rows + n_cols) // (2 * n_cols)
            else:
                ir = min(ir + leap, n_rows)
                ic = ((2 * ir - 1) * n_cols + n_rows) // (2 * n_rows)
            r = r0 + step_r * ir
            c = c0 + step_c * ic
            continue
        decision = (2 * ic + 1) * n_rows - (2 * ir + 1) * n_cols
        if decision == 0:
            if clear[r, c + step_c] == 0 or clear[r + step_r, c] == 0:
                return False
            r += step_r
            c += step_c
            ir += 1
            ic += 1
        elif decision < 0:
            c += step_c
            ic += 1
        else:
            r += step_r
            ir += 1
        if clear[r, c] == 0:
            return False
    return True


# An indexed binary min-heap over flat cell indices: `pos[cell]` is the cell's slot, so an
# improved cost is a decrease-key instead of a duplicate entry, and the heap never holds more
# than one entry per cell. Its arrays are allocated for every cell with np.empty, which only
# reserves address space: pages are touched as the heap grows (growing arrays inside the
# compiled loop instead made every iteration pay reference counting, ~40 % slower). Ties on f
# prefer larger g (deeper nodes), which cuts expansions on open ground.


@njit(cache=True, inline="always")
def _before(f_a, g_a, f_b, g_b) -> bool:
    return f_a < f_b or (f_a == f_b and g_a > g_b)


@njit(cache=True, inline="always")
def _sift_up(nodes, keys, ties, pos, i):
    node = nodes[i]
    key = keys[i]
    tie = ties[i]
    while i > 0:
        parent = (i - 1) >> 1
        if not _before(key, tie, keys[parent], ties[parent]):
            break
        nodes[i] = nodes[parent]
        keys[i] = keys[parent]
        ties[i] = ties[parent]
        pos[nodes[i]] = i
        i = parent
    nodes[i] = node
    keys[i] = key
    ties[i] = tie
    pos[node] = i


@njit(cache=True, inline="always")
def _sift_down(nodes, keys, ties, pos, i, size):
    node = nodes[i]
    key = keys[i]
    tie = ties[i]
    while True:
        child = 2 * i + 1
        if child >= size:
            break
        right = child + 1
        if right < size and _before(keys[right], ties[right], keys[child], ties[child]):
            child = right
        if not _before(keys[child], ties[child], key, tie):
            break
        nodes[i] = nodes[child]
        keys[i] = keys[child]
        ties[i] = ties[child]
        pos[nodes[i]] = i
        i = child
    nodes[i] = node
    keys[i] = key
    ties[i] = tie
    pos[node] = i


@njit(cache=True, inline="always")
def _pop(nodes, keys, ties, pos, size):
    """Remove the heap's first entry; returns (cell, new size)."""
    top = np.int64(nodes[0])
    size -= 1
    if size > 0:
        nodes[0] = nodes[size]
        keys[0] = keys[size]
        ties[0] = ties[size]
        _sift_down(nodes, keys, ties, pos, 0, size)
    return top, size


@njit(cache=True)
def _trace_back(parent, start, goal, width):
    """(K, 2) cells from start to goal by following parent links from the goal."""
    count = 1
    node = goal
    while node != start:
        node = parent[node]
        count += 1
    cells = np.empty((count, 2), np.int64)
    node = goal
    for k in range(count - 1, -1, -1):
        cells[k, 0] = node // width
        cells[k, 1] = node % width
        node = parent[node]
    return cells


@njit(cache=True, inline="always")
def _octile(r0, c0, r1, c1) -> float:
    dr = abs(r1 - r0)
    dc = abs(c1 - c0)
    return (max(dr, dc) - min(dr, dc)) + SQRT2 * min(dr, dc)


@njit(cache=True, inline="always")
def _euclid(r0, c0, r1, c1) -> float:
    return math.sqrt(float((r1 - r0) * (r1 - r0) + (c1 - c0) * (c1 - c0)))


# Cell states: 0 never seen (g, parent and pos are then garbage), 1 open, 2 closed. Only the
# state array is zero-filled, so a short search on a huge grid does not pay for touching g.
# Cell indices are int32 (flat r * W + c): half the memory traffic of int64.
_UNSEEN, _OPEN, _CLOSED = 0, 1, 2


@njit(cache=True)
def _open_search(n_cells, start, start_key):
    """The arrays of one best-first search over n_cells, with ``start`` open at ``start_key``:
    state, g, parent, heap position, and the heap itself (nodes, keys, tie-breakers)."""
    state = np.zeros(n_cells, np.uint8)
    g = np.empty(n_cells, np.float64)
    parent = np.empty(n_cells, np.int32)
    pos = np.empty(n_cells, np.int32)
    nodes = np.empty(n_cells, np.int32)
    keys = np.empty(n_cells, np.float64)
    ties = np.empty(n_cells, np.float64)
    g[start] = 0.0
    parent[start] = start
    state[start] = _OPEN
    nodes[0] = start
    keys[0] = start_key
    ties[0] = 0.0
    pos[start] = 0
    return state, g, parent, pos, nodes, keys, ties


@njit(cache=True)
def _astar_kernel(free, start_r, start_c, goal_r, goal_c):
    height, width = free.shape
    start = start_r * width + start_c
    goal = goal_r * width + goal_c
    state, g, parent, pos, nodes, keys, ties = _open_search(height * width, start, _octile(start_r, start_c, goal_r, goal_c))
    size = 1

    while size > 0:
        current, size = _pop(nodes, keys, ties, pos, size)
        state[current] = _CLOSED
        if current == goal:
            return _trace_back(parent, start, goal, width)
        r = current // width
        c = current - r * width
        moves = _allowed_moves(free, r, c)
        for k in range(9):
            if not (moves >> k) & 1:
                continue
            dr = k // 3 - 1
            dc = k % 3 - 1
            neighbour = current + dr * width + dc
            if state[neighbour] == _CLOSED:
                continue
            g_new = g[current] + (SQRT2 if dr != 0 and dc != 0 else 1.0)
            if state[neighbour] == _UNSEEN:
                slot = size
                size += 1
                nodes[slot] = neighbour
                state[neighbour] = _OPEN
            elif g_new < g[neighbour]:
                slot = pos[neighbour]
            else:
                continue
            g[neighbour] = g_new
            parent[neighbour] = current
            keys[slot] = g_new + _octile(r + dr, c + dc, goal_r, goal_c)
            ties[slot] = g_new
            _sift_up(nodes, keys, ties, pos, slot)
    return np.empty((0, 2), np.int64)


@njit(cache=True)
def _lazy_theta_kernel(clear, start_r, start_c, goal_r, goal_c):
    """Lazy Theta* (Nash, Koenig, Tovey 2010, Fig. 2) with the Euclidean heuristic.

    A generated neighbour optimistically takes its expander's parent as its own ("path 2")
    without a line-of-sight check; the check happens once, when the neighbour is expanded
    (SetVertex). If it fails, the cell falls back to its best closed 8-neighbour ("path 1").
    """
    height, width = clear.shape
    start = start_r * width + start_c
    goal = goal_r * width + goal_c
    state, g, parent, pos, nodes, keys, ties = _open_search(height * width, start, _euclid(start_r, start_c, goal_r, goal_c))
    size = 1

    while size > 0:
        current, size = _pop(nodes, keys, ties, pos, size)
        r = current // width
        c = current - r * width
        moves = _allowed_moves(clear, r, c)

        # SetVertex: verify the optimistic parent now that the cell is expanded.
        p = np.int64(parent[current])
        if p != current and not _clear_line_of_sight(clear, p // width, p % width, r, c):
            best_g = np.inf
            best_parent = current
            for k in range(9):
                if not (moves >> k) & 1:
                    continue
                dr = k // 3 - 1
                dc = k % 3 - 1
                neighbour = current + dr * width + dc
                if state[neighbour] != _CLOSED:
                    continue
                g_via = g[neighbour] + (SQRT2 if dr != 0 and dc != 0 else 1.0)
                if g_via < best_g:
                    best_g = g_via
                    best_parent = neighbour
            g[current] = best_g
            parent[current] = best_parent
        state[current] = _CLOSED
        if current == goal:
            return _trace_back(parent, start, goal, width)

        p = np.int64(parent[current])
        p_r = p // width
        p_c = p - p_r * width
        g_p = g[p]
        for k in range(9):
            if not (moves >> k) & 1:
                continue
            nr = r + k // 3 - 1
            nc = c + k % 3 - 1
            neighbour = nr * width + nc
            if state[neighbour] == _CLOSED:
                continue
            g_new = g_p + _euclid(p_r, p_c, nr, nc)
            if state[neighbour] == _UNSEEN:
                slot = size
                size += 1
                nodes[slot] = neighbour
                state[neighbour] = _OPEN
            elif g_new < g[neighbour]:
                slot = pos[neighbour]
            else:
                continue
            g[neighbour] = g_new
            parent[neighbour] = p
            keys[slot] = g_new + _euclid(nr, nc, goal_r, goal_c)
            ties[slot] = g_new
            _sift_up(nodes, keys, ties, pos, slot)
    return np.empty((0, 2), np.int64)


@njit(cache=True)
def _field_kernel(free, goal_r, goal_c):
    """Dijkstra from the goal over the 8-connected moves (no corner cutting): (H, W) uint16 the
    path length from each cell to the goal in steps of 1 / ``per_cell`` cell (``FIELD_UNREACHED``
    where no way leads), and ``per_cell``: ``FIELD_PER_CELL``, fewer where the longest path would
    not fit in 16 bits. Its relaxation is ``_astar_kernel``'s without the heuristic, written out:
    one compiled helper for both made both 30-60 % slower (``benchmarks/bench_metric_search.py``)."""
    height, width = free.shape
    goal = goal_r * width + goal_c
    state, g, parent, pos, nodes, keys, ties = _open_search(height * width, goal, 0.0)
    size = 1
    longest = 0.0
    while size > 0:
        current, size = _pop(nodes, keys, ties, pos, size)
        state[current] = _CLOSED
        longest = g[current]  # popped in order of length: the last is the longest
        r = current // width
        c = current - r * width
        moves = _allowed_moves(free, r, c)
        for k in range(9):
            if not (moves >> k) & 1:
                continue
            dr = k // 3 - 1
            dc = k % 3 - 1
            neighbour = current + dr * width + dc
            if state[neighbour] == _CLOSED:
                continue
            g_new = g[current] + (SQRT2 if dr != 0 and dc != 0 else 1.0)
            if state[neighbour] == _UNSEEN:
                slot = size
                size += 1
                nodes[slot] = neighbour
                state[neighbour] = _OPEN
            elif g_new < g[neighbour]:
                slot = pos[neighbour]
            else:
                continue
            g[neighbour] = g_new
            keys[slot] = g_new
            ties[slot] = g_new
            _sift_up(nodes, keys, ties, pos, slot)
    per_cell = min(FIELD_PER_CELL, (FIELD_UNREACHED - 1) / max(longest, 1.0))
    field = np.full(height * width, FIELD_UNREACHED, np.uint16)
    for cell in range(height * width):
        if state[cell] == _CLOSED:
            field[cell] = np.uint16(round(g[cell] * per_cell))
    return field.reshape(height, width), per_cell


@njit(cache=True)
def _descend_kernel(free, tile_of, tiles, per_cell, start_r, start_c):
    """(K, 2) cells from the start down ``field`` (``_field_kernel``'s) to its goal (each step to
    the 8-neighbour that the Dijkstra reached it from: the least field value plus the step; with
    lengths rounded to 1 / ``per_cell`` cell, one within that of it), or (0, 2) if no way. Every
    step goes to a lower value, so the walk ends. The field comes as a ``TiledRaster``'s ``tile_of`` and
    ``tiles``."""
    out = np.empty((256, 2), np.int64)
    count = 0
    r, c = start_r, start_c
    if _tile_at(tile_of, tiles, r, c) == FIELD_UNREACHED:
        return out[:0]
    straight = per_cell
    diagonal = per_cell * SQRT2
    while True:
        if count == out.shape[0]:
            grown = np.empty((2 * count, 2), np.int64)
            grown[:count] = out
            out = grown
        out[count, 0] = r
        out[count, 1] = c
        count += 1
        here = _tile_at(tile_of, tiles, r, c)
        if here == 0:
            return out[:count]
        moves = _allowed_moves(free, r, c)
        best = np.inf
        best_r, best_c = -1, -1
        for k in range(9):
            if not (moves >> k) & 1:
                continue
            nr = r + k // 3 - 1
            nc = c + k % 3 - 1
            there = _tile_at(tile_of, tiles, nr, nc)
            if not there < here:
                continue
            value = float(there) + (diagonal if nr != r and nc != c else straight)
            if value < best:
                best, best_r, best_c = value, nr, nc
        if best_r < 0:  # a dead end (new obstacles round it): no way rather than a loop
            return out[:0]
        r, c = best_r, best_c


@njit(cache=True, inline="always")
def _tile_at(tile_of, tiles, r, c):
    """The value of cell (r, c) of a ``TiledRaster`` given as its index and tiles."""
    return tiles[tile_of[r >> TILE_SHIFT, c >> TILE_SHIFT], r & (TILE - 1), c & (TILE - 1)]


@njit(cache=True)
def _shortcut(clear, cells):
    """Greedy string pulling: from each kept vertex jump to the farthest one still in sight."""
    count = cells.shape[0]
    keep = np.empty(count, np.int64)
    keep[0] = 0
    kept = 1
    i = 0
    while i < count - 1:
        j = count - 1
        while j > i + 1 and not _clear_line_of_sight(clear, cells[i, 0], cells[i, 1], cells[j, 0], cells[j, 1]):
            j -= 1
        keep[kept] = j
        kept += 1
        i = j
    out = np.empty((kept, 2), np.int64)
    for k in range(kept):
        out[k, 0] = cells[keep[k], 0]
        out[k, 1] = cells[keep[k], 1]
    return out


@njit(cache=True)
def _refine(clear, cells, sweeps):
    """Slide each interior vertex to the neighbouring cell that shortens the path most.

    Theta* vertices sit on cell centres next to obstacles; around a curved (inflated) corner the
    best bend point is often a cell or two away. Each move keeps line of sight to both path
    neighbours, so the path stays in free space; sweeps stop when nothing improves. Line of sight
    is walked from the moved vertex out (the same answer either way): a move that cuts into the
    corner it bends round fails within a few cells, not at the end of a long segment.
    """
    cells = cells.copy()
    count = cells.shape[0]
    for _ in range(sweeps):
        improved = False
        for k in range(1, count - 1):
            ar, ac = cells[k - 1, 0], cells[k - 1, 1]
            br, bc = cells[k + 1, 0], cells[k + 1, 1]
            best_r, best_c = cells[k, 0], cells[k, 1]
            best = _euclid(ar, ac, best_r, best_c) + _euclid(best_r, best_c, br, bc)
            r0, c0 = best_r, best_c
            for dr in range(-1, 2):
                for dc in range(-1, 2):
                    r = r0 + dr
                    c = c0 + dc
                    if (dr == 0 and dc == 0) or not _inside(clear.shape[0], clear.shape[1], r, c):
                        continue
                    length = _euclid(ar, ac, r, c) + _euclid(r, c, br, bc)
                    if length < best - 1e-9 and clear[r, c] > 0:
                        if _clear_line_of_sight(clear, r, c, ar, ac) and _clear_line_of_sight(clear, r, c, br, bc):
                            best = length
                            best_r, best_c = r, c
            if best_r != r0 or best_c != c0:
                cells[k, 0] = best_r
                cells[k, 1] = best_c
                improved = True
        if not improved:
            break
    return cells


@njit(cache=True)
def _open_line(through, row, col, r, c):
    """Do the cells on the straight line from (row, col) to (r, c) (sampled every half cell, the
    ends' own cells not counted) all lie on ``through`` (off the grid: yes)?"""
    height, width = through.shape
    steps = 2 * max(abs(r - row), abs(c - col))
    for k in range(1, steps):
        rr = int(np.floor(row + 0.5 + (r - row) * k / steps))
        cc = int(np.floor(col + 0.5 + (c - col) * k / steps))
        if (rr != row or cc != col) and (rr != r or cc != c) and 0 <= rr < height and 0 <= cc < width and not through[rr, cc]:
            return False
    return True


@njit(cache=True)
def _nearest_free_kernel(free, row, col, max_radius, through, check):
    """Nearest free cell by Euclidean distance, searching square rings of growing size; with
    ``check``, only cells the straight line from (row, col) reaches over ``through`` cells."""
    height, width = free.shape
    best_d2 = max_radius * max_radius + 1
    best_r = -1
    best_c = -1
    # rings beyond the farthest grid corner hold no cell
    farthest = max(abs(row), abs(row - height + 1), abs(col), abs(col - width + 1))
    for ring in range(min(max_radius, farthest) + 1):
        if ring * ring >= best_d2:  # every cell of this ring is at least `ring` away
            break
        for dr in range(-ring, ring + 1):
            edge_row = dr == -ring or dr == ring
            step = 1 if edge_row else 2 * ring
            dc = -ring
            while dc <= ring:
                r = row + dr
                c = col + dc
                if 0 <= r < height and 0 <= c < width and free[r, c]:
                    d2 = dr * dr + dc * dc
                    if d2 < best_d2 and (not check or _open_line(through, row, col, r, c)):
                        best_d2 = d2
                        best_r = r
                        best_c = c
                dc += step
    return best_r, best_c


# --------------------------------------------------------------------------------------------
# Public planners
# --------------------------------------------------------------------------------------------


def _as_grid(free: ArrayLike) -> NDArray[np.bool_]:
    grid = np.ascontiguousarray(free, dtype=np.bool_)
    if grid.ndim != 2:
        raise ValueError(f"free must be a 2-D bool array, got shape {grid.shape}")
    if grid.size >= 2**31:
        raise ValueError(f"grid of {grid.size} cells is too large (cell indices are int32)")
    return grid


def _cell(cell: ArrayLike) -> Cell:
    row, col = np.asarray(cell).reshape(2)
    return int(row), int(col)


def _is_free(grid: NDArray[np.bool_], cell: Cell) -> bool:
    r, c = cell
    return 0 <= r < grid.shape[0] and 0 <= c < grid.shape[1] and bool(grid[r, c])


def line_of_sight(free: ArrayLike, a: ArrayLike, b: ArrayLike) -> bool:
    """Does the segment between the centres of cells a and b cross only free cells?

    free: (H, W) bool; a, b: (row, col). Conservative supercover: every cell the segment
    touches counts, including both side cells where it passes exactly through a grid corner.
    False if either end is outside the grid or blocked.
    """
    grid, a, b = _as_grid(free), _cell(a), _cell(b)
    if not (_is_free(grid, a) and _is_free(grid, b)):
        return False
    return bool(_line_of_sight(grid, a[0], a[1], b[0], b[1]))


def astar(free: ArrayLike, start: ArrayLike, goal: ArrayLike) -> CellPath | None:
    """8-connected A* with the octile heuristic and no corner cutting.

    free: (H, W) bool; start, goal: (row, col). Returns the (K, 2) int64 cells of a shortest
    8-connected path, start and goal included (every step is to an 8-neighbour), or None.
    """
    grid, start, goal = _as_grid(free), _cell(start), _cell(goal)
    if not (_is_free(grid, start) and _is_free(grid, goal)):
        return None
    cells = _astar_kernel(grid, start[0], start[1], goal[0], goal[1])
    return cells if cells.shape[0] > 0 else None


def sight_raster(free: ArrayLike) -> NDArray[np.uint8]:
    """(H, W) uint8 the Chebyshev clearance (cells) of ``free`` that ``theta_star``'s line of sight
    leaps on: a caller that searches one mask often makes it once and passes it."""
    return np.asarray(_chebyshev_clearance(_as_grid(free)), dtype=np.uint8)


def theta_star(free: ArrayLike, start: ArrayLike, goal: ArrayLike, sight: NDArray[np.uint8] | None = None) -> CellPath | None:
    """Any-angle path: Lazy Theta*, then shortcut and vertex refinement (all compiled).

    free: (H, W) bool; start, goal: (row, col); sight: ``sight_raster(free)`` if the caller keeps it
    (else made here, a pass over the whole mask). Returns the (K, 2) int64 vertices of a polyline
    from start to goal whose every segment has ``line_of_sight``, or None. Its length is within 1 %
    of the continuous shortest path through the free cells.
    """
    grid, start, goal = _as_grid(free), _cell(start), _cell(goal)
    if not (_is_free(grid, start) and _is_free(grid, goal)):
        return None
    clear = _chebyshev_clearance(grid) if sight is None else sight
    cells = _lazy_theta_kernel(clear, start[0], start[1], goal[0], goal[1])
    if cells.shape[0] == 0:
        return None
    if cells.shape[0] > 2:
        cells = _shortcut(clear, cells)
        cells = _shortcut(clear, _refine(clear, cells, 20))
    return cells


class GoalField(NamedTuple):
    """The length of the shortest 8-connected path (no corner cutting) from each cell of a mask to
    one goal cell: ``steps`` (H, W) uint16 in units of 1 / ``per_cell`` cell, ``FIELD_UNREACHED``
    where no way leads; kept while the goal lasts, so as the tiles a way leads into
    (``navkit.raster.TiledRaster``: 2 bytes a cell of those, the unreached rest one shared tile)."""

    steps: TiledRaster
    per_cell: float

    def cells(self) -> NDArray[np.float64]:
        """(H, W) the lengths in cells (inf where no way leads)."""
        steps = self.steps.dense()
        return np.where(steps == FIELD_UNREACHED, np.inf, steps / self.per_cell)

    @property
    def nbytes(self) -> int:
        return int(self.steps.nbytes)


def goal_field(free: ArrayLike, goal: ArrayLike) -> GoalField:
    """The ``GoalField`` of ``free`` rooted at ``goal`` (row, col). Made once per goal, it gives
    every later path to that goal by ``field_path``, from any start, without a search."""
    grid, goal = _as_grid(free), _cell(goal)
    if not _is_free(grid, goal):
        return GoalField(TiledRaster.of(np.full(grid.shape, FIELD_UNREACHED, np.uint16), FIELD_UNREACHED), FIELD_PER_CELL)
    steps, per_cell = _field_kernel(grid, goal[0], goal[1])
    return GoalField(TiledRaster.of(np.asarray(steps), FIELD_UNREACHED), float(per_cell))


def field_path(free: ArrayLike, field: GoalField, start: ArrayLike, sight: NDArray[np.uint8] | None = None) -> CellPath | None:
    """The path from ``start`` (row, col) to the goal of ``field``, descending it through the cells
    of ``free`` (a shortest 8-connected path where ``field`` is ``goal_field(free)``, to within
    its rounding; where ``free`` has lost cells since, e.g. to new obstacles, a way down the field
    round them, or None if it meets a dead end), then the shortcut and vertex refinement that
    ``theta_star`` ends with, on ``sight`` (``sight_raster(free)``; None: cell by cell on
    ``free``). None if no way leads."""
    grid, start = _as_grid(free), _cell(start)
    if not _is_free(grid, start):
        return None
    cells = _descend_kernel(grid, field.steps.tile_of, field.steps.tiles, field.per_cell, start[0], start[1])
    if cells.shape[0] == 0:
        return None
    return _pulled(grid.view(np.uint8) if sight is None else sight, cells)


def _pulled(sight: NDArray[np.uint8], cells: NDArray[np.int64]) -> NDArray[np.int64]:
    """A cell path shortened: string pulling from its start and from its goal, each refined, the
    shorter kept (greedy pulling from one end misses a bend the other end finds)."""
    if cells.shape[0] <= 2:
        return cells
    forward = _shortcut(sight, _refine(sight, _shortcut(sight, cells), 20))
    backward = _shortcut(sight, _refine(sight, _shortcut(sight, cells[::-1].copy()), 20))[::-1]
    return forward if path_length(forward, 1.0) <= path_length(backward, 1.0) else np.ascontiguousarray(backward)


def astar_smoothed(free: ArrayLike, start: ArrayLike, goal: ArrayLike, sight: NDArray[np.uint8] | None = None) -> CellPath | None:
    """``astar``'s 8-connected shortest path, then ``theta_star``'s shortcut and refinement: an
    any-angle path (``line_of_sight`` on every segment) found with cheaper expansions than
    Lazy Theta*'s, 0.1-0.3 % longer on the baseline's maps (BENCHMARKS.md, "Design choices: the search
    algorithm"). ``sight``: the grid's ``sight_raster`` if the caller keeps one; None: the pulling
    walks its lines cell by cell on the grid itself (the same answers; a clearance transform of
    the whole grid for one path cost more than the walks: 0.26 against 0.09 ms a search, median,
    on NavTopo's union grids)."""
    grid, start, goal = _as_grid(free), _cell(start), _cell(goal)
    if not (_is_free(grid, start) and _is_free(grid, goal)):
        return None
    cells = _astar_kernel(grid, start[0], start[1], goal[0], goal[1])
    if cells.shape[0] == 0:
        return None
    return _pulled(grid.view(np.uint8) if sight is None else sight, cells)


def jps_smoothed(free: ArrayLike, start: ArrayLike, goal: ArrayLike, sight: NDArray[np.uint8] | None = None) -> CellPath | None:
    """``astar_smoothed`` with jump point search in place of A* (``_jps_kernel``: a shortest
    8-connected path as A*'s, found putting only the jump points on the open list): the same
    length before the pulling, fewer expansions on open ground."""
    grid, start, goal = _as_grid(free), _cell(start), _cell(goal)
    if not (_is_free(grid, start) and _is_free(grid, goal)):
        return None
    cells = _jps_kernel(grid, start[0], start[1], goal[0], goal[1])
    if cells.shape[0] == 0:
        return None
    return _pulled(grid.view(np.uint8) if sight is None else sight, cells)


def nearest_free(free: ArrayLike, cell: ArrayLike, max_radius_cells: int, through: ArrayLike | None = None) -> Cell | None:
    """The free cell nearest (Euclidean) to ``cell`` within ``max_radius_cells``, or None.

    free: (H, W) bool; cell: (row, col), may lie outside the grid. Returns ``cell`` itself when
    it is free. Use it to move a start or goal that falls inside the inflated zone.
    through: (H, W) bool, optional: only a cell the straight line from ``cell`` reaches over these
    cells counts (e.g. no wall cell on the way: a robot snapped a metre through a wall drove into it).
    """
    grid, (row, col) = _as_grid(free), _cell(cell)
    lines = np.ones((1, 1), np.bool_) if through is None else _as_grid(through)
    r, c = _nearest_free_kernel(grid, row, col, max(int(max_radius_cells), 0), lines, through is not None)
    if r < 0:
        return None
    return int(r), int(c)


# Jump point search for the no-corner-cutting rule (appended to grid_search.py)


@njit(cache=True, inline="always")
def _free_at(free, r, c) -> bool:
    return 0 <= r < free.shape[0] and 0 <= c < free.shape[1] and free[r, c] != 0


@njit(cache=True)
def _jump_straight(free, r, c, dr, dc, goal_r, goal_c):
    """From (r, c) along a row or a column: the first cell that is the goal or has a forced
    neighbour (a side cell free whose cell behind it is not: only a path through here reaches it
    best), or -1 at a wall."""
    width = free.shape[1]
    while True:
        r += dr
        c += dc
        if not _free_at(free, r, c):
            return -1
        if r == goal_r and c == goal_c:
            return r * width + c
        if dr == 0:
            if (_free_at(free, r - 1, c) and not _free_at(free, r - 1, c - dc)) or (
                _free_at(free, r + 1, c) and not _free_at(free, r + 1, c - dc)
            ):
                return r * width + c
        elif (_free_at(free, r, c - 1) and not _free_at(free, r - dr, c - 1)) or (
            _free_at(free, r, c + 1) and not _free_at(free, r - dr, c + 1)
        ):
            return r * width + c


@njit(cache=True)
def _jump(free, r, c, dr, dc, goal_r, goal_c):
    """The jump point reached from (r, c) by the move (dr, dc) (allowed: ``_allowed_moves``), or -1.
    A diagonal run stops where a straight run from it finds one; every diagonal step keeps the
    no-corner-cutting rule."""
    width = free.shape[1]
    if dr == 0 or dc == 0:
        return _jump_straight(free, r, c, dr, dc, goal_r, goal_c)
    while True:
        r += dr
        c += dc
        if r == goal_r and c == goal_c:
            return r * width + c
        if _jump_straight(free, r, c, dr, 0, goal_r, goal_c) >= 0 or _jump_straight(free, r, c, 0, dc, goal_r, goal_c) >= 0:
            return r * width + c
        if not (_free_at(free, r + dr, c) and _free_at(free, r, c + dc) and _free_at(free, r + dr, c + dc)):
            return -1


@njit(cache=True)
def _jps_kernel(free, start_r, start_c, goal_r, goal_c):
    """Jump point search (D. Harabor, A. Grastien, "Online Graph Pruning for Pathfinding on Grid
    Maps", AAAI 2011) for moves that never cut a corner: A*'s shortest 8-connected path with only
    the jump points put on the open list. Returns the path's cells, every step to an 8-neighbour."""
    height, width = free.shape
    start = start_r * width + start_c
    goal = goal_r * width + goal_c
    state, g, parent, pos, nodes, keys, ties = _open_search(height * width, start, _octile(start_r, start_c, goal_r, goal_c))
    size = 1
    while size > 0:
        current, size = _pop(nodes, keys, ties, pos, size)
        state[current] = _CLOSED
        if current == goal:
            return _trace_jumps(parent, start, goal, width)
        r = current // width
        c = current - r * width
        moves = _allowed_moves(free, r, c)
        if current != start:  # prune to the moves on from the parent's direction
            p = parent[current]
            pr = p // width
            dr = (r > pr) - (r < pr)
            dc = (c > p - pr * width) - (c < p - pr * width)
            keep = 0
            if dr != 0 and dc != 0:
                keep = (1 << (3 * (dr + 1) + 1)) | (1 << (3 + dc + 1)) | (1 << (3 * (dr + 1) + dc + 1))
            elif dr == 0:  # along a row: on, and both sides with their diagonals on
                keep = (1 << (3 + dc + 1)) | (1 << 1) | (1 << 7) | (1 << (dc + 1)) | (1 << (6 + dc + 1))
            else:
                keep = (1 << (3 * (dr + 1) + 1)) | (1 << 3) | (1 << 5) | (1 << (3 * (dr + 1))) | (1 << (3 * (dr + 1) + 2))
            moves &= keep
        for k in range(9):
            if not (moves >> k) & 1:
                continue
            jumped = _jump(free, r, c, k // 3 - 1, k % 3 - 1, goal_r, goal_c)
            if jumped < 0 or state[jumped] == _CLOSED:
                continue
            jr = jumped // width
            jc = jumped - jr * width
            g_new = g[current] + _octile(r, c, jr, jc)
            size = _relax(state, g, parent, pos, nodes, keys, ties, size, jumped, current, g_new, _octile(jr, jc, goal_r, goal_c))
    return np.empty((0, 2), np.int64)


@njit(cache=True, inline="always")
def _relax(state, g, parent, pos, nodes, keys, ties, size, node, via, g_new, heuristic):
    """Open ``node`` at cost ``g_new`` through ``via``, or lower its cost if that is less; returns
    the heap's new size. (``_astar_kernel`` and ``_field_kernel`` write this out: a helper there
    measured slower, where the relaxation is most of the work.)"""
    if state[node] == _UNSEEN:
        slot = size
        size += 1
        nodes[slot] = node
        state[node] = _OPEN
    elif g_new < g[node]:
        slot = pos[node]
    else:
        return size
    g[node] = g_new
    parent[node] = via
    keys[slot] = g_new + heuristic
    ties[slot] = g_new
    _sift_up(nodes, keys, ties, pos, slot)
    return size


@njit(cache=True)
def _trace_jumps(parent, start, goal, width):
    """(K, 2) cells from start to goal: the jump points joined cell by cell (each leg is straight
    or diagonal, then straight: ``_jump``'s runs)."""
    count = 1
    node = goal
    while node != start:  # cells per leg: its Chebyshev length
        prev = parent[node]
        count += max(abs(node // width - prev // width), abs(node % width - prev % width))
        node = prev
    cells = np.empty((count, 2), np.int64)
    k = count - 1
    node = goal
    cells[k, 0] = node // width
    cells[k, 1] = node % width
    while node != start:
        prev = parent[node]
        r, c = node // width, node % width
        pr, pc = prev // width, prev % width
        while r != pr or c != pc:  # back towards prev: diagonally while both differ, then straight
            r -= (r > pr) - (r < pr)
            c -= (c > pc) - (c < pc)
            k -= 1
            cells[k, 0] = r
            cells[k, 1] = c
        node = prev
    return cells


# the any-angle searches by name (each ``(free, start, goal, sight) -> cells or None``), for the
# planners' ``search`` settings: chosen by measurement (BENCHMARKS.md, "Design choices: the search algorithm")
SEARCHES: dict[str, Callable[..., CellPath | None]] = {"astar": astar_smoothed, "jps": jps_smoothed, "theta_star": theta_star}
