"""The scaling sweep: growth exponents fitted from run folders whose figures grow by known powers of
the environment size, and the sweep's bookkeeping (one generated building per size, written once;
a finished size kept, an interrupted one resumed)."""

from __future__ import annotations

import csv
import io
import math
import shutil

import numpy as np
import pytest
import yaml
from crafted_run import write_crafted_run

from reports.plots import grid_layer
from reports.report import make_report
from reports.results import Run
from reports.sweep import fit_exponent, scaling_csv, scaling_data, wall_precision, write_drift, write_scaling
from runners.sweep import DriftOptions, ScalingOptions, run_drift, run_scaling
from scenarios.lattice import lattice_building, lattice_shape

SIZES = [150.0, 300.0, 600.0, 1200.0]


@pytest.fixture
def sized_runs(tmp_path):
    """Memory grows linearly with the corridor length, planning time with its square root."""
    return [
        write_crafted_run(
            tmp_path / f"{int(size)}m",
            scenario=f"scaling_{int(size)}m",
            corridor_length_m=size,
            memory_scale=size / 150.0,
            planning_scale=math.sqrt(size / 150.0),
        )
        for size in SIZES
    ]


def test_fit_exponent_recovers_a_power_law_and_needs_two_sizes():
    fit = fit_exponent([100.0, 200.0, 400.0], [3.0 * 100**1.5, 3.0 * 200**1.5, 3.0 * 400**1.5])
    assert fit.exponent == pytest.approx(1.5) and fit.coefficient == pytest.approx(3.0) and fit.points == 3
    assert fit_exponent([100.0, 100.0], [1.0, 2.0]) is None
    assert fit_exponent([100.0, 200.0], [None, 0.0]) is None  # no positive values, no fit


def test_the_scaling_study_fits_the_growth_the_runs_were_written_with(sized_runs):
    runs = [Run.load(r) for r in sized_runs]
    data = scaling_data(runs)
    for system in ("navtopo", "metric_grid"):
        assert [x for x, _ in data.points[system]["total"]] == SIZES
        for series in ("total", "map", "localization", "derived", "rss", "disk"):
            assert data.fit(system, series).exponent == pytest.approx(1.0, abs=1e-6), series
        for series in ("planning_ms", "first_plan_ms"):
            assert data.fit(system, series).exponent == pytest.approx(0.5, abs=1e-6), series
    assert data.fit("metric_grid", "model") is None  # zero bytes at every size: nothing to fit
    assert data.fit("navtopo", "model").exponent == pytest.approx(1.0)
    # navtopo's planning median at 150 m is 10.5 ms (tests/test_reports.py); c = 10.5 / 150^0.5
    assert data.fit("navtopo", "planning_ms").coefficient == pytest.approx(10.5 / math.sqrt(150.0))
    rows = {(r["system"], r["series"]): r for r in csv.DictReader(io.StringIO(scaling_csv(runs)))}
    assert float(rows[("navtopo", "total")]["600m"]) == 12_000_000 and float(rows[("navtopo", "total")]["exponent"]) == 1.0


@pytest.mark.long
def test_a_sweep_report_shows_the_study_first(sized_runs, tmp_path):
    made = make_report(sized_runs, tmp_path / "report", study=write_scaling, study_title="Scaling")
    out = tmp_path / "report"
    assert (out / "plots" / "scaling.png").is_file() and (out / "plots" / "scaling.svg").is_file()
    text = (out / "scaling.md").read_text()
    assert "| navtopo | 0.50 | 0.50 | 1.00 | 1.00 | 1.00 | 1.00 | 1.00 | 1.00 | 1.00 |" in text
    page = made.html.read_text()
    assert page.index("<h2>Scaling</h2>") < page.index('id="scaling"') < page.index('id="table1"')


def test_run_scaling_writes_each_building_once_and_resumes_an_unfinished_size(tmp_path, monkeypatch):
    import runners.sweep as sweep

    generated = []

    def fake_tree(length, **kwargs):
        from scenarios.generators import scenario_dict

        generated.append(length)
        corridor = {"points": [[0.0, 0.0], [length, 0.0]], "width": 2.0}
        return scenario_dict(kwargs["name"], "a corridor", kwargs["seed"], [corridor], [], [], length, kwargs["trials"], 1.0)

    loaded = []
    monkeypatch.setitem(sweep.GENERATORS, "lattice", fake_tree)
    monkeypatch.setattr(sweep, "load_scenario", lambda path: loaded.append(path) or path)
    calls = []

    def fake_run_all(todo):
        for scenario, options in todo:
            calls.append((scenario.name, options.out, options.resume, options.trials, options.systems))
            folder = options.out or options.resume
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "manifest.json").write_text("{}")
            if folder.name != "60m":  # the 60 m run is interrupted: no summary
                (folder / "summary.json").write_text("{}")

    options = ScalingOptions(lengths=[30.0, 60.0], trials=2, out=tmp_path / "sweep")
    folders = run_scaling(options, fake_run_all)
    assert folders == [tmp_path / "sweep" / "30m", tmp_path / "sweep" / "60m"]
    assert generated == [30.0, 60.0]
    written = yaml.safe_load((tmp_path / "sweep" / "scenarios" / "scaling_lattice_30m.yaml").read_text())
    assert written["name"] == "scaling_lattice_30m" and written["world"]["corridors"][0]["points"][1] == [30.0, 0.0]
    assert calls[0] == ("scaling_lattice_30m.yaml", tmp_path / "sweep" / "30m", None, 2, ["navtopo", "metric_grid"])
    # again: 30 m is finished and kept, 60 m resumed; no building generated twice
    calls.clear()
    run_scaling(options, fake_run_all)
    assert generated == [30.0, 60.0]
    assert calls == [("scaling_lattice_60m.yaml", None, tmp_path / "sweep" / "60m", 2, ["navtopo", "metric_grid"])]


# --- drift ------------------------------------------------------------------------------------


def test_wall_precision_counts_the_map_walls_near_a_gt_wall(tmp_path):
    run = write_crafted_run(tmp_path / "run")
    # the grid's one wall cell lands at (0.05, 0.45), 0.1 m from the corridor's end wall; of the
    # graph's two, (0.95, 1.55) is inside a wall and (3.05, -0.45) 0.3 m from the obstacle: 1 of 2
    assert wall_precision(Run.load(run), "metric_grid") == 1.0
    assert wall_precision(Run.load(run), "navtopo") == 0.5
    # a drifted grid: the same cell 1.95 m further along the map frame's -y lands mid-corridor at (2.0, 0.0)
    meta = yaml.safe_load((run / "maps" / "metric_grid" / "map.yaml").read_text())
    meta["origin"] = [-0.95, -2.45, 0.0]
    (run / "maps" / "metric_grid" / "map.yaml").write_text(yaml.safe_dump(meta))
    drifted = Run.load(run)
    layer = grid_layer(drifted, "metric_grid")
    assert layer.centres(layer.occupied) == pytest.approx(np.array([[2.0, 0.0]]))
    assert wall_precision(drifted, "metric_grid") == 0.0
    shutil.rmtree(run / "ground_truth")
    assert wall_precision(Run.load(run), "metric_grid") is None


@pytest.mark.long
def test_the_drift_study_reports_each_level_and_draws_figure_1(tmp_path):
    folders = [write_crafted_run(tmp_path / level, setting=level) for level in ("precise", "noisy", "strong")]
    meta = yaml.safe_load((folders[2] / "maps" / "metric_grid" / "map.yaml").read_text())
    meta["origin"] = [-0.95, -2.45, 0.0]  # the strong run's grid drifted
    (folders[2] / "maps" / "metric_grid" / "map.yaml").write_text(yaml.safe_dump(meta))
    made = make_report(folders, tmp_path / "report", study=write_drift, study_title="Drift")
    text = (tmp_path / "report" / "drift.md").read_text()
    assert "| precise | metric_grid | 6 | 0.67 | 0.950 | 1.000 | – |" in text
    assert "| strong | metric_grid | 6 | 0.67 | 0.950 | 0.000 | – |" in text
    assert "| noisy | navtopo | 6 | 0.83 | 0.800 | 0.500 | – |" in text
    rows = list(csv.DictReader(io.StringIO((tmp_path / "report" / "drift.csv").read_text())))
    assert [(r["level"], r["system"]) for r in rows][:3] == [
        ("precise", "navtopo"),
        ("precise", "metric_grid"),
        ("noisy", "navtopo"),
    ]
    assert {p.name: p.note for p in made.study} == {"drift": "", "figure1": ""}
    for name in ("drift", "figure1"):
        assert (tmp_path / "report" / "plots" / f"{name}.png").is_file() and (
            tmp_path / "report" / "plots" / f"{name}.svg"
        ).is_file()


def test_run_drift_runs_the_scenario_once_per_level_with_that_setting(tmp_path, monkeypatch):
    from types import SimpleNamespace

    import runners.sweep as sweep

    loaded = []
    monkeypatch.setattr(sweep, "load_scenario", lambda name: loaded.append(name) or SimpleNamespace(name=name, trials=[{}] * 5))
    calls = []

    def fake_run_all(todo):
        for scenario, options in todo:
            calls.append((scenario.name, options.setting, options.out, options.resume))
            folder = options.out or options.resume
            folder.mkdir(parents=True, exist_ok=True)
            (folder / "manifest.json").write_text("{}")
            if options.setting != "strong":
                (folder / "summary.json").write_text("{}")

    options = DriftOptions(scenario="tiny", out=tmp_path / "drift")
    assert run_drift(options, fake_run_all) == [tmp_path / "drift" / level for level in ("precise", "noisy", "strong")]
    assert loaded == ["tiny"] and [c[1] for c in calls] == ["precise", "noisy", "strong"]
    calls.clear()
    run_drift(options, fake_run_all)
    assert calls == [("tiny", "strong", None, tmp_path / "drift" / "strong")]


# --- the scaling sweep's buildings ------------------------------------------------------------


@pytest.mark.parametrize("length", [150.0, 300.0, 600.0, 1200.0, 2400.0])
def test_a_lattice_totals_the_length_with_blocks_of_a_building(length):
    nx, ny, block = lattice_shape(length)
    assert ((ny + 1) * nx + (nx + 1) * ny) * block == pytest.approx(length)
    assert 12.0 <= block <= 26.0 and nx >= ny >= 1


def test_a_lattice_building_has_one_loop_per_block_and_loads(tmp_path):
    from shapely.ops import unary_union

    from scenarios import load_scenario
    from scenarios.world import corridor_polygon

    spec = lattice_building(150.0, seed=31, trials=3, name="lattice_test")
    corridors = unary_union([corridor_polygon(c["points"], c["width"]) for c in spec["world"]["corridors"]])
    nx, ny, _ = lattice_shape(150.0)
    assert len(corridors.interiors) == nx * ny  # a ring of corridor round every block
    path = tmp_path / "lattice.yaml"
    path.write_text(yaml.safe_dump(spec))
    scenario = load_scenario(path)
    assert scenario.summary()["corridor_length_m"] == pytest.approx(150.0)
    assert len(scenario.trials) == 3 and spec["world"]["rooms"] and spec["world"]["obstacles"]
