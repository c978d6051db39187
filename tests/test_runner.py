"""The runner end to end: the oracle on `tiny`, an interrupted run resumed, the CLI contracts."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from runners.cli import app
from runners.results import RunDir

ROOT = Path(__file__).resolve().parent.parent


def cli(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "runners.cli", *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout)


@pytest.mark.long
def test_an_interrupted_oracle_run_resumes_without_losing_or_duplicating_a_trial(tmp_path):
    from test_scaleout import short_tiny

    out = tmp_path / "run"
    process = subprocess.Popen(
        [sys.executable, "-m", "runners.cli", "run", str(short_tiny(tmp_path)), "--systems", "oracle", "--out", str(out)],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    trials = out / "trials.jsonl"
    deadline = time.monotonic() + 400
    while time.monotonic() < deadline and process.poll() is None:
        if trials.is_file() and trials.read_text().count("\n") >= 1:
            break
        time.sleep(0.2)
    interrupted = process.poll() is None
    if interrupted:
        os.killpg(process.pid, signal.SIGKILL)  # the run and its worker processes
        process.wait()
        assert not (out / "summary.json").exists()
    before = RunDir(out).read_trials()
    assert len(before) >= 1

    # a second driver on a folder another one holds is refused in one line, and writes nothing
    listing = sorted(p.relative_to(out) for p in out.rglob("*"))
    with RunDir(out).hold():
        refused = CliRunner().invoke(app, ["run", "--resume", str(out)])
    assert refused.exit_code != 0 and "another driver is running this run" in refused.output, refused.output
    assert f"pid {os.getpid()}" in refused.output and "Traceback" not in refused.output
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == listing and RunDir(out).read_trials() == before

    # the folder keeps the scenario as the run read it: moved away, the resume reads the copy
    original = tmp_path / "short_tiny.yaml"
    copy = out / "scenario" / "short_tiny.yaml"
    assert json.loads((out / "manifest.json").read_text())["scenario_copy"] == "scenario/short_tiny.yaml"
    assert copy.read_bytes() == original.read_bytes()
    original.rename(tmp_path / "moved.yaml")

    result = CliRunner().invoke(app, ["run", "--resume", str(out)])
    assert result.exit_code == 0, result.output
    assert "the run's own copy is read" in result.output

    from reports.report import make_report

    made = make_report([out])  # the command to run it again names the copy, from the report's folder
    assert made.sections[0].command.startswith("navtopo-bench run ../scenario/short_tiny.yaml --systems oracle")

    records = [json.loads(line) for line in trials.read_text().splitlines() if line.strip()]
    keys = [(r["system"], r["trial"]) for r in records]
    assert sorted(keys) == [("oracle", 0), ("oracle", 1), ("oracle", 2)]  # none lost, none twice
    # the oracle succeeds everywhere with near-perfect efficiency against the GT shortest path
    for r in records:
        assert r["success"], r
        assert r["efficiency"] >= 0.9
        assert r["shortest_m"] > 5.0 and r["travelled_m"] >= 0.9 * r["shortest_m"]
        assert r["planning_ms"]["count"] >= 1
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary) == ["oracle"]
    assert summary["oracle"]["success_rate"] == 1.0 and summary["oracle"]["efficiency_mean"] >= 0.9
    assert summary["oracle"]["memory"]["rss_bytes"] is not None

    # the contract's files are there: manifest, mapping report, maps, TUM trajectories
    manifest = json.loads((out / "manifest.json").read_text())
    assert {"scenario", "systems", "seed", "config", "versions", "git_revision", "machine", "created"} <= set(manifest)
    mapping = json.loads((out / "mapping" / "oracle.json").read_text())
    assert mapping["scans"] > 10 and mapping["route_length_m"] == pytest.approx(mapping["route_plan_length_m"], rel=0.1)
    assert (out / "maps" / "oracle").is_dir()
    rows = np.loadtxt(out / "trajectories" / "oracle" / "trial-0.tum")
    assert rows.shape[1] == 8
    start = records[[r["trial"] for r in records].index(0)]["start"]
    assert rows[0, 1:3] == pytest.approx(start[:2], abs=1e-6)
    assert np.linalg.norm(np.diff(rows[:, 1:3], axis=0), axis=1).sum() == pytest.approx(
        records[[r["trial"] for r in records].index(0)]["travelled_m"], rel=1e-3
    )


def test_validate_exits_2_with_one_line_per_bad_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(
        "format: navtopo-scenario/1\nname: b\n"
        "world: {corridors: [{points: [[0, 0], [5, 0]], width: -2}]}\n"
        "mapping_route: {waypoints: [[0, 0], [4, 0]]}\n"
    )
    broken = tmp_path / "broken.yaml"
    broken.write_text("format: [unclosed\n")
    result = cli("scenario", "validate", str(bad), str(broken), str(ROOT / "scenarios" / "bundled" / "tiny.yaml"))
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 2
    assert lines[0].startswith(f"{bad}: world.corridors.0.width: ")
    assert lines[1].startswith(f"{broken}: ")
    assert "Traceback" not in result.stderr + result.stdout


def test_run_refuses_a_malformed_scenario_before_writing_anything(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: navtopo-scenario/1\nname: b\nworld: {corridors: []}\nmapping_route: {waypoints: [[0, 0], [4, 0]]}\n")
    result = CliRunner().invoke(app, ["run", str(bad), "--systems", "oracle", "--results", str(tmp_path / "results")])
    assert result.exit_code == 2
    assert "bad.yaml: world: needs corridors or rooms, or a map" in result.output
    assert not (tmp_path / "results").exists()


def test_run_refuses_more_trials_than_the_scenario_lists_before_writing_anything(tmp_path):
    """``--trials`` above a scene's count is refused in one line naming the file and its count, never
    silently capped; at the count it runs (here 0 trials asked of a scene: mapping only is allowed)."""
    from scenarios.scenario import load_scenario

    listed = len(load_scenario("tiny").trials)
    result = CliRunner().invoke(
        app, ["run", "tiny", "--systems", "oracle", "--trials", str(listed + 1), "--results", str(tmp_path / "r")]
    )
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and f"--trials {listed + 1}: " in lines[0] and f"lists {listed} trials" in lines[0]
    assert "tiny" in lines[0] and "Traceback" not in result.output
    assert not (tmp_path / "r").exists()


def test_scenario_show_json_reports_the_contract_keys():
    result = CliRunner().invoke(app, ["scenario", "show", "tiny", "--json"])
    assert result.exit_code == 0
    data = json.loads(result.stdout)
    for key in (
        "name",
        "corridor_length_m",
        "free_area_m2",
        "route_length_m",
        "trial_count",
        "trial_distance_mean_m",
        "bounds_m",
    ):
        assert key in data
    assert data["corridor_length_m"] == pytest.approx(25.0)


def test_config_prints_the_resolved_oracle_config():
    result = CliRunner().invoke(app, ["config", "oracle"])
    assert result.exit_code == 0
    assert "oracle:" in result.stdout and "goal_tolerance: 0.35" in result.stdout


def test_maps_from_an_earlier_run_skips_mapping_and_refuses_another_seed(tmp_path):
    from test_scaleout import short_tiny

    scenario = str(short_tiny(tmp_path))  # the oracle maps nothing: a 3 m route
    first = tmp_path / "first"
    result = CliRunner().invoke(app, ["run", scenario, "--systems", "oracle", "--trials", "0", "--out", str(first)])
    assert result.exit_code == 0, result.output
    second = tmp_path / "second"
    result = CliRunner().invoke(
        app, ["run", scenario, "--systems", "oracle", "--trials", "1", "--maps-from", str(first), "--out", str(second)]
    )
    assert result.exit_code == 0, result.output
    mapping = json.loads((second / "mapping" / "oracle.json").read_text())
    assert (
        mapping["maps_from"] == str(first)
        and mapping["scans"] == json.loads((first / "mapping" / "oracle.json").read_text())["scans"]
    )
    assert "mapping tiny" not in result.output  # no route was driven
    assert [r.trial for r in RunDir(second).read_trials()] == [0]
    refused = CliRunner().invoke(
        app, ["run", scenario, "--systems", "oracle", "--seed", "5", "--maps-from", str(first), "--out", str(tmp_path / "x")]
    )
    assert refused.exit_code == 2 and "seed" in refused.output and not (tmp_path / "x").exists()


def test_after_ctrl_c_the_resume_hint_is_the_last_thing_on_the_terminal(tmp_path):
    """Under a pseudo-terminal (the progress display redraws in place): Ctrl-C during the trials
    leaves ``interrupted; finish the run with --resume <folder>`` as the last line, with no redraw
    of the display after it."""
    import pty
    import re
    import select

    from test_scaleout import short_tiny

    out = tmp_path / "run"
    command = [sys.executable, "-m", "runners.cli", "run", str(short_tiny(tmp_path)), "--systems", "oracle", "--out", str(out)]
    pid, fd = pty.fork()
    if pid == 0:  # the child: the command, on the terminal
        os.chdir(ROOT)
        os.execv(sys.executable, command)
    screen, sent, deadline = b"", False, time.monotonic() + 300
    while time.monotonic() < deadline:
        if select.select([fd], [], [], 0.2)[0]:
            try:
                data = os.read(fd, 65536)
            except OSError:  # the terminal closed: the command ended
                break
            if not data:
                break
            screen += data
        if not sent and b"trials" in screen:  # the navigation bar is up: the run is under way
            time.sleep(0.5)
            os.write(fd, b"\x03")
            sent = True
    _, status = os.waitpid(pid, 0)
    assert sent and os.waitstatus_to_exitcode(status) == 130, screen[-2000:]
    hint = screen.rfind(b"interrupted; finish the run with --resume")
    assert hint >= 0, screen[-2000:]
    after = screen[hint:]
    assert not re.search(rb"\x1b\[\d*[ABJK]", after), after  # no cursor moved up, no line erased after it
    text = re.sub(rb"\x1b\[[0-9;?]*[A-Za-z]", b"", after).decode()
    assert text.strip().splitlines() == [f"interrupted; finish the run with --resume {out}"]


@pytest.mark.parametrize("width", [80, 120])
def test_the_summary_fits_the_terminal_whole_numbers_and_failures_by_reason(tmp_path, monkeypatch, width):
    from crafted_run import write_crafted_run
    from rich.console import Console

    import runners.commands.progress as progress
    from reports.tables import COLUMNS, rows

    run = write_crafted_run(tmp_path / "run")
    summary = json.loads((run / "summary.json").read_text())
    summary["navtopo"]["failure_reasons"] = {"collision": 1, "no_path": 2}
    (run / "summary.json").write_text(json.dumps(summary))
    screen = Console(width=width, record=True, file=open(os.devnull, "w"))  # noqa: SIM115 - closed with the console
    monkeypatch.setattr(progress, "console", screen)
    progress.print_summary(run)
    lines = screen.export_text().splitlines()
    assert all(len(line.rstrip()) <= width for line in lines)
    table = "\n".join(lines)
    assert "…" not in table  # nothing cut
    assert "no_path 2," in table and "collision 1" in table  # most first, wrapped between reasons
    kept, left_out = progress.fitting_columns(COLUMNS, rows(run), width)
    assert [key for key, _, _ in kept] == [key for key, _ in COLUMNS[: len(kept)]]  # dropped from the last
    for row in rows(run):  # every cell of a column shown is there whole
        for key, _, _ in kept:
            if key != "failures":
                assert f" {row[key]} " in table, (key, row[key])
    if left_out:
        assert f"not shown at {width} columns: " + ", ".join(t for _, t in left_out) in " ".join(table.split())
    assert width == 120 or len(left_out) >= 1
