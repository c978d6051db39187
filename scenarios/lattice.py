"""Procedural buildings with loops at any size: a lattice of corridors round blocks, dressed as offices.

``lattice_building(total_length, seed)`` lays ``nx`` x ``ny`` blocks of one size, with corridors
along every block edge, so that the corridors' centre lines total ``total_length`` metres exactly:
``(ny + 1) * nx * block + (nx + 1) * ny * block``. Of the grid shapes whose block lies within
``block_m``, the most nearly square one is taken (ties: the larger block). Every pair of
neighbouring junctions is joined two ways round a block, so a mapping route closes loops wherever it
goes, as in an office floor or a hospital. ``scenarios.generators.dress`` then adds door niches,
side rooms, furniture of several heights and pillars along the corridors (never in junctions). Used
by the scaling sweep (``navtopo-bench sweep scaling``); same length and seed, same building.
"""

from __future__ import annotations

import numpy as np

from scenarios.generators import dress, scenario_dict


def lattice_shape(total_length: float, block_m: tuple[float, float] = (12.0, 26.0)) -> tuple[int, int, float]:
    """(nx, ny, block) with corridors totalling ``total_length``; raises ValueError if none fits."""
    best = None
    for nx in range(1, 200):
        for ny in range(1, nx + 1):
            block = total_length / ((ny + 1) * nx + (nx + 1) * ny)
            if block_m[0] <= block <= block_m[1]:
                key = (nx / ny, -block)
                if best is None or key < best[0]:
                    best = (key, (nx, ny, block))
    if best is None:
        raise ValueError(f"no lattice of blocks {block_m[0]:g}-{block_m[1]:g} m totals {total_length:g} m of corridor")
    return best[1]


def lattice_building(
    total_length: float,
    seed: int = 0,
    corridor_width: tuple[float, float] = (1.8, 2.6),
    block_m: tuple[float, float] = (12.0, 26.0),
    route_factor: float = 1.0,
    trials: int = 20,
    min_distance: float | None = None,
    name: str | None = None,
) -> dict:
    """A scenario dict (format 1) of a dressed lattice building; ``scenarios.schema.parse_spec`` reads it."""
    rng = np.random.default_rng(seed)
    nx, ny, block = lattice_shape(total_length, block_m)
    width_x, width_y = nx * block, ny * block
    corridors = [
        {"points": [[0.0, round(j * block, 3)], [round(width_x, 3), round(j * block, 3)]], "width": _width(rng, corridor_width)}
        for j in range(ny + 1)
    ]
    corridors += [
        {"points": [[round(i * block, 3), 0.0], [round(i * block, 3), round(width_y, 3)]], "width": _width(rng, corridor_width)}
        for i in range(nx + 1)
    ]
    rooms, obstacles = dress(corridors, rng)
    return scenario_dict(
        name or f"lattice_{int(round(total_length))}m_s{seed}",
        f"generated office lattice, {nx} x {ny} blocks of {block:.1f} m, {total_length:.0f} m of corridor",
        seed,
        corridors,
        rooms,
        obstacles,
        route_factor * total_length,
        trials,
        # default: 40 % of the way across the lattice (x + y), which any size can hold
        min_distance if min_distance is not None else 0.4 * (width_x + width_y),
    )


def _width(rng: np.random.Generator, widths: tuple[float, float]) -> float:
    return round(float(rng.uniform(*widths)), 2)
