"""Write a generated scene (``scenarios.generators``) as a scenario file, for runs and studies.

Development and tuning happen on such scenes, with seeds apart from the benchmark's, never on a
bundled benchmark scene (docs/NOTES.md, "Tuning rule"). Example, the looped building the NavTopo
loop-mapping figures in BENCHMARKS.md use, then its mapping stage in both settings:

    .venv/bin/python benchmarks/generate_scene.py ring --length 140 --seed 201 --rings 2 -o /tmp/ring201.yaml
    .venv/bin/navtopo-bench run /tmp/ring201.yaml --systems navtopo --trials 0 --setting precise,noisy --out /tmp/ring201

Same arguments, same file.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml
from _tuning import BENCHMARK_SEEDS

from scenarios import generators
from scenarios.schema import parse_spec


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("kind", choices=["tree", "ring"], help="tree: corridor_tree; ring: ring_building")
    parser.add_argument("--length", type=float, default=140.0, help="total corridor length (m)")
    parser.add_argument("--seed", type=int, default=201)
    parser.add_argument("--rings", type=int, default=2, choices=[1, 2], help="ring: one ring, or two sharing a corridor")
    parser.add_argument("--repeated-rooms", type=int, default=0, help="ring: identical rooms side by side")
    parser.add_argument(
        "--door-width", default="0.9,1.0", help="ring: MIN,MAX width of the rooms' doors (m); the robot is 0.6 m wide"
    )
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("-o", "--output", type=Path, required=True)
    args = parser.parse_args()
    if args.seed in BENCHMARK_SEEDS:
        seeds = sorted(BENCHMARK_SEEDS)
        print(f"generate_scene: seed {args.seed} is one of the benchmark's {seeds}; pick another", file=sys.stderr)
        return 2
    if args.length <= 0:
        print("generate_scene: --length must be positive", file=sys.stderr)
        return 2
    try:
        low, high = (float(v) for v in args.door_width.split(","))
    except ValueError:
        print(f"generate_scene: --door-width {args.door_width!r} is not MIN,MAX", file=sys.stderr)
        return 2
    if not 0.6 < low <= high:
        print("generate_scene: --door-width needs 0.6 < MIN <= MAX (the robot is 0.6 m wide)", file=sys.stderr)
        return 2
    if args.kind == "tree":
        spec = generators.corridor_tree(args.length, seed=args.seed, trials=args.trials)
    else:
        spec = generators.ring_building(
            args.length,
            seed=args.seed,
            rings=args.rings,
            repeated_rooms=args.repeated_rooms,
            door_width=(low, high),
            trials=args.trials,
            name=f"ring{args.seed}",
        )
    parse_spec(spec, args.output)  # the generators' output must be a valid scenario; raises otherwise
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(yaml.safe_dump(spec, sort_keys=False, default_flow_style=None, width=120), encoding="utf-8")
    print(args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
