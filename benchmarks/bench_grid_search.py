"""Plan-time benchmark of navkit.grid_search on large synthetic grids.

Two kinds of grid per size: a random obstacle field (discs and boxes, ~25 % blocked) and a
maze (a perfect maze of corridors on a coarse lattice, scaled up), both planned corner to
corner, the worst case for a search. The first call of each planner compiles or loads the
numba cache and is not timed. Prints the median wall-clock and the median CPU time of the
process over --repeats calls (the erosion by the robot radius: one call; ``passable``, a
planner's medial level on a clearance raster made once: --repeats calls; the exact squared
distance transform ``clearance_squared`` against OpenCV's exact one, squared and rounded as it
was before ``navkit`` had its own: --repeats calls); on a shared machine (see the load average
printed first) the CPU time is the steadier figure. ``--size 200`` is a NavTopo union grid's size.

    python benchmarks/bench_grid_search.py --size 1000 3000 --repeats 5
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable
from functools import partial
from typing import TypeVar

import cv2
import numpy as np

from navkit import grid_search


def obstacle_field(size: int, rng: np.random.Generator, blocked: float = 0.25) -> np.ndarray:
    """(size, size) bool free grid with random discs and boxes of 1-4 % of the side."""
    free = np.ones((size, size), dtype=bool)
    rows, cols = np.ogrid[:size, :size]
    while 1.0 - free.mean() < blocked:
        r, c = rng.integers(0, size, 2)
        half = int(rng.integers(size // 100 + 1, size // 25 + 2))
        if rng.random() < 0.5:
            free[max(r - half, 0) : r + half, max(c - half, 0) : c + half] = False
        else:
            window = (slice(max(r - half, 0), r + half), slice(max(c - half, 0), c + half))
            disc = (rows[window[0]] - r) ** 2 + (cols[:, window[1]] - c) ** 2 <= half * half
            free[window] &= ~disc
    return free


def maze(size: int, rng: np.random.Generator, corridor: int = 20, wall: int = 5) -> np.ndarray:
    """(size, size) bool free grid: a depth-first perfect maze with `corridor`-wide passages."""
    pitch = corridor + wall
    n = max((size - wall) // pitch, 2)
    visited = np.zeros((n, n), dtype=bool)
    free = np.zeros((size, size), dtype=bool)

    def open_box(r0: int, c0: int, r1: int, c1: int) -> None:
        free[wall + r0 * pitch : wall + r1 * pitch + corridor,
             wall + c0 * pitch : wall + c1 * pitch + corridor] = True  # fmt: skip

    stack = [(0, 0)]
    visited[0, 0] = True
    open_box(0, 0, 0, 0)
    while stack:
        r, c = stack[-1]
        moves = [(r + dr, c + dc) for dr, dc in ((1, 0), (-1, 0), (0, 1), (0, -1))]
        moves = [(a, b) for a, b in moves if 0 <= a < n and 0 <= b < n and not visited[a, b]]
        if not moves:
            stack.pop()
            continue
        a, b = moves[rng.integers(len(moves))]
        visited[a, b] = True
        open_box(min(r, a), min(c, b), max(r, a), max(c, b))
        stack.append((a, b))
    return free


Result = TypeVar("Result")


def time_call(plan: Callable[[], Result], repeats: int) -> tuple[float, float, Result]:
    """Median wall-clock ms, median CPU ms and the result of `repeats` calls after a warm-up."""
    result = plan()  # compile / load the cache, warm the allocator
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        result = plan()
        wall.append((time.perf_counter() - t0) * 1e3)
        cpu.append((time.process_time() - c0) * 1e3)
    return statistics.median(wall), statistics.median(cpu), result


def opencv_squared(free: np.ndarray) -> np.ndarray:
    """``clearance_squared`` as OpenCV's exact transform gives it (the outside non-free)."""
    padded = np.pad(free, 1, mode="constant", constant_values=False).view(np.uint8)
    distance = cv2.distanceTransform(padded, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
    return np.rint(np.square(distance, dtype=np.float64))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, nargs="+", default=[1000, 3000])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)

    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
    print(f"{'grid':<18}{'free %':>7}{'planner':>12}{'wall ms':>9}{'cpu ms':>9}"
          f"{'length':>9}{'vertices':>9}")  # fmt: skip
    for size in args.size:
        for kind, make in (("obstacles", obstacle_field), ("maze", maze)):
            free = make(size, rng)
            start = grid_search.nearest_free(free, (0, 0), size)
            goal = grid_search.nearest_free(free, (size - 1, size - 1), size)
            assert start is not None and goal is not None
            label = f"{kind} {size}x{size}"
            for name, planner in (("astar", grid_search.astar),
                                  ("theta_star", grid_search.theta_star)):  # fmt: skip
                wall, cpu, path = time_call(partial(planner, free, start, goal), args.repeats)
                length = grid_search.path_length(path, 1.0) if path is not None else float("nan")
                vertices = len(path) if path is not None else 0
                print(f"{label:<18}{100 * free.mean():>7.1f}{name:>12}{wall:>9.1f}{cpu:>9.1f}"
                      f"{length:>9.1f}{vertices:>9d}")  # fmt: skip
            inflate = partial(grid_search.inflate_free, free, 0.3, 0.05)
            wall, cpu, _ = time_call(inflate, 1)
            print(f"{label:<18}{'':>7}{'inflate':>12}{wall:>9.1f}{cpu:>9.1f}")
            # a planner's medial level on a transform made once (the metric baseline's third level)
            squared = grid_search.clearance_squared(free)
            medial = partial(grid_search.passable, squared, 0.325, 0.05, 0.3)
            wall, cpu, _ = time_call(medial, args.repeats)
            print(f"{label:<18}{'':>7}{'passable':>12}{wall:>9.1f}{cpu:>9.1f}")
            for name, transform in (("edt", grid_search.clearance_squared), ("edt opencv", opencv_squared)):
                wall, cpu, squared = time_call(partial(transform, free), args.repeats)
                print(f"{label:<18}{'':>7}{name:>12}{wall:>9.2f}{cpu:>9.2f}")
            assert np.array_equal(grid_search.clearance_squared(free), opencv_squared(free))


if __name__ == "__main__":
    main()
