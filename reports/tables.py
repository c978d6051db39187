"""Summary tables of a results folder (Markdown, CSV). Reads only the folder's files."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

COLUMNS = [
    ("system", "system"),
    ("success", "success"),
    ("efficiency", "efficiency"),
    ("spl", "SPL"),
    ("first_plan_ms", "first plan median (ms)"),
    ("planning_median_ms", "planning median (ms)"),
    ("planning_p95_ms", "planning p95 (ms)"),
    ("memory_mb", "memory total (MB)"),
    ("map_mb", "map (MB, exact)"),
    ("disk_mb", "map on disk (MB)"),
    ("rss_mb", "RSS growth (MB)"),
    ("mapping_ms_per_scan", "mapping (ms/scan)"),
]


def _mb(value: Any) -> str:
    return f"{value / 1e6:.2f}" if isinstance(value, (int, float)) else "–"


def _num(value: Any, digits: int = 3) -> str:
    return f"{value:.{digits}f}" if isinstance(value, (int, float)) else "–"


def rows(run_dir: Path) -> list[dict[str, str]]:
    summary = json.loads((Path(run_dir) / "summary.json").read_text())
    out = []
    for name, s in summary.items():
        planning = s.get("planning_ms") or {}
        memory = s.get("memory") or {}
        mapping = s.get("mapping_ms_per_scan") or {}
        out.append(
            {
                "system": name,
                "success": f"{s.get('successes', 0)}/{s.get('trials', 0)}",
                "efficiency": _num(s.get("efficiency_mean")),
                "spl": _num(s.get("spl_mean")),
                "first_plan_ms": _num((s.get("first_plan_ms") or {}).get("median"), 2),
                "planning_median_ms": _num(planning.get("median"), 2),
                "planning_p95_ms": _num(planning.get("p95"), 2),
                "memory_mb": _mb(memory.get("total")),
                "map_mb": _mb(memory.get("map_bytes")),
                "disk_mb": _mb(memory.get("disk_bytes")),
                "rss_mb": _mb(memory.get("rss_bytes")),
                "mapping_ms_per_scan": _num(mapping.get("median"), 2),
            }
        )
    return out


def markdown(table: list[dict[str, str]]) -> str:
    header = "| " + " | ".join(title for _, title in COLUMNS) + " |"
    rule = "|" + "|".join("---" for _ in COLUMNS) + "|"
    lines = [header, rule] + ["| " + " | ".join(row[key] for key, _ in COLUMNS) + " |" for row in table]
    return "\n".join(lines) + "\n"


def to_csv(table: list[dict[str, str]]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=[key for key, _ in COLUMNS])
    writer.writeheader()
    writer.writerows(table)
    return buffer.getvalue()


def write_tables(run_dir: Path) -> Path:
    out = Path(run_dir) / "report"
    out.mkdir(parents=True, exist_ok=True)
    table = rows(run_dir)
    (out / "table.md").write_text(markdown(table))
    (out / "table.csv").write_text(to_csv(table))
    return out
