"""NavTopo's mapping-end passes (``NavTopo.finish_mapping``: shortcuts between locations joined only
the long way round, every edge's length as the local planner drives it) made again on the saved
maps of earlier runs, into copies of those runs that ``navtopo-bench run --maps-from`` can use.

The mapping drive (locations, their grids, the edges it made) is kept as saved; only the passes
that run when it ends are made at the current code: the edges' lengths are cleared and measured
again, and shortcuts the current pass finds are added (those the earlier pass made stay). For
measuring a change to those passes without driving every route again; the copy's
``mapping/navtopo.json`` records where it came from (``refinished_from``) and its new counts.

    .venv/bin/python benchmarks/refinish_navtopo_maps.py RUN OUT [RUN OUT ...] [--mapping '{"shortcut_ratio": 1.5}']

``--mapping``: NavTopo mapping-config overrides for the passes (for tuning them on generated scenes;
recorded in the copy's ``mapping/navtopo.json`` as ``refinished_with``).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

from navtopo.system import NavTopo, NavTopoConfig


def refinish(run: Path, out: Path, mapping: dict) -> dict:
    if out.exists():
        raise SystemExit(f"{out}: already exists; give a new folder")
    manifest = json.loads((run / "manifest.json").read_text())
    base = manifest["config"]["navtopo"]
    config = NavTopoConfig.model_validate({**base, "mapping": {**base.get("mapping", {}), **mapping}})
    system = NavTopo.load(run / "maps" / "navtopo", config)
    edges_before = system.graph.edge_count
    system.graph.clear_edge_lengths()
    system.finish_mapping()
    shutil.copytree(
        run,
        out,
        symlinks=True,
        ignore=shutil.ignore_patterns("navigation", "trajectories", "trials.jsonl", "summary.json", "report"),
    )
    shutil.rmtree(out / "maps" / "navtopo")
    system.save(out / "maps" / "navtopo")
    record_path = out / "mapping" / "navtopo.json"
    record = json.loads(record_path.read_text())
    counters = system.maintainer.counters
    record["refinished_from"] = str(run)
    record["refinished_with"] = mapping
    record["edges"] = system.graph.edge_count
    record.setdefault("counters", {})["shortcuts"] = record["counters"].get("shortcuts", 0) + counters.shortcuts
    record["counters"]["edges_measured"] = counters.edges_measured
    record_path.write_text(json.dumps(record))
    return {
        "run": str(run),
        "out": str(out),
        "edges": [edges_before, system.graph.edge_count],
        "measured": counters.edges_measured,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("pairs", type=Path, nargs="+", help="RUN OUT pairs")
    parser.add_argument("--mapping", default="{}", help="NavTopo mapping-config overrides (JSON)")
    args = parser.parse_args()
    if len(args.pairs) % 2:
        parser.error("give RUN OUT pairs")
    for run, out in zip(args.pairs[::2], args.pairs[1::2], strict=True):
        print(json.dumps(refinish(run, out, json.loads(args.mapping))))


if __name__ == "__main__":
    main()
