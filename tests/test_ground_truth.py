"""A run's ground_truth/ folder holds what reports draw against, read back through the reports'
own container (reports/results.py) and checked against the scenario it came from."""

from __future__ import annotations

import math

import numpy as np
import pytest

from reports.results import Run
from runners.ground_truth import FILES, write_ground_truth
from scenarios import load_scenario


@pytest.fixture(scope="module")
def tiny():
    return load_scenario("tiny")


def test_ground_truth_read_back_matches_the_scenario(tiny, tmp_path):
    folder = write_ground_truth(tiny, tmp_path, trial_count=2)
    missing: list[str] = []
    gt = Run._load_ground_truth(folder, missing)
    assert missing == [] and gt is not None
    # the raster, upright in image order: free cells are the navigation world's free cells
    assert gt.image.shape == tiny.world.free.shape
    assert np.array_equal(gt.mask("free")[::-1], tiny.navigation_world.free)
    assert np.array_equal(gt.mask("wall", "obstacle")[::-1], ~tiny.world.free)
    x0, x1, y0, y1 = gt.extent
    assert (x0, y0) == pytest.approx(tuple(tiny.world.origin[:2]))
    # a trial's start, looked up through the extent as a plot does, is on a free cell
    for trial in tiny.trials[:2]:
        col = int((trial.start[0] - x0) / gt.raster.resolution)
        row = gt.image.shape[0] - 1 - int((trial.start[1] - y0) / gt.raster.resolution)
        assert gt.mask("free")[row, col]
    assert gt.raster.map_frame == pytest.approx(list(tiny.route_start), abs=1e-6)
    # the trials run (2 of 3), each with its GT shortest path from start to goal
    assert sorted(gt.trials) == [0, 1]
    for index, trial in gt.trials.items():
        path = np.asarray(trial.shortest_path)
        assert path[0] == pytest.approx(tiny.trials[index].start[:2], abs=1e-3)
        assert path[-1] == pytest.approx(tiny.trials[index].goal[:2], abs=1e-3)
        assert np.linalg.norm(np.diff(path, axis=0), axis=1).sum() == pytest.approx(trial.shortest_m, rel=1e-3)
        assert trial.start[2] == pytest.approx(math.degrees(tiny.trials[index].start[2]))
    route = np.asarray(gt.route.polyline)
    assert np.linalg.norm(np.diff(route, axis=0), axis=1).sum() == pytest.approx(gt.route.length_m, rel=1e-3)


def test_a_folder_that_holds_the_ground_truth_is_left_alone(tiny, tmp_path):
    folder = write_ground_truth(tiny, tmp_path)
    before = {name: (folder / name).stat().st_mtime_ns for name in FILES}
    (folder / "trials.json").write_text((folder / "trials.json").read_text())  # touched by someone
    touched = (folder / "trials.json").stat().st_mtime_ns
    write_ground_truth(tiny, tmp_path)
    after = {name: (folder / name).stat().st_mtime_ns for name in FILES}
    assert after == {**before, "trials.json": touched}
