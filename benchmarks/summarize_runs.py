"""The figures BENCHMARKS.md quotes, printed from results folders: one Markdown table per kind of
figure, every number read from the run's own files (``summary.json``, ``mapping/*.json``,
``trials.jsonl``, ``manifest.json``), none typed by hand.

    .venv/bin/python benchmarks/summarize_runs.py RUN_DIR [RUN_DIR ...]
    .venv/bin/python benchmarks/summarize_runs.py --by-scene RUN_DIR [RUN_DIR ...]

``--by-scene``: one compact table per setting instead, a row per scene and a column per system
(success, mean efficiency over the successes, failures by reason and stage), and a row of totals;
where a scene's system is in several runs (a system's trials made again on a run's maps with
``--maps-from``), the newest run's trials count.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def _num(value: Any, digits: int = 3) -> str:
    return f"{value:.{digits}f}" if isinstance(value, (int, float)) else "–"


def _mb(value: Any) -> str:
    return f"{value / 1e6:.2f}" if isinstance(value, (int, float)) else "–"


def _read(path: Path) -> Any:
    return json.loads(path.read_text()) if path.is_file() else {}


def _scene_cell(records: list[dict[str, Any]]) -> str:
    """success/trials, mean efficiency over the successes, failures by reason (stage)."""
    good = [r for r in records if r.get("success")]
    failures: dict[str, int] = {}
    for r in records:
        if not r.get("success"):
            key = f"{r.get('reason')} ({r.get('failure_stage')})"
            failures[key] = failures.get(key, 0) + 1
    cell = f"{len(good)}/{len(records)}"
    if good:
        cell += f", {sum(float(r['efficiency']) for r in good) / len(good):.3f}"
    return cell + "".join(f", {k}" + (f" x{n}" if n > 1 else "") for k, n in failures.items())


def by_scene(run_dirs: list[Path]) -> None:
    """``--by-scene``: a table per setting, a row per scene, a column per system (the newest run's trials)."""
    latest: dict[tuple[str, str, str], tuple[str, list[dict[str, Any]]]] = {}
    order: list[tuple[str, str]] = []
    for run in run_dirs:
        manifest = _read(run / "manifest.json")
        scene, setting, created = manifest.get("scenario", {}).get("name"), manifest.get("setting"), manifest.get("created", "")
        if (scene, setting) not in order:
            order.append((scene, setting))
        path = run / "trials.jsonl"
        trials = [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []
        for system in sorted({r["system"] for r in trials}):
            key = (scene, setting, system)
            if key not in latest or created > latest[key][0]:
                latest[key] = (created, [r for r in trials if r["system"] == system])
    systems = sorted({k[2] for k in latest}, key=lambda name: (name != "navtopo", name != "metric_grid", name))
    for setting in dict.fromkeys(s for _, s in order):
        print(f"\n| scene ({setting}) | " + " | ".join(systems) + " |\n|---|" + "---|" * len(systems))
        totals = {system: [0, 0] for system in systems}
        for scene, _ in [o for o in order if o[1] == setting]:
            cells = []
            for system in systems:
                records = latest.get((scene, setting, system), ("", []))[1]
                totals[system][0] += sum(bool(r.get("success")) for r in records)
                totals[system][1] += len(records)
                cells.append(_scene_cell(records) if records else "–")
            print(f"| {scene} | " + " | ".join(cells) + " |")
        print("| **all** | " + " | ".join(f"**{ok}/{n}**" for ok, n in totals.values()) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run_dirs", type=Path, nargs="+")
    parser.add_argument("--by-scene", action="store_true", help="a table per setting: a row per scene, a column per system")
    args = parser.parse_args()
    if args.by_scene:
        by_scene(args.run_dirs)
        return
    rows_nav, rows_mem, rows_map, rows_loc, rows_runs = [], [], [], [], []
    for run in args.run_dirs:
        manifest = _read(run / "manifest.json")
        summary = _read(run / "summary.json")
        label = f"{manifest.get('scenario', {}).get('name')} / {manifest.get('setting')}"
        goals = (manifest.get("protocol") or {}).get("goals", "map")
        smoothing = ((manifest.get("config") or {}).get("navtopo") or {}).get("planning", {}).get("smoothing")
        extra = []
        if goals != "map":
            extra.append(f"goals {goals}")
        if (manifest.get("protocol") or {}).get("initial_pose") == "none":
            extra.append("kidnapped")
        if smoothing and smoothing != "lookahead":
            extra.append(f"smoothing {smoothing}")
        if manifest.get("maps_from"):
            extra.append("maps from the run above")
        if extra:
            label += " (" + ", ".join(extra) + ")"
        rows_runs.append(f"| {run.name} | {label} | {manifest.get('git_revision')} | {manifest.get('created')} |")
        for name, s in summary.items():
            planning, first = s.get("planning_ms") or {}, s.get("first_plan_ms") or {}
            memory = s.get("memory") or {}
            tracking = s.get("tracking_error_m") or {}
            reasons = ", ".join(f"{k} {v}" for k, v in (s.get("failure_reasons") or {}).items()) or "–"
            rows_nav.append(
                f"| {label} | {name} | {s.get('successes')}/{s.get('trials')} | {_num(s.get('efficiency_mean'))} | "
                f"{_num(s.get('spl_mean'))} | {_num(first.get('median'), 2)} | {_num(planning.get('median'), 2)} / "
                f"{_num(planning.get('p95'), 2)} ({planning.get('count')}) | {_num(s.get('map_load_ms'), 1)} | "
                f"{_num(tracking.get('median'))} / {_num(tracking.get('p95'))} | {reasons} |"
            )
            rows_mem.append(
                f"| {label} | {name} | {_mb(memory.get('total'))} | {_mb(memory.get('map'))} | "
                f"{_mb(memory.get('localization'))} | {_mb(memory.get('derived'))} | {_mb(memory.get('model'))} | "
                f"{_mb(memory.get('disk_bytes'))} | "
                f"{_mb(memory.get('rss_bytes'))} | {_mb(memory.get('rss_process_bytes'))} |"
            )
            loc = s.get("startup_localization")
            if loc:
                seconds = loc.get("seconds") or {}
                conversion = s.get("goal_conversion_error_m") or {}
                metres = loc.get("metres") or {}
                rows_loc.append(
                    f"| {label} | {name} | {loc['right']} | {loc['wrong']} | {loc['not_localized']} | "
                    f"{loc.get('from_given_pose', '–')} | {_num(seconds.get('median'), 1)} / {_num(seconds.get('max'), 1)} | "
                    f"{_num(metres.get('median'), 2)} / {_num(metres.get('max'), 2)} | {_num(loc.get('error_m_median'))} | "
                    f"{_num(s.get('efficiency_after_startup_mean'))} | {_num(conversion.get('median'))} / "
                    f"{_num(conversion.get('max'))} |"
                )
        for path in sorted((run / "mapping").glob("*.json")) if (run / "mapping").is_dir() else []:
            mapping = _read(path)
            if "edge_error" in mapping and not mapping.get("maps_from"):
                edges = mapping["edge_error"]
                counters = mapping.get("counters", {})
                per_scan = mapping.get("ms_per_scan") or {}
                rows_map.append(
                    f"| {label} | {mapping.get('vertices')} | {mapping.get('edges')} | "
                    f"{_num(edges['translation_m']['median'])} / {_num(edges['translation_m']['max'])} | "
                    f"{_num(edges['rotation_deg']['median'], 2)} / {_num(edges['rotation_deg']['max'], 2)} | "
                    f"{_num(mapping.get('vertices_second_half_share'), 2)} "
                    f"({mapping.get('vertices_second_half', '–')}, {mapping.get('vertices_second_half_revisited', '–')}) | "
                    f"{_num(per_scan.get('median'), 1)} / {_num(per_scan.get('p95'), 1)} | "
                    f"{counters.get('inside')} / {counters.get('moved_along_edge')} / {counters.get('localized')} / "
                    f"{counters.get('loop_closures')} / {counters.get('rejected_edges')} / {counters.get('stayed')} | "
                    f"{counters.get('rejected_closures', '–')} / {counters.get('undone_closures', '–')} |"
                )
    print("| run | scenario / setting | git revision | created |\n|---|---|---|---|")
    print("\n".join(rows_runs))
    print(
        "\n| scenario / setting | system | success | efficiency | SPL | first plan median (ms) | "
        "planning median / p95 (calls) (ms) | map load (ms) | tracking error median / p95 (m) | failures |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(rows_nav))
    print(
        "\n| scenario / setting | system | memory total (MB) | map | localization | derived | model | "
        "on disk | RSS growth | worker RSS |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(rows_mem))
    if rows_loc:
        print(
            "\n| scenario / setting | system | start-up localization right | wrong | not localized | from the given pose | "
            "seconds median / max | metres driven median / max | error median (m) | efficiency after start-up | "
            "goal conversion error median / max (m) |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        print("\n".join(rows_loc))
    if rows_map:
        print(
            "\n| scenario / setting | vertices | edges | edge error median / max (m) | edge error median / max (°) | "
            "new in 2nd half (count, at revisited places) | ms per scan median / p95 | "
            "inside / along edge / localized / loop closures / rejected / stayed | loop closures refused / undone |"
        )
        print("|---|---|---|---|---|---|---|---|---|")
        print("\n".join(rows_map))


if __name__ == "__main__":
    main()
