"""What one report holds: its runs (each with its plots, config file and reproducing command),
the plots over all runs, a study's plots and the files written (``reports.report`` makes it,
``reports.html`` draws it)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from reports.plots import PlotResult
from reports.results import Run


@dataclass
class RunSection:
    """One run in a report: its key, its plots, its config file and the command that reproduces it."""

    run: Run
    key: str
    plots: list[PlotResult] = field(default_factory=list)
    failures: list[PlotResult] = field(default_factory=list)  # a crop per failed trial (``reports.failures``)
    config_file: str = "config.yaml"
    command: str = ""


@dataclass
class Report:
    out: Path
    sections: list[RunSection]
    combined: list[PlotResult]
    files: list[Path]
    study: list[PlotResult] = field(default_factory=list)
    study_title: str = ""
    left_out: list[str] = field(default_factory=list)  # runs named twice or copied, one line each

    @property
    def html(self) -> Path:
        return self.out / "report.html"

    @property
    def notes(self) -> list[str]:
        """Why any plot was skipped or drawn without the GT map, one line each."""
        lines = [f"{s.key}: {p.name}: {p.note}" for s in self.sections for p in s.plots + s.failures if p.note]
        return self.left_out + lines + [f"{p.name}: {p.note}" for p in self.combined + self.study if p.note]
