"""The parts of the `navtopo-bench` command line; ``runners/cli.py`` declares the commands.

errors.py     the command line's own expected failures (``navkit.errors.BenchError``)
console.py    the two consoles and the ``error:`` / ``note:`` lines
checks.py     refusals several commands share: numbers, lists, output paths, executors
jobs.py       where jobs run: the executor options and the one executor of a command
request.py    ``RunRequest``: the flags of `run` as one typed model with their rules
resume.py     the manifest of a run folder to resume (``reports.results.Manifest``)
runs.py       what `run` does with a request: new runs, a resume, a suite's runs
progress.py   the display of runs in flight and of their outcomes (rich)
scenario.py   `scenario list|show|validate|render`
sweep.py      `sweep scaling|drift`
"""
