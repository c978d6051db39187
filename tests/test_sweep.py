"""The scaling sweep: growth exponents fitted from run folders whose figures grow by known powers of
the environment size, and the sweep's bookkeeping (one generated building per size, written once;
a finished size kept, an interrupted one resumed)."""

from __future__ import annotations

import csv
import io
import math

import pytest
import yaml
from crafted_run import write_crafted_run

from reports.report import make_report
from reports.results import Run
from reports.sweep import fit_exponent, scaling_csv, scaling_data, write_scaling
from runners.sweep import ScalingOptions, run_scaling

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
        generated.append(length)
        return {"name": kwargs["name"], "length": length}

    loaded = []
    monkeypatch.setattr(sweep, "corridor_tree", fake_tree)
    monkeypatch.setattr(sweep, "load_scenario", lambda path: loaded.append(path) or path)
    calls = []

    def fake_run(scenario, options):
        calls.append((scenario.name, options.out, options.resume, options.trials, options.systems))
        folder = options.out or options.resume
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "manifest.json").write_text("{}")
        if folder.name != "60m":  # the 60 m run is interrupted: no summary
            (folder / "summary.json").write_text("{}")
        return sweep.RunDir(folder)

    options = ScalingOptions(lengths=[30.0, 60.0], trials=2, out=tmp_path / "sweep")
    folders = run_scaling(options, fake_run)
    assert folders == [tmp_path / "sweep" / "30m", tmp_path / "sweep" / "60m"]
    assert generated == [30.0, 60.0]
    written = yaml.safe_load((tmp_path / "sweep" / "scenarios" / "scaling_30m.yaml").read_text())
    assert written == {"name": "scaling_30m", "length": 30.0}
    assert calls[0] == ("scaling_30m.yaml", tmp_path / "sweep" / "30m", None, 2, ["navtopo", "metric_grid"])
    # again: 30 m is finished and kept, 60 m resumed; no building generated twice
    calls.clear()
    run_scaling(options, fake_run)
    assert generated == [30.0, 60.0]
    assert calls == [("scaling_60m.yaml", None, tmp_path / "sweep" / "60m", 2, ["navtopo", "metric_grid"])]
