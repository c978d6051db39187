"""What every system takes from a 3D lidar cloud for 2D maps: the obstacle band and ray tracing.

* ``obstacle_points``: the returns between ``floor_height`` and ``ceiling_height`` (metres above the
  floor under the robot) are obstacles; lower ones are floor, higher ones ceiling. The defaults suit
  the benchmark robot (lidar at 0.6 m, 16 channels over [-15°, 15°]): 0.15 m is above floor returns
  and below anything the robot cannot drive over (a 0.3 m box is an obstacle); 1.8 m (mount height
  + 1.2 m) is above any robot body and below ceilings (2.4 m and up in buildings), so door frames,
  shelves and tables are obstacles while a ceiling is not. NavTopo's location grids and the metric
  baseline's grid use the same band.
* ``azimuth_bins``: the azimuth bin of each return (the metric baseline's free ranges per bin,
  NavTopo's start-up beams).
* ``trace_ray`` / ``trace_scan``: free space along every return's ray into a uint8 grid of
  ``UNKNOWN`` / ``FREE`` / ``OCCUPIED`` cells (``navkit.raster``), compiled; coordinates are
  continuous cell coordinates (cell c covers [c, c + 1)).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numba import njit
from numpy.typing import ArrayLike, NDArray

FLOOR_HEIGHT = 0.15  # m above the floor: lower returns are floor
CEILING_HEIGHT = 1.8  # m above the floor: higher returns are ceiling
MAX_GAP_DEG = 2.5  # degrees: free space is filled between returns at most this far apart in azimuth


class HeightBand(Protocol):
    """Anything with the obstacle band's two heights (a location grid's config, a baseline's scan config)."""

    @property
    def floor_height(self) -> float: ...

    @property
    def ceiling_height(self) -> float: ...


@dataclass(frozen=True)
class ObstacleBand:
    floor_height: float = FLOOR_HEIGHT
    ceiling_height: float = CEILING_HEIGHT


def azimuth_bins(xy: ArrayLike, bins: int) -> NDArray[np.int64]:
    """(N, >=2) points in the robot frame -> (N,) index of the azimuth bin each lies in: ``bins``
    bins of 2π / bins, bin b centred on azimuth b * 2π / bins (whole degrees at 360 bins, as the
    simulated lidar's columns are, so one column falls in one bin)."""
    p = np.asarray(xy, dtype=np.float64)
    return np.round(np.arctan2(p[:, 1], p[:, 0]) / (2.0 * np.pi / bins)).astype(np.int64) % bins


def obstacle_points(points: ArrayLike, band: HeightBand | None = None) -> NDArray:
    """The returns that are obstacles: ``floor_height <= z <= ceiling_height``.

    points: (N, 3) in the robot frame, z up from the floor. Returns (M, 3), same dtype.
    """
    band = band or ObstacleBand()
    p = np.asarray(points)
    z = p[:, 2]
    return p[(z >= band.floor_height) & (z <= band.ceiling_height)]


@njit(cache=True, nogil=True)
def trace_ray(grid, origin, end_u, end_v):  # pragma: no cover - compiled
    """Mark cells FREE along the segment origin -> end, in continuous cell coordinates (cell c
    covers [c, c + 1); the origin is ``(origin, origin)``), stopping at the first OCCUPIED cell or
    the grid's edge. Returns how far the free part reaches, in cells.

    Grid traversal of Amanatides & Woo (1987): every cell the segment crosses is visited once.
    """
    n_rows, n_cols = grid.shape
    du = end_u - origin
    dv = end_v - origin
    length = np.sqrt(du * du + dv * dv)
    if length < 1e-9:
        return 0.0
    # start a hair inside the segment: the origin lies on a cell corner
    u = origin + du * 1e-9
    v = origin + dv * 1e-9
    cu = int(np.floor(u))
    cv = int(np.floor(v))
    eu = int(np.floor(end_u))
    ev = int(np.floor(end_v))
    if du > 0:
        step_u, t_max_u, t_delta_u = 1, (cu + 1 - u) / du, 1.0 / du
    elif du < 0:
        step_u, t_max_u, t_delta_u = -1, (u - cu) / -du, -1.0 / du
    else:
        step_u, t_max_u, t_delta_u = 0, np.inf, np.inf
    if dv > 0:
        step_v, t_max_v, t_delta_v = 1, (cv + 1 - v) / dv, 1.0 / dv
    elif dv < 0:
        step_v, t_max_v, t_delta_v = -1, (v - cv) / -dv, -1.0 / dv
    else:
        step_v, t_max_v, t_delta_v = 0, np.inf, np.inf
    t_entry = 0.0  # where the segment enters the current cell, as a fraction of its length
    for _ in range(abs(eu - cu) + abs(ev - cv) + 1):
        if cu < 0 or cv < 0 or cu >= n_cols or cv >= n_rows or grid[cv, cu] == 2:  # OCCUPIED
            return t_entry * length
        grid[cv, cu] = 1  # FREE
        if cu == eu and cv == ev:
            break
        if t_max_u < t_max_v:
            t_entry = t_max_u
            cu += step_u
            t_max_u += t_delta_u
        else:
            t_entry = t_max_v
            cv += step_v
            t_max_v += t_delta_v
    return length


@njit(cache=True, nogil=True)
def trace_scan(grid, ends_u, ends_v, origin, max_gap, similar_ratio):  # pragma: no cover
    """Trace every return, then fill between angularly adjacent directions.

    A lidar's rays fan out: at 1° steps they are 0.17 m apart at 10 m, and 0.1 m cells between
    them would stay unknown. Between two neighbouring directions at most ``max_gap`` radians apart,
    extra rays are traced every half cell at the far end, reaching the interpolated range (or the
    shorter of the two when they differ by more than ``similar_ratio``: a depth edge). Wider gaps
    are directions without returns and stay unknown.
    """
    n = ends_u.shape[0]
    azimuth = np.empty(n)
    reach = np.empty(n)
    for k in range(n):
        reach[k] = trace_ray(grid, origin, ends_u[k], ends_v[k])
        azimuth[k] = np.arctan2(ends_v[k] - origin, ends_u[k] - origin)
    order = np.argsort(azimuth)
    # one direction per distinct azimuth (several channels share one), with the longest reach
    dir_az = np.empty(n)
    dir_reach = np.empty(n)
    m = 0
    for k in order:
        if m > 0 and azimuth[k] - dir_az[m - 1] < 1e-4:
            dir_reach[m - 1] = max(dir_reach[m - 1], reach[k])
        else:
            dir_az[m] = azimuth[k]
            dir_reach[m] = reach[k]
            m += 1
    for i in range(m):
        j = (i + 1) % m
        gap = dir_az[j] - dir_az[i]
        if j == 0:
            gap += 2.0 * np.pi
        if gap <= 0.0 or gap > max_gap:
            continue
        r_i = dir_reach[i]
        r_j = dir_reach[j]
        r_far = max(r_i, r_j)
        similar = abs(r_i - r_j) <= max(similar_ratio * r_far, 2.0)
        count = int(gap * r_far / 0.5)
        for c in range(1, count + 1):
            f = c / (count + 1.0)
            r = r_i + f * (r_j - r_i) if similar else min(r_i, r_j)
            a = dir_az[i] + f * gap
            trace_ray(grid, origin, origin + r * np.cos(a), origin + r * np.sin(a))
