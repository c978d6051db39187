# navtopo-bench: `make bench` and `make test` each set everything up on a fresh clone.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
BENCH := $(VENV)/bin/navtopo-bench
STAMP := $(VENV)/.installed
# the default benchmark: the paper's scene, the three systems, trials on both cores
BENCH_SCENARIO ?= corridor_150m
BENCH_SYSTEMS ?= navtopo,metric_grid,oracle
BENCH_WORKERS ?= 2
BENCH_OUT ?= results/$(BENCH_SCENARIO)/bench

.PHONY: setup browser bench test test-slow lint clean

setup: $(STAMP)

# torch first and pinned: 2.13.0 is a CPU build found on local disk; an unpinned torch pulls a
# multi-GB CUDA build. Then the project (its torch range is satisfied by 2.13.0).
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e '.[dev,ray]'
	touch $(STAMP)

bench: setup
	rm -rf $(BENCH_OUT)
	$(BENCH) run $(BENCH_SCENARIO) --systems $(BENCH_SYSTEMS) --workers $(BENCH_WORKERS) --out $(BENCH_OUT)
	$(BENCH) report $(BENCH_OUT)
	cat $(BENCH_OUT)/report/table.md

# The HTML report's browser test needs headless Chromium: installed only if missing, and only where
# apt-get can run (as root); anywhere else that one test is skipped with its reason. Never fails.
browser:
	@if command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
		echo "installing chromium (apt-get) for the report's browser test"; \
		{ apt-get install -y --no-install-recommends chromium >/dev/null 2>&1 || \
		  { apt-get update >/dev/null 2>&1 && apt-get install -y --no-install-recommends chromium >/dev/null 2>&1; }; } || \
		echo "chromium: apt-get failed; the report's browser test will be skipped"; \
	else echo "chromium: not found and apt-get not usable here; the report's browser test will be skipped"; fi

# pytest exits 5 when it collects no test (e.g. a -k filter that matches none): not a failure
test: setup browser
	$(PY) -m pytest -m "not slow" -n 2 -q $(PYTEST_ARGS); status=$$?; \
	if [ $$status -eq 5 ]; then echo "pytest: no tests collected"; exit 0; fi; exit $$status

test-slow: setup
	$(PY) -m pytest -m slow -q

# ruff (style, imports, complexity at most 15) and mypy on every package, the benchmarks and tools
lint: setup
	$(VENV)/bin/ruff check navkit navtopo baselines scenarios runners reports tests benchmarks tools
	$(VENV)/bin/mypy navkit navtopo baselines scenarios runners reports
	PYTHONPATH=. $(VENV)/bin/mypy benchmarks tools

clean:
	rm -rf $(VENV) results .pytest_cache
