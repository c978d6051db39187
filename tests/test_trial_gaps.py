"""Trials a robot can do: each trial's narrowest gap (scenarios/gaps.py) against known answers, the
margin generated trials keep, listed trials refused below it or run marked narrow, and the keys of
ground_truth/trials.json, trials.jsonl and the report's per-trial table.

The crafted world: two rooms, one above the other, parted by a 0.2 m wall with two doors, at a
0.01 m raster so that one centimetre is one cell. The wide door is exactly as wide as the robot
(radius 0.3 m) plus the default margin (0.1 m) on each side, 0.8 m: its gap is 0.1 m; the narrow
one is a centimetre under, 0.79 m: its gap is 0.095 m.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from crafted_run import write_crafted_run

from reports import trial_table
from reports.records import TrialRecord
from reports.results import Run
from reports.trial_table import gap_notes, markdown, trial_lines
from runners.ground_truth import write_ground_truth
from runners.metrics import trial_record
from scenarios import ScenarioError, load_scenario
from scenarios.gaps import GapGauge, ridge_clearance
from scenarios.schema import GAP_CAP_M, TRIAL_MARGIN_M, WorldSpec
from scenarios.world import build_world

RADIUS = 0.3
WIDE_X, WIDE_W = 1.5, 2 * (RADIUS + TRIAL_MARGIN_M)  # 0.8 m: its edges on cell boundaries
NARROW_X, NARROW_W = 4.505, WIDE_W - 0.01  # 0.79 m: centred half a cell over, so 79 cells exactly
WALL_Y = (3.0, 3.2)


def two_rooms(tmp_path: Path, trials, name: str = "doors.yaml", resolution: float = 0.01) -> Path:
    spec = {
        "format": "navtopo-scenario/1",
        "name": "doors",
        "seed": 3,
        "world": {
            "resolution": resolution,
            "rooms": [{"center": [3.0, 1.5], "size": [6.0, 3.0]}, {"center": [3.0, 4.7], "size": [6.0, 3.0]}],
            "corridors": [
                {"points": [[WIDE_X, 2.9], [WIDE_X, 3.3]], "width": WIDE_W},
                {"points": [[NARROW_X, 2.9], [NARROW_X, 3.3]], "width": NARROW_W},
            ],
        },
        "robot": {"radius": RADIUS},
        "mapping_route": {"waypoints": [[1.0, 1.0], [WIDE_X, 5.0], [5.0, 5.0], [WIDE_X, 5.0], [5.0, 1.0]]},
        "trials": trials,
    }
    path = tmp_path / name
    path.write_text(yaml.safe_dump(spec))
    return path


def through_narrow_door(path: np.ndarray) -> bool:
    """Whether a polyline crosses the wall between the rooms in the narrow door."""
    for a, b in zip(path[:-1], path[1:], strict=True):
        if (a[1] - WALL_Y[0]) * (b[1] - WALL_Y[0]) <= 0 and a[1] != b[1]:
            x = a[0] + (WALL_Y[0] - a[1]) / (b[1] - a[1]) * (b[0] - a[0])
            if abs(x - NARROW_X) < NARROW_W / 2 + 0.05:
                return True
    return False


# --- the gap of known passages --------------------------------------------------------------


def door_world(width: float, x: float, resolution: float):
    spec = WorldSpec.model_validate(
        {
            "resolution": resolution,
            "rooms": [{"center": [3.0, 1.5], "size": [6.0, 3.0]}, {"center": [3.0, 4.7], "size": [6.0, 3.0]}],
            "corridors": [{"points": [[x, 2.9], [x, 3.3]], "width": width}],
        }
    )
    return build_world(spec, "t.yaml")


@pytest.mark.parametrize(
    ("width", "x", "resolution"),
    [(0.8, 1.5, 0.05), (0.85, 1.525, 0.05), (0.9, 1.5, 0.05), (1.0, 1.5, 0.05), (0.8, 1.5, 0.01), (0.79, 4.505, 0.01)],
)
def test_a_door_of_n_cells_leaves_n_cells_over_two_less_the_radius_whatever_their_parity(width, x, resolution):
    world = door_world(width, x, resolution)
    row = world.to_cell(np.array([x, 3.1]))[0]
    cells = int(world.free[row].sum())
    assert cells * resolution == pytest.approx(width)  # the door is n cells of the raster
    gap = GapGauge(world, RADIUS).measure(np.array([[x - 0.2, 1.0], [x + 0.1, 5.0]]))
    assert gap.gap_m == pytest.approx(cells * resolution / 2 - RADIUS, abs=1e-6)
    assert gap.where is not None and abs(gap.where[0] - x) <= resolution and WALL_Y[0] - 0.05 <= gap.where[1] <= WALL_Y[1] + 0.05


def test_the_ridge_fit_lifts_an_even_door_by_half_a_cell_and_its_slopes_not_at_all():
    world = door_world(0.8, 1.5, 0.05)  # 16 cells: the cell centres miss the ridge by half a cell
    raw, ridge = world.clearance, ridge_clearance(world.clearance, world.resolution)
    row = world.to_cell(np.array([1.5, 3.1]))[0]
    assert raw[row].max() == pytest.approx(0.375) and ridge[row].max() == pytest.approx(0.4)
    # never lowered, and lifted by at most half a step along the diagonal (a 1-Lipschitz field's bound)
    assert np.all(ridge >= raw) and np.all(ridge <= raw + world.resolution * math.sqrt(2) / 2 + 1e-9)
    # the top of the door's cross-section is lifted by half a cell, its slopes are not
    assert np.count_nonzero(ridge[row] > raw[row] + 1e-9) == 2
    # the 3 m deep room is a passage too: its middle (60 cells from wall to wall) is lifted to
    # 1.5 m, a cell on its slope is left alone
    middle, slope = (tuple(world.to_cell(np.array([3.0, y]))) for y in (1.5, 1.0))
    assert raw[middle] == pytest.approx(1.475) and ridge[middle] == pytest.approx(1.5)
    assert ridge[slope] == pytest.approx(raw[slope]) == pytest.approx(1.025)


@pytest.mark.parametrize("angle", [10.0, 22.5, 30.0, 45.0, 60.0])
@pytest.mark.parametrize("width", [0.8, 1.0, 1.2])
def test_a_door_at_an_angle_to_the_raster_is_measured_to_half_a_cell(angle, width):
    a = math.radians(angle)
    along, across = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
    centre = np.array([5.0, 5.0])
    spec = WorldSpec.model_validate(
        {
            "resolution": 0.05,
            "rooms": [{"center": list(centre + s * 2.3 * along), "size": [4, 4], "yaw": angle} for s in (-1, 1)],
            "corridors": [{"points": [list(centre - 0.4 * along), list(centre + 0.4 * along)], "width": width}],
        }
    )
    world = build_world(spec, "t.yaml")
    path = np.array([centre - 2 * along + 0.1 * across, centre + 2 * along - 0.05 * across])
    assert GapGauge(world, RADIUS).measure(path).gap_m == pytest.approx(width / 2 - RADIUS, abs=0.5 * 0.05)


def corridor_scenario(tmp_path: Path, start, goal, width: float = 2.0) -> Path:
    spec = {
        "format": "navtopo-scenario/1",
        "name": "straight",
        "world": {"corridors": [{"points": [[0, 0], [20, 0]], "width": width}]},
        "mapping_route": {"waypoints": [[1, 0], [19, 0]]},
        "trials": [{"start": start, "goal": goal}],
    }
    path = tmp_path / "straight.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


@pytest.mark.parametrize(
    ("start", "goal"),
    [
        ([1.0, 0.0, 0.0], [19.0, 0.0]),  # on the centre line
        ([1.0, -0.65, 0.0], [19.0, 0.6]),  # from beside one wall to beside the other: the passage is what counts
        ([1.0, 0.68, 0.0], [19.0, 0.68]),  # hugging a wall, 2 cm from touching it: the ends' footprints are no gap
    ],
)
def test_the_narrowest_gap_of_a_straight_corridor_is_half_its_width_less_the_radius(tmp_path, start, goal):
    width = 2.0
    trial = load_scenario(corridor_scenario(tmp_path, start, goal, width)).trials[0]
    assert trial.narrowest_gap_m == pytest.approx(width / 2 - RADIUS, abs=0.05)  # to a cell
    assert not trial.narrow


def test_a_gap_wider_than_a_metre_is_wide_open(tmp_path):
    trial = load_scenario(corridor_scenario(tmp_path, [1.0, 0.0, 0.0], [19.0, 0.0], width=3.0)).trials[0]
    assert trial.narrowest_gap_m == GAP_CAP_M and trial.gap_at is None


# --- generated trials keep the margin -------------------------------------------------------


def test_generated_trials_never_pass_the_door_a_centimetre_under_the_margin(tmp_path):
    kept = load_scenario(two_rooms(tmp_path, {"generate": {"count": 8, "min_distance": 3.0}}))
    assert kept.trial_margin_m == TRIAL_MARGIN_M
    assert all(t.narrowest_gap_m >= TRIAL_MARGIN_M - 1e-6 for t in kept.trials)
    assert not any(through_narrow_door(t.shortest_path) for t in kept.trials)
    between = [t for t in kept.trials if (t.start[1] - 3.1) * (t.goal[1] - 3.1) < 0]
    assert between and all(t.narrowest_gap_m == pytest.approx(0.1, abs=1e-6) for t in between)  # the wide door, exactly
    # the same draws without a margin do go through the narrow door: the margin is what left them out
    free = load_scenario(two_rooms(tmp_path, {"generate": {"count": 8, "min_distance": 3.0, "margin": 0.0}}, "free.yaml"))
    narrow = [t for t in free.trials if through_narrow_door(t.shortest_path)]
    assert narrow and all(t.narrowest_gap_m == pytest.approx(0.095, abs=1e-6) for t in narrow)


def test_a_margin_no_trial_can_keep_is_one_line_naming_the_margin(tmp_path):
    # every trial at least 6 m long goes from one room to the other, through a door of gap 0.1 m
    path = two_rooms(tmp_path, {"generate": {"count": 1, "min_distance": 6.0, "margin": 0.5}}, resolution=0.05)
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    assert "trials.generate" in str(caught.value) and "margin 0.5 m" in str(caught.value)
    assert "\n" not in str(caught.value)


# --- listed trials: refused below the margin, or run marked narrow --------------------------

THROUGH_NARROW = {"start": [NARROW_X, 2.0, 90.0], "goal": [NARROW_X, 4.2]}
THROUGH_WIDE = {"start": [WIDE_X, 2.0, 90.0], "goal": [WIDE_X, 4.2]}


@pytest.mark.parametrize("near", [1.0, 0.45])  # ends a metre from the door, or just outside its mouth
def test_a_listed_trial_through_the_narrow_door_is_refused_with_one_line(tmp_path, near):
    through = {"start": [NARROW_X, WALL_Y[0] - near, 90.0], "goal": [NARROW_X, WALL_Y[1] + near]}
    path = two_rooms(tmp_path, [THROUGH_WIDE, through])
    with pytest.raises(ScenarioError) as caught:
        load_scenario(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: trials.1: ") and "\n" not in message
    assert "narrowest gap 0.095 m" in message and "below the margin 0.1 m" in message and "allow_narrow" in message
    assert "at (4.5" in message  # where the gap is


def test_a_listed_trial_exactly_at_the_margin_is_kept(tmp_path):
    trial = load_scenario(two_rooms(tmp_path, [THROUGH_WIDE])).trials[0]
    assert trial.narrowest_gap_m == pytest.approx(0.1, abs=1e-6) and not trial.narrow


def test_a_listed_trial_allowed_narrow_runs_marked_in_trials_json_and_its_record(tmp_path):
    scenario = load_scenario(two_rooms(tmp_path, [THROUGH_WIDE, {**THROUGH_NARROW, "allow_narrow": True}]))
    wide, narrow = scenario.trials
    assert narrow.narrow and narrow.narrowest_gap_m == pytest.approx(0.095, abs=1e-6)
    assert not wide.narrow
    assert scenario.summary()["trial_narrowest_gap_m"] == pytest.approx(0.095) and scenario.summary()["trials_narrow"] == 1
    # ground_truth/trials.json
    folder = write_ground_truth(scenario, tmp_path / "run")
    data = json.loads((folder / "trials.json").read_text())
    assert data["margin_m"] == TRIAL_MARGIN_M
    entry = data["trials"][1]
    assert list(entry)[:7] == ["trial", "start", "goal", "shortest_m", "narrowest_gap_m", "narrow", "narrowest_gap_at"]
    assert entry["narrowest_gap_m"] == pytest.approx(0.095) and entry["narrow"] is True
    assert entry["narrowest_gap_at"][0] == pytest.approx(NARROW_X, abs=0.02)
    gt = Run._load_ground_truth(folder, [])
    assert gt is not None and gt.trial_margin_m == TRIAL_MARGIN_M
    assert gt.trials[1].narrow and gt.trials[1].narrowest_gap_m == pytest.approx(0.095) and not gt.trials[0].narrow
    # the trial's record in trials.jsonl: the keys beside shortest_m, kept through the typed record
    record = trial_record("oracle", 1, narrow, 0, success=True, reason="", travelled_m=2.3).as_json()
    keys = list(record)
    assert keys[keys.index("shortest_m") + 1 : keys.index("shortest_m") + 3] == ["narrowest_gap_m", "narrow"]
    assert record["narrowest_gap_m"] == pytest.approx(0.095) and record["narrow"] is True
    read = TrialRecord.model_validate(json.loads(json.dumps(record)))
    assert read.narrow and read.narrowest_gap_m == pytest.approx(0.095) and read.as_json() == record


def test_allow_narrow_and_margin_are_validated(tmp_path):
    for trials, key, reason in (
        ([{**THROUGH_WIDE, "allow_narrow": "yes"}], "trials.0.allow_narrow", "valid boolean"),
        ({"generate": {"count": 2, "margin": -0.1}}, "trials.generate.margin", "greater than or equal to 0"),
        ({"generate": {"count": 2, "margin": 1.5}}, "trials.generate.margin", "less than or equal to 1"),
    ):
        with pytest.raises(ScenarioError) as caught:
            load_scenario(two_rooms(tmp_path, trials))
        assert f": {key}: " in str(caught.value) and reason in str(caught.value)


# --- the report shows each trial's gap ------------------------------------------------------


def test_the_report_lists_each_trials_gap_and_marks_the_narrow_one(tmp_path):
    root = write_crafted_run(tmp_path / "run")
    truth = root / "ground_truth" / "trials.json"
    data = json.loads(truth.read_text())
    gaps = {0: (0.4, False), 1: (1.0, False), 2: (0.05, True)}
    for entry in data["trials"]:
        if entry["trial"] in gaps:
            entry["narrowest_gap_m"], entry["narrow"] = gaps[entry["trial"]]
    data["margin_m"] = 0.1
    truth.write_text(json.dumps(data))
    run = Run.load(root)
    lines = {line.trial: line for line in trial_lines(run)}
    assert lines[2].narrow and lines[2].narrowest_gap_m == 0.05 and not lines[0].narrow
    text = markdown([run])
    assert "| 0 | " in text and "0.400" in text and "≥ 1" in text and "0.050 *narrow*" in text
    assert "| 3 | 5.00 | – | " in text  # a trial whose gap was never measured (a run from before)
    (note,) = gap_notes([run])
    assert trial_table.GAP_CAP_M == GAP_CAP_M  # the reports' copy (they import nothing of scenarios)
    assert "0.050 m" in note and "(trial 2)" in note and "margin: 0.1 m" in note and "narrow**: 2." in note


# --- a robot's map: a map_server PGM with a door at the margin and one a pixel under ----------


def door_map(tmp_path: Path, trials) -> Path:
    """A 4 m x 6.2 m map at 0.05 m: two rooms parted by a 4-pixel wall with a door of 16 pixels
    (0.8 m: exactly the margin for radius 0.3 m) at x 0.6-1.4 and one of 15 (0.75 m) at x 2.5-3.25."""
    res, width, height = 0.05, 80, 124
    x = (np.arange(width) + 0.5) * res
    y = (np.arange(height) + 0.5) * res
    free = ((x > 0.1) & (x < 3.9))[None, :] & (((y > 0.1) & (y < 3.0)) | ((y > 3.2) & (y < 6.1)))[:, None]
    in_wall = ((y > 3.0) & (y < 3.2))[:, None]
    free |= in_wall & (((x > 0.6) & (x < 1.4)) | ((x > 2.5) & (x < 3.25)))[None, :]
    pixels = np.where(free, 254, 0).astype(np.uint8)[::-1]  # the image's first row is the top
    (tmp_path / "doors.pgm").write_bytes(f"P5\n{width} {height}\n255\n".encode() + pixels.tobytes())
    meta = {"image": "doors.pgm", "resolution": res, "origin": [0.0, 0.0, 0.0], "occupied_thresh": 0.65, "free_thresh": 0.196}
    (tmp_path / "doors_map.yaml").write_text(yaml.safe_dump(meta))
    spec = {
        "format": "navtopo-scenario/1",
        "name": "door_map",
        "world": {"map": {"yaml": "doors_map.yaml"}},
        "mapping_route": {"waypoints": [[1.0, 1.0], [1.0, 5.0], [3.0, 5.0]]},
        "trials": trials,
    }
    path = tmp_path / "door_map.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def test_on_a_robots_map_a_door_at_the_margin_is_kept_and_one_a_pixel_under_is_refused(tmp_path):
    at_margin = {"start": [1.0, 2.0, 90.0], "goal": [1.0, 4.2]}
    (trial,) = load_scenario(door_map(tmp_path, [at_margin])).trials
    assert trial.narrowest_gap_m == pytest.approx(0.1, abs=1e-6) and not trial.narrow
    under = {"start": [2.875, 2.0, 90.0], "goal": [2.875, 4.2]}
    with pytest.raises(ScenarioError, match=r"trials\.1: its shortest path's narrowest gap 0\.075 m .* below the margin 0\.1 m"):
        load_scenario(door_map(tmp_path, [at_margin, under]))
