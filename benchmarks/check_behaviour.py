"""Same behaviour before and after a change that should not alter it (a refactor).

The suite is deterministic: per (system, trial) every field of a record but timings, the
worker's process figures and where it ran is the same from run to run (docs/DESIGN.md,
"Determinism"). This script runs a fixed set of runs and compares two such sets file by file:

    # the fixed set (tiny, corridor_150m and loop_office_door with 5 trials, precise and noisy;
    # navtopo, metric_grid and oracle) with the code of this checkout, into OUT
    .venv/bin/python benchmarks/check_behaviour.py run OUT
    # ... with the code of another checkout (e.g. a `git worktree` at the revision before)
    .venv/bin/python benchmarks/check_behaviour.py run OUT --code ../before
    # identical apart from timings? exit 0, else 1 with every difference listed
    .venv/bin/python benchmarks/check_behaviour.py compare BEFORE AFTER

What is compared: every file of every run folder but the reports: ``trials.jsonl`` (record by
record, keyed by system and trial), ``summary.json``, ``mapping/*.json``, ``navigation/*.json``
and ``manifest.json`` as JSON with the keys below removed at any depth; everything else (saved
maps, trajectories, ground truth) byte for byte, JSON files inside maps as JSON too.

Removed keys: wall-clock timings (``compute_s``, ``planning_ms``, ``planning_ms_samples``,
``first_plan_ms``, ``map_load_ms``, ``ms_per_scan``, ``mapping_ms_per_scan``), the process's own
figures (``rss_bytes``, ``rss_process_bytes``, ``rss_before_load``), where and when it ran
(``worker``, ``created``, ``git_revision``, ``versions``, ``machine``, and the manifest's
``scenario.file``, a path into the checkout that ran). Memory breakdowns are
exact byte counts of data structures and are compared.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

VOLATILE = frozenset(
    {
        "compute_s",
        "planning_ms",
        "planning_ms_samples",
        "first_plan_ms",
        "map_load_ms",
        "ms_per_scan",
        "mapping_ms_per_scan",
        "rss_bytes",
        "rss_process_bytes",
        "rss_before_load",
        "worker",
        "created",
        "git_revision",
        "versions",
        "machine",
    }
)

SUITE = """\
format: navtopo-suite/1
systems: [navtopo, metric_grid, oracle]
runs:
  - scenarios: [tiny]
    settings: [precise, noisy]
  - scenarios: [corridor_150m, loop_office_door]
    settings: [precise, noisy]
    trials: 5
"""

SKIPPED_DIRS = {"report", "logs"}


def strip(value: Any) -> Any:
    """``value`` with the volatile keys removed at every depth."""
    if isinstance(value, dict):
        return {key: strip(item) for key, item in value.items() if key not in VOLATILE}
    if isinstance(value, list):
        return [strip(item) for item in value]
    return value


def run_set(out: Path, code: Path | None, workers: int) -> int:
    """The fixed set of runs into ``out`` (a suite), with the code of checkout ``code`` if given."""
    env = dict(os.environ)
    if code is not None:
        env["PYTHONPATH"] = str(code.resolve()) + os.pathsep + env.get("PYTHONPATH", "")
    with tempfile.TemporaryDirectory() as tmp:
        suite = Path(tmp) / "behaviour.yaml"
        suite.write_text(SUITE)
        command = [sys.executable, "-c", "import sys; from runners.cli import main; sys.exit(main())"]
        command += ["run", "--suite", str(suite), "--out", str(out), "--workers", str(workers)]
        return subprocess.call(command, env=env, cwd=code or Path.cwd())


def files_of(root: Path) -> set[Path]:
    found = set()
    for path in root.rglob("*"):
        relative = path.relative_to(root)
        if path.is_file() and not (SKIPPED_DIRS & set(relative.parts)):
            found.add(relative)
    return found


def trial_records(path: Path) -> dict[tuple[str, int], Any]:
    records = {}
    for line in path.read_text().splitlines():
        if line.strip():
            record = json.loads(line)
            records[(record["system"], record["trial"])] = strip(record)
    return records


def differences(a: Any, b: Any, where: str) -> list[str]:
    """Where two stripped JSON values differ, one line each (first 20 per value)."""
    if isinstance(a, dict) and isinstance(b, dict):
        found = []
        for key in sorted(set(a) | set(b), key=str):
            if key not in a or key not in b:
                found.append(f"{where}.{key}: only in {'after' if key not in a else 'before'}")
            else:
                found += differences(a[key], b[key], f"{where}.{key}")
        return found
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        found = []
        for index, (x, y) in enumerate(zip(a, b, strict=True)):
            found += differences(x, y, f"{where}[{index}]")
        return found
    if a != b:
        show = json.dumps(a)[:80], json.dumps(b)[:80]
        return [f"{where}: {show[0]} -> {show[1]}"]
    return []


def compare_file(before: Path, after: Path, relative: Path) -> list[str]:
    name = str(relative)
    if relative.name == "trials.jsonl":
        return differences(
            {f"{s}/{t}": r for (s, t), r in trial_records(before).items()},
            {f"{s}/{t}": r for (s, t), r in trial_records(after).items()},
            name,
        )
    if relative.suffix == ".json":
        a, b = strip(json.loads(before.read_text())), strip(json.loads(after.read_text()))
        if relative.name == "manifest.json":  # where the checkout lies, not what ran
            for manifest in (a, b):
                manifest.get("scenario", {}).pop("file", None)
        return differences(a, b, name)
    if before.read_bytes() != after.read_bytes():
        return [f"{name}: the bytes differ"]
    return []


def compare(before: Path, after: Path) -> list[str]:
    found = []
    files_before, files_after = files_of(before), files_of(after)
    found += [f"{path}: only before" for path in sorted(files_before - files_after)]
    found += [f"{path}: only after" for path in sorted(files_after - files_before)]
    for relative in sorted(files_before & files_after):
        found += compare_file(before / relative, after / relative, relative)
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("run", help="the fixed set of runs into OUT")
    run.add_argument("out", type=Path)
    run.add_argument("--code", type=Path, help="a checkout whose code runs instead of this one's (e.g. a git worktree)")
    run.add_argument("--workers", type=int, default=2)
    check = commands.add_parser("compare", help="two sets of runs: identical apart from timings?")
    check.add_argument("before", type=Path)
    check.add_argument("after", type=Path)
    args = parser.parse_args(argv)
    if args.command == "run":
        return run_set(args.out.resolve(), args.code, args.workers)
    for folder in (args.before, args.after):
        if not folder.is_dir():
            print(f"error: {folder}: not a folder", file=sys.stderr)
            return 2
    found = compare(args.before, args.after)
    for line in found[:200]:
        print(line)
    if found:
        print(f"{len(found)} differences ({args.before} -> {args.after})")
        return 1
    print(f"identical apart from timings: {len(files_of(args.before))} files ({args.before} = {args.after})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
