# Two commands do everything on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint typecheck kernels unit suite bench clean browser

# Installed by uv where pip is told of a folder of wheels (PIP_FIND_LINKS or pip's find-links: torch's CPU build lies
# there; uv reads no pip configuration, and without that folder torch would come as a CUDA build of several GB), else
# by pip. The same packages at the same versions either way (pip freeze identical); a fresh venv here in 56 s by uv,
# cache cold, and in 182 s by pip (2026-12-03). Byte-compiled at install either way: where PYTHONDONTWRITEBYTECODE is
# set, as on these machines, nothing is compiled later, and without it every process compiled mlflow, torch and numpy
# from source again (the suite 812 -> 1106 s with pip's --no-compile).
# uv pinned: every CI run installs with the one measured
UV := uv==0.13.9
FIND_LINKS ?= $(or $(PIP_FIND_LINKS),$(shell $(PYTHON) -m pip config get global.find-links 2>/dev/null))

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	if [ -n "$(FIND_LINKS)" ] && $(BIN)/python -m pip install -q $(UV) && \
	   $(BIN)/uv pip install -q --python $(BIN)/python $(foreach f,$(FIND_LINKS),--find-links $(f)) --compile-bytecode \
	     -e ".[dev]"; then :; else $(BIN)/python -m pip install -q -e ".[dev]"; fi
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/hydrowatch demo

lint: $(STAMP)
	$(BIN)/ruff check hydrowatch services tests benchmarks

typecheck: $(STAMP)
	$(BIN)/mypy hydrowatch services

# Headless Chromium for the web page's browser tests and benchmark (tests/test_web_browser.py,
# benchmarks/bench_web.py): Debian's package, installed where apt-get is there and we are root. Never
# fails: without a browser those tests skip and say why.
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
	  { command -v apt-get >/dev/null 2>&1 && [ "$$(id -u)" = 0 ] && \
	    { timeout 900 apt-get install -y -q chromium >/dev/null 2>&1 || \
	      { timeout 300 apt-get update -q >/dev/null 2>&1 && \
	        timeout 900 apt-get install -y -q chromium >/dev/null 2>&1; }; }; } || \
	  echo "no Chromium (apt-get install chromium): the browser tests will be skipped"

# Three pytest-xdist workers on the CI machine's two cores: tests/conftest.py keeps each module on one worker and the
# modules that start services on the same one, which mostly waits for their messages; the other two take the CPU it
# leaves. Measured here (2026-12-03, the same code, its kernels compiled beforehand): the suite 838 s on two workers,
# 693 s on three; against a two-worker run of the code before, the service tests 600 -> 664 test-s and the rest
# 976 -> 1312 (they share the cores): the service worker is now the longest.
TEST_WORKERS ?= 3
PYTEST := $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile

unit: $(STAMP) browser
	$(PYTEST)

# numba's kernels compiled into their cache (tests/compile_kernels.py says why)
kernels: $(STAMP)
	$(BIN)/python tests/compile_kernels.py

# make test: Chromium installs (apt-get: mostly waiting on the network) while the venv installs; then the kernels
# (one core, ~45 s), ruff and mypy (one core, 60-90 s cold) start together; the suite starts once the kernels are
# compiled and ruff passed, mypy going on beside it. The suite is CPU-bound (its processes used 1.9 of the 2 cores on
# three workers): measured in fresh clones here, mypy beside the kernels alone left a core idle after them (set-up
# 103 -> 146 s, the suite not shorter by as much).
suite: kernels lint browser
	$(PYTEST)

test:
	$(MAKE) --no-print-directory -j4 typecheck suite

bench: $(STAMP) browser
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
