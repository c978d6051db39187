"""The loop scenes as full runs (``make test-slow``): mapping where corridors form loops, in both
settings, and a door shut after mapping that both systems must go round. Bounds are the issues'."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

pytestmark = pytest.mark.slow


def _run(scenario: str, setting: str, out: Path, systems: str = "navtopo,metric_grid,oracle", *extra: str) -> dict:
    command = [sys.executable, "-m", "runners.cli", "run", scenario, "--systems", systems, *extra]
    command += ["--setting", setting, "--workers", "2", "--out", str(out)]
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=3 * 3600)
    assert result.returncode == 0, result.stderr[-2000:]
    return json.loads((out / "summary.json").read_text())


def _two_laps(tmp_path: Path) -> Path:
    """loop_office with a route of two laps: its tour (799 m) covers the building once, so the
    bundled route's second half maps new places by construction; here the second lap (the tour
    backwards) revisits every place, and a location made there is a place mapped twice."""
    text = (ROOT / "scenarios" / "bundled" / "loop_office.yaml").read_text(encoding="utf-8")
    assert "auto: {min_length: 600.8}" in text
    path = tmp_path / "loop_office_two_laps.yaml"
    path.write_text(text.replace("auto: {min_length: 600.8}", "auto: {min_length: 1200}"), encoding="utf-8")
    return path


@pytest.mark.parametrize("setting", ["precise", "noisy"])
def test_navtopo_maps_a_building_with_loops_without_mapping_places_twice(setting, tmp_path):
    out = tmp_path / "run"
    _run(str(_two_laps(tmp_path)), setting, out, "navtopo", "--trials", "0")
    mapping = json.loads((out / "mapping" / "navtopo.json").read_text())
    assert mapping["edge_error"]["translation_m"]["max"] <= 0.3
    assert mapping["edge_error"]["rotation_deg"]["max"] <= 3.0
    assert mapping["vertices_second_half_share"] <= 0.1


def test_both_systems_go_round_a_door_shut_after_mapping(tmp_path):
    summary = _run("loop_office_door", "precise", tmp_path / "run")
    for name in ("navtopo", "metric_grid"):
        assert summary[name]["success_rate"] >= 0.9, (name, summary[name]["failure_reasons"])
    records = [json.loads(line) for line in (tmp_path / "run" / "trials.jsonl").read_text().splitlines()]
    assert any(r["system"] == "navtopo" and r.get("planning_ms", {}).get("count") for r in records)
