# Two commands do everything on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint typecheck kernels unit bench clean browser

# Byte-compiled at install (pip's default): where PYTHONDONTWRITEBYTECODE is set, as on these machines, nothing is
# compiled later, and without it every process compiled mlflow, torch and numpy from source again (the suite 812 ->
# 1106 s with --no-compile). Python 3.11's own pip (23) installs the project as it is.
$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q -e ".[dev]"
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

unit: $(STAMP) browser
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile

# numba's kernels compiled into their cache (tests/compile_kernels.py says why)
kernels: $(STAMP)
	$(BIN)/python tests/compile_kernels.py

# The kernels compile while Chromium installs; then mypy (one core, about a minute) runs beside the suite, whose
# service worker leaves CPU idle (the three-worker suite used 1.76 of the 2 cores).
test: lint
	$(MAKE) --no-print-directory -j2 kernels browser
	$(MAKE) --no-print-directory -j2 typecheck unit

bench: $(STAMP) browser
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
