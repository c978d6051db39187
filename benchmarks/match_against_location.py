"""Scans of a recorded mapping drive matched against one location's grid, seeded by the truth.

A location holds the grid of the one scan it was made from; the maintainer matches later scans
against it (tracking, moves along edges, edge measurements). This replays that match for a range
of scans of a drive (``_tuning.cached_drive``: recorded once, cached), each seeded by the true
relative pose, and prints how far the matched pose lies from the truth against what the matcher
claims (the square root of its covariance's rotation and largest position variance): where a
match is biased, and whether the covariance says so. Candidates override ``MatchingConfig``.

    .venv/bin/python benchmarks/generate_scene.py aliased-wing --seed 134 -o /tmp/AW134.yaml
    .venv/bin/python benchmarks/match_against_location.py --scene /tmp/AW134.yaml --location-stamp 153.4 \\
        --scans 3940:4030:6 --candidate 'faces={face_angle: 120}'
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from _tuning import cached_drive, file_scenario

from navkit import geometry as se2
from navkit.scan_grid import GridConfig, grid_from_points
from navtopo.scan_matching import MatchingConfig, match, prepare


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", type=Path, required=True, help="a scene file from benchmarks/generate_scene.py")
    parser.add_argument("--setting", default="precise")
    parser.add_argument("--cache", type=Path, default=Path("data/tuning"), help="recorded drives")
    parser.add_argument("--location-stamp", type=float, required=True, help="the location's scan stamp (s)")
    parser.add_argument("--scans", required=True, help="START:STOP[:STEP] indices of the drive's scans to match")
    parser.add_argument("--candidate", action="append", default=[], help="NAME=YAML MatchingConfig overrides")
    parser.add_argument("--json", type=Path, help="also write the rows here")
    args = parser.parse_args()

    scenario, key = file_scenario(args.scene, args.setting)
    rec = cached_drive(args.cache, scenario, key)
    stamps = np.asarray(rec.stamps, dtype=np.float64)
    location = int(np.argmin(np.abs(stamps - args.location_stamp)))
    start, stop, *step = (int(v) for v in args.scans.split(":"))
    scans = range(start, min(stop, len(rec)), step[0] if step else 1)
    candidates: dict[str, dict[str, Any]] = {"default": {}}
    for item in args.candidate:
        name, _, text = item.partition("=")
        candidates[name.strip()] = yaml.safe_load(text) or {}
    grid_config = GridConfig()
    print(f"location: scan {location} at {np.round(rec.true[location], 2).tolist()}")
    rows: list[dict[str, Any]] = []
    for name, overrides in candidates.items():
        config = MatchingConfig.model_validate({**MatchingConfig().model_dump(), **overrides})
        reference = prepare(grid_from_points(rec.observation(location).points, grid_config), grid_config, config)
        for k in scans:
            truth = se2.between(rec.true[location], rec.true[k])
            query = prepare(grid_from_points(rec.observation(k).points, grid_config), grid_config, config)
            result = match(reference, query, initial_guess=truth, config=config, grid_config=grid_config)
            error = se2.between(truth, result.pose)
            spread = result.covariance if result.covariance is not None else np.full((3, 3), np.nan)
            row = {
                "candidate": name,
                "scan": k,
                "distance_m": round(float(np.hypot(truth[0], truth[1])), 2),
                "error_m": round(float(np.hypot(error[0], error[1])), 3),
                "error_deg": round(float(np.degrees(error[2])), 2),
                "claimed_m": round(float(np.sqrt(np.max(np.linalg.eigvalsh(spread[:2, :2])))), 3),
                "claimed_deg": round(float(np.degrees(np.sqrt(spread[2, 2]))), 2),
                "accepted": bool(result.accepted),
                "overlap": round(float(result.overlap), 2),
                "wall_agreement": round(float(result.wall_agreement), 2),
            }
            rows.append(row)
            print(json.dumps(row), flush=True)
    for name in candidates:
        mine = [r for r in rows if r["candidate"] == name and r["accepted"]]
        if mine:
            degrees = np.abs([float(r["error_deg"]) for r in mine])
            print(
                f"{name}: {len(mine)} accepted, rotation error median {np.median(degrees):.2f} deg, "
                f"max {np.max(degrees):.2f} deg; "
                f"claimed median {np.median([float(r['claimed_deg']) for r in mine]):.2f} deg"
            )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
