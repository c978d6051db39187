"""The README's worked example of a new scenario is a scenario that loads, validates and runs."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from runners.cli import app
from scenarios import load_scenario

ROOT = Path(__file__).resolve().parent.parent


def readme_example(tmp_path: Path) -> Path:
    text = (ROOT / "README.md").read_text()
    found = re.search(r"<!-- example-scenario: (\S+) -->\n```yaml\n(.*?)```\n<!-- /example-scenario -->", text, re.S)
    assert found, "README.md lost its worked scenario example"
    path = tmp_path / found.group(1)
    path.write_text(found.group(2))
    return path


def test_the_readme_scenario_validates_and_is_what_the_readme_says(tmp_path):
    path = readme_example(tmp_path)
    result = CliRunner().invoke(app, ["scenario", "validate", str(path)])
    assert result.exit_code == 0 and "ok" in result.output
    scenario = load_scenario(path)
    summary = scenario.summary()
    assert summary["name"] == "office_t" and summary["corridor_length_m"] == pytest.approx(26.0)
    assert summary["trial_count"] == 3 and summary["route_length_m"] >= 60.0
    assert all(trial.shortest_m >= 8.0 for trial in scenario.trials)


@pytest.mark.slow
def test_the_readme_scenario_runs_and_reports(tmp_path):
    path = readme_example(tmp_path)
    out = tmp_path / "run"
    result = CliRunner().invoke(app, ["run", str(path), "--systems", "oracle", "--trials", "1", "--out", str(out)])
    assert result.exit_code == 0, result.output
    result = CliRunner().invoke(app, ["report", str(out)])
    assert result.exit_code == 0, result.output
    assert (out / "report" / "report.html").is_file() and "| office_t | precise | oracle | 1/1" in (
        out / "report" / "table.md"
    ).read_text()
