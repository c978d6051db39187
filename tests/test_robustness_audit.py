"""Issue 14, audited as a new user would try it: inputs the first pass let through (map_server
thresholds, read-only folders as root, sweep flags, a run folder named twice, config knobs that
validate and then fail the mapping stage), each one line and a non-zero exit with nothing created."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from test_robustness import one_line_error
from typer.testing import CliRunner

from runners.cli import app


def refused_by_main(monkeypatch, capsys, *args: str) -> str:
    """The command (its entry point, which makes usage errors one line too) refused with one
    `error:` line on stderr and exit 2; returns that line."""
    import sys

    from runners.cli import main

    monkeypatch.setattr(sys, "argv", ["navtopo-bench", *args])
    code = main()
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and len(err.splitlines()) == 1 and err.startswith("error: "), (code, out, err)
    return err


@pytest.fixture
def read_only() -> Path:
    """A folder this process cannot write: os.access answers yes to root everywhere, so as root
    the folder is /sys (sysfs refuses new files even to root)."""
    if os.geteuid() != 0:
        pytest.skip("as a user, a folder's mode is what refuses (tests/test_robustness.py)")
    try:
        Path("/sys/navtopo-probe").touch()
    except OSError:
        return Path("/sys")
    Path("/sys/navtopo-probe").unlink()
    pytest.skip("/sys is writable here")


# ---------------------------------------------------------------------------------------------
# outputs that cannot be written, as root


@pytest.mark.parametrize(
    "args",
    [
        ["run", "tiny", "--out", "{ro}/run"],
        ["run", "tiny", "--results", "{ro}/results"],
        ["scenario", "render", "tiny", "-o", "{ro}/map.png"],
        ["train-descriptor", "--data-dir", "{ro}/data", "--out", "{tmp}/weights"],
        ["sweep", "drift", "tiny", "--out", "{ro}/drift"],
    ],
)
def test_an_output_on_a_read_only_folder_is_refused_before_any_work(tmp_path, read_only, args):
    args = [a.format(ro=read_only, tmp=tmp_path) for a in args]
    line = one_line_error(CliRunner().invoke(app, args))
    assert f"{read_only} is not writable" in line
    assert list(tmp_path.iterdir()) == []


def test_report_and_plot_graph_into_a_read_only_folder_are_refused(tmp_path, read_only):
    from crafted_run import write_crafted_run

    run = write_crafted_run(tmp_path / "run")
    for args in (["report", str(run), "--out", f"{read_only}/r"], ["plot-graph", str(run), "-o", f"{read_only}/g.png"]):
        assert f"{read_only} is not writable" in one_line_error(CliRunner().invoke(app, args))
    assert not (run / "report").exists()


def test_training_threads_below_one_are_refused_before_generating_scans(tmp_path, monkeypatch, capsys):
    line = refused_by_main(monkeypatch, capsys, "train-descriptor", "--threads", "0", "--data-dir", str(tmp_path / "data"))
    assert "--threads" in line and list(tmp_path.iterdir()) == []
