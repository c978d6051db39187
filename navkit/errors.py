"""The one base of every expected failure: a message of one line and the command's exit code.

Expected failures are inputs refused (a malformed scenario, a missing map image, a corrupt saved
map, a flag out of range: exit code 2) and runs that could not finish (a failed stage: exit code
1). The command line catches ``BenchError`` in one place and prints ``error: <message>``; anything
else is a bug and keeps its traceback.

``FileProblem`` names the file, the key in it and the reason, as ``file: key: reason``.
"""

from __future__ import annotations

from pathlib import Path


class BenchError(Exception):
    """An expected failure; ``str(error)`` is the one line to show a user."""

    exit_code: int = 2  # an input refused; a run that failed is 1

    def __init__(self, message: str) -> None:
        super().__init__(message)


class FileProblem(BenchError):
    """A file that cannot be used: ``file: key: reason`` (``file: reason`` when no key applies)."""

    def __init__(self, file: str | Path, key: str, reason: str) -> None:
        self.file, self.key, self.reason = str(file), key, reason
        super().__init__(f"{file}: {key}: {reason}" if key else f"{file}: {reason}")
