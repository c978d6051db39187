"""The command line's own expected failures.

Each is a ``navkit.errors.BenchError``: ``str(error)`` is the one line a user sees after
``error:``, ``exit_code`` the command's exit code. ``runners/cli.py`` catches them in one place
(``BenchGroup.invoke``); errors of other layers (``ScenarioError``, ``SuiteError``,
``ExecutorUnavailable``, ``SweepError``) reach it unchanged.
"""

from __future__ import annotations

from navkit.errors import BenchError


class Refused(BenchError):
    """An input refused before any work: a flag's value, an output that cannot be written, a file
    that cannot be used (exit 2)."""

    exit_code = 2


class RunsFailed(BenchError):
    """Runs that failed once every run ended (a stage, a worker): one ``error:`` line each (exit 1)."""

    exit_code = 1

    def __init__(self, failures: list[str]) -> None:
        self.failures = failures
        super().__init__("; ".join(failures))


class ReportFailed(BenchError):
    """A report that failed on a run it could read (a bug or an odd file; exit 1)."""

    exit_code = 1


class Interrupted(BenchError):
    """Ctrl-C during runs; the message says how to finish them (exit 130)."""

    exit_code = 130
