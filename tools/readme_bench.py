"""Puts a real benchmark run into the README: its report's Table 1 and three of its plots.

    .venv/bin/python tools/readme_bench.py results/corridor_150m/bench

The run's report is made (``navtopo-bench report RUN``) if it is missing; the plots are copied to
``docs/img/bench_*.png`` and the table, with the run's revision, date and command, replaces what
stands between the README's ``<!-- bench:start -->`` and ``<!-- bench:end -->`` markers. Nothing in
that section is written by hand: run this again after a new ``make bench``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
START, END = "<!-- bench:start -->", "<!-- bench:end -->"
PLOTS = [  # (report plot, README image, caption)
    ("trajectories_navtopo", "bench_trajectories_navtopo", "NavTopo's trials over the ground-truth map (failures marked)"),
    ("planning", "bench_planning", "planning time per call, every system (log scale; failed trials counted under each)"),
    ("map_navtopo", "bench_map_navtopo", "NavTopo's graph of locations over the ground-truth map"),
]


def section(run: Path, table: str) -> str:
    manifest = json.loads((run / "manifest.json").read_text(encoding="utf-8"))
    revision = str(manifest.get("git_revision") or "unknown")[:12]
    created = manifest.get("created", "unknown date")
    cores = (manifest.get("machine") or {}).get("cpus", "?")
    scenario = manifest.get("scenario")
    scenario = scenario.get("name") if isinstance(scenario, dict) else scenario or run.parent.name
    lines = [
        START,
        f"From `make bench` ({scenario}, revision `{revision}`, {created}; {cores} cores), written by",
        f"`.venv/bin/python tools/readme_bench.py {run.relative_to(ROOT) if run.is_relative_to(ROOT) else run}`:",
        "",
        table.strip(),
        "",
    ]
    for _, image, caption in PLOTS:
        lines += [f"![{caption}](docs/img/{image}.png)", "", f"*{caption}.*", ""]
    lines.append(END)
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a finished run folder (make bench writes results/<scenario>/bench)")
    parser.add_argument("--readme", type=Path, default=ROOT / "README.md")
    parser.add_argument("--images", type=Path, default=ROOT / "docs" / "img", help="where the plots go (the README's docs/img)")
    args = parser.parse_args()
    run = args.run.resolve()
    if not (run / "summary.json").is_file():
        print(f"error: {run}: not a finished run (no summary.json)", file=sys.stderr)
        return 2
    report = run / "report"
    if not (report / "table.md").is_file():
        subprocess.run([sys.executable, "-m", "runners.cli", "report", str(run)], cwd=ROOT, check=True)
    missing = [name for name, _, _ in PLOTS if not (report / "plots" / f"{name}.png").is_file()]
    if missing:
        print(f"error: {report / 'plots'}: no {', '.join(missing)} (the run must hold navtopo)", file=sys.stderr)
        return 2
    text = args.readme.read_text(encoding="utf-8")
    if text.count(START) != 1 or text.count(END) != 1:
        print(f"error: {args.readme}: expected one {START} ... {END} section", file=sys.stderr)
        return 2
    table = (report / "table.md").read_text(encoding="utf-8").split("\n", 1)[1]  # without its heading
    for name, image, _ in PLOTS:
        shutil.copyfile(report / "plots" / f"{name}.png", args.images / f"{image}.png")
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    args.readme.write_text(head + section(run, table) + tail, encoding="utf-8")
    print(f"wrote {args.readme} and {args.images}/bench_*.png from {run}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
