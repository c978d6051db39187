"""Reports read results folders only: the typed container, the intervals, Table 1 against figures
computed on paper from a hand-written folder (tests/crafted_run.py), and the plots' placement of
saved maps against the ground truth."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from crafted_run import write_crafted_run

from reports import stats
from reports.results import Run, RunFormatError


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
