r"""Write a generated scene as a scenario file, for runs, studies and tuning.

Development and tuning happen on such scenes, with seeds apart from the benchmark's, never on a
bundled benchmark scene (docs/NOTES.md, "Tuning rule"). Kinds:

    tree, ring, lattice        shape buildings (scenarios.generators, scenarios.lattice)
    hall                       an open hall with rows of racks, a warehouse (scenarios.hall)
    slam-ring, slam-tree,      the same drawn as a robot's SLAM map (scenarios.slam_like): a PGM +
    slam-lattice, slam-hall    YAML map beside the scenario (<output stem>_map.*), the building's
                               route (one tour) and trials; --artefacts changes the amounts
    aliased-wing               identical rooms along one or two corridors (--rooms a row, --corridors)
    aliased-ring               a ring whose --sides (2 or 4) look the same (--rooms a side)
    mirror                     a ring building mirror-symmetric about a cross corridor

Example, the looped building the NavTopo loop-mapping figures in BENCHMARKS.md use, then its
mapping stage in both settings:

    .venv/bin/python benchmarks/generate_scene.py ring --length 140 --seed 201 --rings 2 -o /tmp/ring201.yaml
    .venv/bin/navtopo-bench run /tmp/ring201.yaml --systems navtopo --trials 0 --setting precise,noisy --out /tmp/ring201

A SLAM-like map with more speckle and no laser fans:

    .venv/bin/python benchmarks/generate_scene.py slam-ring --seed 301 -o /tmp/s301/ring.yaml \
        --artefacts speckle_per_100m2=6,fans_per_100m=0

A world that changes after mapping (two corridor stretches shut; 3 in 4 trials meet one):

    .venv/bin/python benchmarks/generate_scene.py ring --seed 431 --shut 2 --trials 12 -o /tmp/shut431.yaml

Same arguments, same files (byte for byte).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import yaml
from _tuning import BENCHMARK_SEEDS

from navkit.errors import BenchError
from scenarios import aliased, generators, hall, lattice
from scenarios.changes import with_shut_stretches
from scenarios.schema import parse_spec
from scenarios.slam_like import Artefacts, write_slam_scenario

SHUT_KINDS = ["ring", "lattice", "mirror"]
KINDS = [
    "tree",
    "ring",
    "lattice",
    "hall",
    "slam-ring",
    "slam-tree",
    "slam-lattice",
    "slam-hall",
    "aliased-wing",
    "aliased-ring",
    "mirror",
]


class Refused(Exception):
    """An argument refused: the one line to print."""


def arguments() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("kind", choices=KINDS)
    parser.add_argument(
        "--length",
        type=float,
        default=140.0,
        help="total corridor length (m): tree, ring, lattice, slam-*, mirror; the long side: hall",
    )
    parser.add_argument("--seed", type=int, default=201)
    parser.add_argument(
        "--rings", type=int, default=2, choices=[1, 2], help="ring, slam-ring: one ring, or two sharing a corridor"
    )
    parser.add_argument("--repeated-rooms", type=int, default=0, help="ring: identical rooms side by side")
    parser.add_argument(
        "--door-width", default="0.9,1.0", help="ring: MIN,MAX width of the rooms' doors (m); the robot is 0.6 m wide"
    )
    parser.add_argument("--rooms", type=int, default=None, help="aliased-wing: rooms a row (8); aliased-ring: rooms a side (4)")
    parser.add_argument("--corridors", type=int, default=2, choices=[1, 2], help="aliased-wing: one corridor, or two in a ring")
    parser.add_argument("--sides", type=int, default=4, choices=[2, 4], help="aliased-ring: look-alike sides")
    parser.add_argument(
        "--artefacts",
        default="",
        help="slam-*: KEY=VALUE,... of scenarios.slam_like.Artefacts (e.g. speckle_per_100m2=6), or 'none'",
    )
    parser.add_argument("--route-factor", type=float, default=None, help="auto route of at least this x the corridor length")
    parser.add_argument(
        "--shut",
        type=int,
        default=0,
        help="ring, lattice, mirror: corridor stretches shut after mapping (world.changes, a fire door closed); the "
        "trials are then explicit, 3 in 4 of them through a shut stretch (scenarios.changes)",
    )
    parser.add_argument("--trials", type=int, default=20)
    parser.add_argument("-o", "--output", type=Path, required=True)
    return parser


def door_widths(text: str) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in text.split(","))
    except ValueError:
        raise Refused(f"--door-width {text!r} is not MIN,MAX") from None
    if not 0.6 < low <= high:
        raise Refused("--door-width needs 0.6 < MIN <= MAX (the robot is 0.6 m wide)")
    return low, high


def artefacts(text: str) -> Artefacts:
    """``KEY=VALUE,...`` over the defaults; a tuple's VALUE is ``LOW:HIGH``."""
    if text.strip() == "none":
        return Artefacts.none()
    fields = {f.name: f for f in dataclasses.fields(Artefacts)}
    values: dict[str, object] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, _, value = part.partition("=")
        if key not in fields:
            raise Refused(f"--artefacts: unknown amount {key!r} (one of {', '.join(fields)})")
        try:
            default = getattr(Artefacts(), key)
            if isinstance(default, tuple):
                values[key] = tuple(type(default[0])(v) for v in value.split(":"))
                if len(values[key]) != 2:  # type: ignore[arg-type]
                    raise ValueError
            else:
                values[key] = type(default)(value)
        except ValueError:
            raise Refused(f"--artefacts: {key}={value!r} is not a number (a range: LOW:HIGH)") from None
    try:
        return Artefacts(**values)  # type: ignore[arg-type]
    except ValueError as exc:
        raise Refused(f"--artefacts: {exc}") from None


def shape_spec(args: argparse.Namespace, kind: str) -> dict:
    """The scenario dict of a shape kind (a slam kind's building: its own kind without ``slam-``)."""
    factor = {"route_factor": args.route_factor} if args.route_factor is not None else {}
    if kind.startswith("slam-"):
        factor = {"route_factor": args.route_factor if args.route_factor is not None else 1.0}  # one tour
        kind = kind.removeprefix("slam-")
    if kind == "tree":
        return generators.corridor_tree(args.length, seed=args.seed, trials=args.trials, **factor)
    if kind == "ring":
        return generators.ring_building(
            args.length,
            seed=args.seed,
            rings=args.rings,
            repeated_rooms=args.repeated_rooms,
            door_width=door_widths(args.door_width),
            trials=args.trials,
            name=f"ring{args.seed}",
            **factor,
        )
    if kind == "lattice":
        return lattice.lattice_building(args.length, seed=args.seed, trials=args.trials, **factor)
    if kind == "hall":
        return hall.hall_building(args.length, seed=args.seed, trials=args.trials, **factor)
    if kind == "aliased-wing":
        rooms = args.rooms if args.rooms is not None else 8
        return aliased.aliased_wing(rooms, seed=args.seed, corridors=args.corridors, trials=args.trials, **factor)
    if kind == "aliased-ring":
        rooms = args.rooms if args.rooms is not None else 4
        return aliased.aliased_ring(rooms, seed=args.seed, sides=args.sides, trials=args.trials, **factor)
    return aliased.mirror_floor(args.length, seed=args.seed, trials=args.trials, **factor)


def main() -> int:
    args = arguments().parse_args()
    try:
        if args.seed in BENCHMARK_SEEDS:
            raise Refused(f"seed {args.seed} is one of the benchmark's {sorted(BENCHMARK_SEEDS)}; pick another")
        if args.length <= 0:
            raise Refused("--length must be positive")
        amounts = artefacts(args.artefacts) if args.kind.startswith("slam-") else None
        spec = shape_spec(args, args.kind)
        if args.shut:
            if args.kind not in SHUT_KINDS:
                raise Refused(f"--shut: {args.kind} has no loop round a shut stretch; one of {', '.join(SHUT_KINDS)}")
            spec = with_shut_stretches(spec, args.output, args.shut, args.seed, args.trials)
        if amounts is not None:
            made = write_slam_scenario(spec, args.output, args.seed, amounts)  # validated before it writes
            print(f"{args.output}: {made.record.summary()}")
            return 0
        parse_spec(spec, args.output)  # the generators' output must be a valid scenario
    except (Refused, BenchError) as exc:  # BenchError: the scenario refused, one line naming file and key
        print(f"generate_scene: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:  # a building the generators cannot make (a lattice of that length, ...)
        print(f"generate_scene: {args.kind}: {exc}", file=sys.stderr)
        return 2
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(yaml.safe_dump(spec, sort_keys=False, default_flow_style=None, width=120), encoding="utf-8")
    print(args.output)
    return 0


if __name__ == "__main__":
    sys.exit(main())
