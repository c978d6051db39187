"""Reports read results folders only: the typed container, the intervals, Table 1 against figures
computed on paper from a hand-written folder (tests/crafted_run.py), and the plots' placement of
saved maps against the ground truth."""

from __future__ import annotations

import csv
import io
import json
import math
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from crafted_run import write_crafted_run

from reports import stats
from reports.plots import graph_layout, grid_layer, run_plots
from reports.report import make_report, repeated_note, reproduce_command
from reports.results import Run, RunFormatError
from reports.tables import cells, latex, markdown_document, table_rows, to_csv

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def crafted(tmp_path):
    return write_crafted_run(tmp_path / "run")


# --- the typed container ---------------------------------------------------------------------


def test_run_load_reads_every_file_of_the_contract(crafted):
    run = Run.load(crafted)
    assert run.systems == ["navtopo", "metric_grid"] and run.seed == 7 and run.setting == "precise"
    assert run.missing == []
    # the first record of a (system, trial) counts, a torn last line is skipped
    assert len(run.trials) == 12
    assert run.trials_of("navtopo")[0].success is True
    assert run.summary["navtopo"].memory.total == 3_000_000
    assert run.mapping["navtopo"].anchors[1] == [2.0, 3.0, 0.5, 0.0]
    assert run.map_kind("navtopo") == "graph" and run.map_kind("metric_grid") == "grid"
    gt = run.ground_truth
    assert gt is not None and gt.image.shape == (40, 60) and gt.extent == (-1.0, 5.0, -2.0, 2.0)
    assert gt.trials[3].shortest_m == 5.0
    # the raster reads upright: the obstacle written at image rows 18..21, cols 40..41 lies at
    # x in [3.0, 3.2], y in [-0.2, 0.2]
    rows, cols = np.nonzero(gt.mask("obstacle"))
    assert (cols.min(), cols.max(), rows.min(), rows.max()) == (40, 41, 18, 21)
    path = run.trajectory("navtopo", 2)
    assert path.shape == (7, 4) and path[0, 1:3] == pytest.approx([0.5, 0.2])


def test_a_run_without_ground_truth_loads_and_says_what_is_missing(crafted):
    shutil.rmtree(crafted / "ground_truth")
    (crafted / "navigation" / "metric_grid.json").unlink()
    run = Run.load(crafted)
    assert run.ground_truth is None and run.navigation["metric_grid"] is None
    assert set(run.missing) == {"ground_truth/", "navigation/metric_grid.json"}


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda root: (root / "summary.json").write_text("{not json"), "summary.json: not readable JSON"),
        (lambda root: (root / "summary.json").unlink(), "not a finished run folder (summary.json missing)"),
        (lambda root: (root / "manifest.json").unlink(), "not a run folder (manifest.json missing)"),
        (lambda root: (root / "summary.json").write_text("[1, 2]"), "summary.json: expected an object keyed by system"),
        (
            lambda root: (root / "summary.json").write_text('{"navtopo": {"success_rate": "high"}}'),
            "summary.json: navtopo: success_rate: Input should be a valid number",
        ),
        (
            lambda root: (root / "trials.jsonl").write_text('{"system": "navtopo"}\nbroken\n{"x": 1}\n'),
            "trials.jsonl: line 2: not JSON",
        ),
        (
            lambda root: (root / "ground_truth" / "trials.json").write_text("[]"),
            "ground_truth/trials.json: expected an object with a list of trials",
        ),
        (lambda root: (root / "ground_truth" / "raster.png").write_bytes(b"not a png"), "raster.png: not a readable PNG"),
    ],
)
def test_a_damaged_folder_fails_with_one_line_naming_the_file(crafted, damage, message):
    damage(crafted)
    with pytest.raises(RunFormatError) as caught:
        Run.load(crafted)
    text = str(caught.value)
    assert message in text and "\n" not in text


# --- bootstrap intervals ---------------------------------------------------------------------


def test_bootstrap_is_seeded_needs_five_values_and_brackets_the_statistic():
    values = [0.9, 0.8, 0.7, 1.0, 0.6]
    low, high = stats.bootstrap(values)
    assert low <= 0.8 <= high and 0.6 <= low and high <= 1.0
    assert stats.bootstrap(values) == (low, high)  # the same every time
    assert stats.bootstrap(values[:4]) is None
    assert stats.bootstrap([0.95] * 6) == pytest.approx((0.95, 0.95))
    assert stats.bootstrap([1.0, 2.0, 3.0, 4.0, 100.0], "median")[1] <= 100.0
    # whole trials are resampled: five trials of identical calls give a point interval
    assert stats.bootstrap_pooled([[100.0, 300.0]] * 5, 50.0) == pytest.approx((200.0, 200.0))
    assert stats.bootstrap_pooled([[1.0]] * 4) is None


@pytest.mark.parametrize("quantile", [50.0, 95.0, 3.0])
def test_a_pooled_quantile_is_np_percentile_of_each_resample_concatenated(quantile):
    rng = np.random.default_rng(3)
    groups = [np.round(rng.gamma(2.0, 3.0, size=rng.integers(0, 60)), 1) for _ in range(9)]  # ties, an empty one
    kept = [g for g in groups if len(g)]
    draws = np.random.default_rng(stats.SEED).integers(0, len(kept), size=(stats.RESAMPLES, len(kept)))
    each = [np.percentile(np.concatenate([kept[i] for i in pick]), quantile) for pick in draws]
    assert stats.bootstrap_pooled(groups, quantile) == stats._interval(np.asarray(each))


# --- Table 1 against figures computed on paper ---------------------------------------------


def test_table_rows_match_the_figures_computed_by_hand(crafted):
    rows = table_rows([Run.load(crafted)])
    topo, metric, *paper = rows
    assert [r.system for r in rows[:2]] == ["navtopo", "metric_grid"] and all(r.paper for r in paper)
    # navtopo: 5 of 6 succeed; efficiency over successes (0.9+0.8+0.7+1.0+0.6)/5; SPL over all /6
    assert (topo.trials, topo.successes, topo.failure_reasons) == (6, 5, {"timeout": 1})
    assert topo.efficiency == pytest.approx(0.8) and topo.spl == pytest.approx(4.0 / 6)
    # first plans 4, 6, 8, 2, 10, 12: median 7, p95 10 + 0.75 * 2 (linear interpolation)
    assert topo.first_plan_ms_median == pytest.approx(7.0) and topo.first_plan_ms_p95 == pytest.approx(11.5)
    # every call: 1..20 ms over the six trials: median 10.5, p95 1 + 0.95 * 19
    assert topo.planning_calls == 20
    assert topo.planning_ms_median == pytest.approx(10.5) and topo.planning_ms_p95 == pytest.approx(19.05)
    assert topo.memory == {"map": 1_000_000, "localization": 500_000, "derived": 250_000, "model": 1_250_000, "total": 3_000_000}
    assert (topo.disk_bytes, topo.rss_bytes, topo.rss_process_bytes) == (800_000, 40_000_000, 400_000_000)
    assert (topo.mapping_ms_per_scan_median, topo.mapping_ms_per_scan_p95) == (25.0, 40.0)
    assert topo.efficiency_ci is not None and topo.efficiency_ci[0] <= 0.8 <= topo.efficiency_ci[1]
    # the metric baseline: 4 of 6, both failures collisions; efficiency over 4 successes: no interval
    assert (metric.successes, metric.failure_reasons) == (4, {"collision": 2})
    assert metric.efficiency == pytest.approx(0.95) and metric.efficiency_ci is None
    assert metric.spl_ci is not None and metric.spl_ci[0] <= metric.spl <= metric.spl_ci[1]
    assert (metric.planning_ms_median, metric.planning_ms_p95, metric.first_plan_ms_median) == (200.0, 300.0, 500.0)

    shown = cells(topo)
    assert shown["success"].startswith("5/6 (83 %) [")
    assert shown["failures"] == "timeout 1"
    assert shown["memory"] == "3.00 (1.00 / 0.50 / 0.25 / 1.25)"
    assert shown["rss"] == "40.00 / 400" and shown["disk"] == "0.80" and shown["mapping"] == "25.0 / 40.0"
    assert shown["planning"].startswith("10.5 [") and shown["planning"].endswith("/ 19.1")
    assert cells(metric)["efficiency"] == "0.950"
    # identical trials give a point interval: every call 100 or 300 ms, median 200
    assert cells(metric)["planning"] == "200 [200, 200] / 300"


def test_markdown_csv_and_latex_carry_the_same_figures(crafted):
    rows = table_rows([Run.load(crafted)])
    text = markdown_document(rows)
    lines = [line for line in text.splitlines() if line.startswith("| ")]
    assert len(lines) == 1 + 2 + 2  # header, two measured rows, the paper's two
    assert "| crafted | precise | navtopo | 5/6 (83 %)" in text and "*the paper*" in text
    table = list(csv.DictReader(io.StringIO(to_csv(rows))))
    topo = table[0]
    assert (topo["system"], topo["source"], topo["trials"], topo["failure_reasons"]) == ("navtopo", "measured", "6", "timeout:1")
    assert float(topo["planning_ms_p95"]) == pytest.approx(19.05) and float(topo["memory_total_mb"]) == 3.0
    assert float(topo["memory_model_mb"]) == 1.25 and float(topo["efficiency"]) == pytest.approx(0.8)
    assert float(topo["efficiency_ci_low"]) <= 0.8 <= float(topo["efficiency_ci_high"])
    assert table[2]["source"] == "paper" and float(table[2]["memory_total_mb"]) == 57.0
    tex = latex(rows)
    assert tex.count(r"\\") >= 5 and r"metric\_grid" in tex and r"\begin{tabular}" in tex and r"\bottomrule" in tex
    assert "%" not in tex.replace(r"\%", "")  # every percent sign escaped


def test_runs_of_one_scenario_and_setting_pool_their_trials(tmp_path):
    a = Run.load(write_crafted_run(tmp_path / "a", seed=7))
    b = Run.load(write_crafted_run(tmp_path / "b", seed=8, memory_scale=2.0))
    other = Run.load(write_crafted_run(tmp_path / "c", seed=7, scenario="other"))
    rows = [r for r in table_rows([a, b, other]) if not r.paper]
    assert [(r.scenario, r.system, r.pooled) for r in rows] == [
        ("crafted", "navtopo", False),
        ("crafted", "metric_grid", False),
        ("other", "navtopo", False),
        ("other", "metric_grid", False),
        ("all 2 scenes", "navtopo", True),
        ("all 2 scenes", "metric_grid", True),
    ]
    topo = rows[0]
    assert topo.seeds == [7, 8] and (topo.trials, topo.successes, topo.planning_calls) == (12, 10, 40)
    assert topo.memory["total"] == 6_000_000  # the larger of the two runs
    assert topo.planning_ms_median == pytest.approx(10.5)


# --- plots: saved maps placed against the ground truth ---------------------------------------


def test_a_graph_is_placed_at_the_true_poses_and_its_walls_where_the_grids_hold_them(crafted):
    run = Run.load(crafted)
    layout = graph_layout(run, "navtopo")
    assert layout.placed_by == "anchor" and layout.edges == [(0, 1)]
    assert layout.poses == pytest.approx(np.array([[1.0, 0.5, math.pi / 2], [3.0, 0.5, 0.0]]))
    # worked out in tests/crafted_run.py (_write_graph)
    assert layout.walls[0] == pytest.approx(np.array([[0.95, 1.55]]))
    assert layout.walls[1] == pytest.approx(np.array([[3.05, -0.45]]))
    # without anchors the odometry hints composed with the map frame give the same places (precise run)
    mapping = json.loads((crafted / "mapping" / "navtopo.json").read_text())
    del mapping["anchors"]
    (crafted / "mapping" / "navtopo.json").write_text(json.dumps(mapping))
    by_hint = graph_layout(Run.load(crafted), "navtopo")
    assert by_hint.placed_by == "hint"
    assert by_hint.poses == pytest.approx(layout.poses)
    assert by_hint.walls[0] == pytest.approx(layout.walls[0])


def test_a_grid_map_is_placed_by_the_map_frame(crafted):
    layer = grid_layer(Run.load(crafted), "metric_grid")
    assert layer.centres(layer.occupied) == pytest.approx(np.array([[0.05, 0.45]]))
    assert layer.free.sum() == 99
    # the grid's lower-left cell (row 0: the lowest y): (-0.45, -0.45) in the map frame -> (0.5 + 0.45, -0.45)
    corner = np.zeros_like(layer.free)
    corner[0, 0] = True
    assert layer.centres(corner) == pytest.approx(np.array([[0.95, -0.45]]))


def test_run_plots_writes_png_and_svg_of_every_plot(crafted, tmp_path):
    results = run_plots(Run.load(crafted), tmp_path / "plots")
    names = [p.name for p in results]
    assert names == [
        "map_navtopo",
        "map_metric_grid",
        "trajectories_navtopo",
        "trajectories_metric_grid",
        "planning",
        "efficiency",
        "map_growth",
    ]
    for plot in results:
        assert plot.note == "" and [f.suffix for f in plot.files] == [".png", ".svg"], plot
        assert all(f.stat().st_size > 1000 for f in plot.files)


def test_plots_that_need_the_ground_truth_are_skipped_with_a_note_when_it_is_missing(crafted, tmp_path):
    shutil.rmtree(crafted / "ground_truth")
    results = {p.name: p for p in run_plots(Run.load(crafted), tmp_path / "plots")}
    assert results["map_metric_grid"].files == [] and "ground_truth/raster.yaml" in results["map_metric_grid"].note
    assert results["map_navtopo"].files and "no ground_truth/" in results["map_navtopo"].note  # placed by anchors
    assert results["planning"].files and results["efficiency"].files


# --- the report: files, the page, copies, several runs, bad input ----------------------------


def _files(folder):
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_the_report_writes_tables_plots_config_and_a_self_contained_page(crafted):
    made = make_report([crafted])
    out = crafted / "report"
    assert made.out == out and made.notes == [repeated_note(Run.load(crafted))]  # a trial written twice
    written = set(_files(out))
    assert {"table.md", "table.csv", "table.tex", "config.yaml", "report.html"} <= written
    for name in ("map_navtopo", "map_metric_grid", "trajectories_navtopo", "planning", "efficiency", "map_growth"):
        assert {f"plots/{name}.png", f"plots/{name}.svg"} <= written
    assert yaml.safe_load((out / "config.yaml").read_text()) == json.loads((crafted / "manifest.json").read_text())["config"]
    page = made.html.read_text()
    # seven plots and a crop of each of the three failed trials
    assert page.count('<img src="data:image/png;base64,') == len([f for f in written if f.endswith(".png")]) == 10
    assert '<table class="results" id="table1">' in page and "<td>5/6 (83 %) [" in page
    # what an RTAB-MAP-style system would keep of the mapping run: a note of its own, not a memory figure
    table = (out / "table.md").read_text()
    assert "an RTAB-MAP-style map of the same mapping run: 2.65 MB, its 11 keyframes' raw lidar clouds (2.40 MB" in table
    # nothing is loaded from anywhere: no external src or href, a policy that forbids it, no script
    assert not re.search(r'(src|href)="(?!data:)', page) and "<script" not in page
    assert "default-src 'none'" in page
    # the manifest and the command that reproduces the run; no path of this machine's folder
    assert (
        "navtopo-bench run crafted --systems navtopo,metric_grid --seed 7 --trials 6 --setting precise "
        "--initial-pose-error 0.5,10 --stop-tolerance 0.35 --config config.yaml"
    ) in page
    assert "0123456789abcdef" in page and "crafted" in page
    assert str(crafted) not in page


def test_a_report_made_from_a_copied_folder_is_the_same_file_for_file(crafted, tmp_path):
    make_report([crafted])
    copy = tmp_path / "elsewhere" / "copied-run"
    shutil.copytree(crafted, copy, ignore=shutil.ignore_patterns("report"))
    make_report([copy])
    original, copied = _files(crafted / "report"), _files(copy / "report")
    assert set(original) == set(copied)
    differing = [name for name in original if original[name] != copied[name]]
    assert differing == []


def test_every_failed_trial_has_a_row_and_a_crop_of_where_it_ended(crafted):
    """The crafted run's failures: NavTopo's trial 2 (timeout) and the baseline's trials 1 and 3
    (collisions), each a row saying which other system failed it, and a crop over the ground truth
    and the system's own map."""
    from reports.failures import crop_bounds, failure_rows, tail

    run = Run.load(crafted)
    rows = failure_rows(run)
    assert [(r.system, r.trial, r.reason) for r in rows] == [
        ("navtopo", 2, "timeout"),
        ("metric_grid", 1, "collision"),
        ("metric_grid", 3, "collision"),
    ]
    assert all(r.also_failed == [] for r in rows) and [r.succeeded for r in rows] == [["metric_grid"], ["navtopo"], ["navtopo"]]
    assert rows[0].left_m == 0.2 and rows[0].travelled_m == pytest.approx(8.0) and rows[0].sim_time_s == 10.0
    made = make_report([crafted])
    table = (made.out / "table.md").read_text()
    assert "## Failed trials" in table
    assert "| navtopo | 2 | timeout | – | 0.20 | 8.0 | 10.0 | metric_grid ok | – |" in table
    assert "| metric_grid | 3 | collision | – | 0.20 | 10.0 | 10.0 | navtopo ok | – |" in table
    page = made.html.read_text()
    assert "<h3>Failed trials</h3>" in page and page.count('<tr id="failure_') == 3
    section = made.sections[0]
    assert [p.name for p in section.failures] == ["failure_navtopo_2", "failure_metric_grid_1", "failure_metric_grid_3"]
    assert all(p.png is not None and p.png.parent.name == "failures" for p in section.failures)
    # the crop: the last 15 m of a 40 m straight run, a square round its end holding them
    path = np.stack([np.linspace(0.0, 40.0, 401), np.zeros(401)], axis=1)
    last = tail(path, 15.0)
    assert last[0, 0] == pytest.approx(25.0) and last[-1, 0] == 40.0
    assert crop_bounds(last, path[-1]) == pytest.approx((24.0, 56.0, -16.0, 16.0))


def test_a_reader_of_the_page_alone_can_say_where_and_in_which_stage_each_trial_failed(tmp_path):
    """Failures of every reason a trial can end with, each with its stage and the system's one line:
    the page has a row for each, saying the stage, the detail, how far from the goal it ended and
    whether the other system failed the same trial."""
    from runners.metrics import REASON_STAGES

    run = write_crafted_run(tmp_path / "run")
    path = run / "trials.jsonl"
    records = [json.loads(line) for line in path.read_text().splitlines()[:-1]]  # the torn line dropped
    reasons = sorted(REASON_STAGES)  # every reason with a stage: not_localized, no_path, ..., out_of_memory
    rewritten = []
    for k, reason in enumerate(reasons):
        for system in ("navtopo", "metric_grid"):
            record = dict(next(r for r in records if r["system"] == system), trial=k, success=False, reason=reason)
            stage, detail = str(REASON_STAGES[reason]), f"{system} says why, {reason}"
            record.update(failure_stage=stage, detail=detail, final_distance_m=1.0 + k)
            if system == "metric_grid" and k % 2:  # the other system reached the goal of every other trial
                record.update(success=True, reason="", failure_stage=None, detail=None, final_distance_m=0.1)
            rewritten.append(record)
    path.write_text("".join(json.dumps(r) + "\n" for r in rewritten))
    page = make_report([run]).html.read_text()
    rows = re.findall(r'<tr id="failure_(\w+?)_(\d+)">(.*?)</tr>', page)
    assert len(rows) == len(reasons) + (len(reasons) + 1) // 2
    for system, trial, cells_html in rows:
        reason = reasons[int(trial)]
        cells = re.findall(r"<td>(.*?)</td>", cells_html)
        assert cells[:5] == [system, trial, reason, str(REASON_STAGES[reason]), f"{1.0 + int(trial):.2f}"]
        other = "metric_grid" if system == "navtopo" else "navtopo"
        assert cells[7] == (f"{other} ok" if int(trial) % 2 else f"{other} failed")
        assert cells[8] == f"{system} says why, {reason}"


def test_the_efficiency_is_judged_on_the_trials_both_systems_ran_paired(crafted):
    """Each system's mean efficiency covers its own successes (5 vs 4 trials here); the note judges
    the order by the per-trial SPL difference on the trials both ran, and says "differs from the
    paper" only where its interval excludes the paper's order (the metric baseline ahead)."""
    from reports.tables import Paired, _paired_text, paired

    p = paired([Run.load(crafted)], "crafted", "precise")
    assert p is not None and (p.trials, p.both, p.topo_only, p.metric_only, p.neither) == (6, 3, 2, 1, 0)
    # SPL per trial: NavTopo 0.9, 0.8, 0, 0.7, 1.0, 0.6; the baseline 0.95, 0, 0.95, 0, 0.95, 0.95
    assert p.spl_difference == pytest.approx(0.2 / 6)
    assert p.spl_difference_ci is not None and p.spl_difference_ci[0] < 0.0 < p.spl_difference_ci[1]
    table = (make_report([crafted]).out / "table.md").read_text()
    assert "Paired over the 6 trials both ran: both reached 3, NavTopo alone 2, the metric baseline alone 1" in table
    assert "does not tell them apart" in table and "Differs from the paper" not in table
    ahead = Paired(10, 10, 0, 0, 0, 0.2, (0.1, 0.3))
    behind = Paired(10, 10, 0, 0, 0, -0.2, (-0.3, -0.1))
    assert "**Differs from the paper**" in _paired_text(ahead) and "same order as the paper's" in _paired_text(behind)


def test_the_page_says_what_the_setting_is_and_which_odometry_each_system_uses(crafted):
    from reports.html import odometry_sources

    page = make_report([crafted]).html.read_text()
    assert "<dt>setting</dt><dd>precise: exact wheel odometry, no lidar range noise</dd>" in page
    config = {
        "navtopo": {"lidar_hints": True},
        "metric_grid": {"odometry": {"source": "lidar", "seed_with_wheel": True}},
        "oracle": {"follower": {}},
    }
    assert odometry_sources(config) == (
        "navtopo: wheel (lidar odometry for map-frame hints); metric_grid: lidar seeded by the wheels; "
        "oracle: the true pose (the reference)"
    )


def test_a_trial_recorded_twice_is_counted_once_and_flagged(crafted):
    """The crafted run's trials.jsonl holds navtopo trial 0 twice (two drivers on one folder, before
    the folder lock): the first record counts, and the report says which trial was repeated."""
    run = Run.load(crafted)
    assert run.repeated == [("navtopo", 0)]
    counted = [r for r in run.trials if (r.system, r.trial) == ("navtopo", 0)]
    assert len(counted) == 1 and counted[0].success and counted[0].reason != "written twice: the first record counts"
    made = make_report([crafted])
    assert made.notes == [
        f"{crafted / 'trials.jsonl'}: navtopo trial 0 (2 records): the first record of each is counted "
        "(two drivers wrote this folder)"
    ]
    assert "<dt>records repeated</dt><dd>navtopo trial 0</dd>" in made.html.read_text()


def test_several_runs_make_one_combined_report(tmp_path):
    a = write_crafted_run(tmp_path / "a", seed=7)
    b = write_crafted_run(tmp_path / "b", seed=8)
    c = write_crafted_run(tmp_path / "c", seed=7, scenario="other")
    made = make_report([a, b, c], tmp_path / "combined")
    assert [s.key for s in made.sections] == ["crafted-precise-s7", "crafted-precise-s8", "other-precise-s7"]
    written = set(_files(tmp_path / "combined"))
    assert {"plots/planning.png", "plots/efficiency.svg", "config-crafted-precise-s8.yaml"} <= written
    assert {"plots/other-precise-s7/map_navtopo.png", "plots/crafted-precise-s7/trajectories_metric_grid.svg"} <= written
    assert not (a / "report").exists()  # with --out nothing is written into the runs
    rows = list(csv.DictReader(io.StringIO((tmp_path / "combined" / "table.csv").read_text())))
    assert [(r["scenario"], r["system"], r["trials"]) for r in rows if r["source"] == "measured"] == [
        ("crafted", "navtopo", "12"),
        ("crafted", "metric_grid", "12"),
        ("other", "navtopo", "6"),
        ("other", "metric_grid", "6"),
        ("all 2 scenes", "navtopo", "18"),  # pooled: every scene of the setting, each system
        ("all 2 scenes", "metric_grid", "18"),
    ]
    pooled = {r["system"]: r for r in rows if r["scenario"] == "all 2 scenes"}
    assert pooled["navtopo"]["successes"] == "15" and pooled["metric_grid"]["successes"] == "12"
    table = (tmp_path / "combined" / "table.md").read_text()
    assert "all 2 scenes (precise), efficiency" in table and "Paired over the 18 trials both ran" in table
    # efficiency per trial: a panel per scene, trial k of two scenes being unrelated
    from reports.plots import groups_of, plot_efficiency

    runs = [Run.load(p) for p in (a, b, c)]
    assert [g.scene for g in groups_of(runs)] == ["crafted · precise"] * 2 + ["other · precise"] * 2
    plot = plot_efficiency(groups_of(runs), tmp_path / "panels")
    assert plot.caption.endswith("a panel per scene and setting")
    page = made.html.read_text()
    assert page.count("navtopo-bench run ") == 3 and "--seed 8" in page and "--config config-other-precise-s7.yaml" in page


def test_a_scenario_file_outside_the_bundled_ones_is_named_by_its_path(crafted):
    manifest = json.loads((crafted / "manifest.json").read_text())
    manifest["scenario"]["file"] = "my scenes/office.yaml"
    manifest["setting_override"] = None
    manifest["protocol"]["goals"] = "native"
    (crafted / "manifest.json").write_text(json.dumps(manifest))
    command = reproduce_command(Run.load(crafted), "config.yaml")
    assert command.startswith("navtopo-bench run 'my scenes/office.yaml' --systems navtopo,metric_grid --seed 7 --trials 6 ")
    assert "--setting" not in command and "--goals native" in command


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda root: (root / "summary.json").write_text("{not json"), "summary.json: not readable JSON"),
        (lambda root: (root / "manifest.json").write_text('{"systems": []}'), "manifest.json: scenario: Field required"),
    ],
)
def test_the_report_command_fails_on_a_damaged_folder_with_one_line(crafted, damage, message):
    damage(crafted)
    result = subprocess.run(
        [sys.executable, "-m", "runners.cli", "report", str(crafted)], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 2
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0] and str(crafted) in lines[0]
    assert "Traceback" not in result.stderr + result.stdout
    assert not (crafted / "report").exists()


def test_reports_import_nothing_of_the_runners_scenarios_or_systems():
    import ast

    forbidden = {"runners", "scenarios", "navtopo", "baselines"}
    for path in sorted((ROOT / "reports").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            assert not {n.split(".")[0] for n in names} & forbidden, f"{path.name} imports {names}"


def test_plot_graph_draws_a_graph_map_as_png_and_svg(crafted, tmp_path):
    from typer.testing import CliRunner

    from runners.cli import app

    result = CliRunner().invoke(app, ["plot-graph", str(crafted), "-o", str(tmp_path / "graph.png")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "graph.png").stat().st_size > 1000 and (tmp_path / "graph.svg").is_file()
    result = CliRunner().invoke(app, ["plot-graph", str(crafted), "-o", str(tmp_path / "g.png"), "--system", "metric_grid"])
    assert result.exit_code == 2 and "no graph map of metric_grid" in result.output
    # a system the run did not run, and a folder that is not there: each its own line
    result = CliRunner().invoke(app, ["plot-graph", str(crafted), "-o", str(tmp_path / "g.png"), "--system", "foo"])
    assert result.exit_code == 2 and "--system foo: " in result.output and "not foo" in result.output
    result = CliRunner().invoke(app, ["report", str(tmp_path / "nowhere")])
    assert result.exit_code == 2 and f"{tmp_path / 'nowhere'}: no such folder" in result.output


def test_the_readme_section_is_the_runs_own_table_and_plots(crafted, tmp_path):
    """tools/readme_bench.py: the README's bench section is replaced by the run's report table and
    plots, the text round it kept; a README without the markers is refused."""
    readme, images = tmp_path / "README.md", tmp_path / "img"
    images.mkdir()
    readme.write_text("# top\n\n<!-- bench:start -->\nold\n<!-- bench:end -->\n\n## after\n", encoding="utf-8")
    tool = [sys.executable, str(Path(__file__).resolve().parent.parent / "tools" / "readme_bench.py"), str(crafted)]
    done = subprocess.run([*tool, "--readme", str(readme), "--images", str(images)], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    text = readme.read_text(encoding="utf-8")
    assert text.startswith("# top\n\n<!-- bench:start -->") and text.endswith("<!-- bench:end -->\n\n## after\n")
    assert "\nold\n" not in text and "| crafted | precise | navtopo | 5/6 (83 %)" in text
    table = (crafted / "report" / "table.md").read_text(encoding="utf-8")
    assert table.split("\n", 1)[1].strip() in text
    for name in ("trajectories_navtopo", "planning", "map_navtopo"):
        assert f"docs/img/bench_{name}.png" in text
        assert (images / f"bench_{name}.png").read_bytes() == (crafted / "report" / "plots" / f"{name}.png").read_bytes()
    readme.write_text("# no markers\n", encoding="utf-8")
    refused = subprocess.run([*tool, "--readme", str(readme), "--images", str(images)], capture_output=True, text=True)
    assert refused.returncode == 2 and "expected one <!-- bench:start -->" in refused.stderr
