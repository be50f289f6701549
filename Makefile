# Two commands do everything on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint typecheck unit bench clean browser

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
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

# Two pytest-xdist workers (one per core of the CI machine); tests/conftest.py keeps each module on one worker and the
# modules that start services on the same one. `python -m pytest` alone runs the suite in one process.
TEST_WORKERS ?= 2

unit: $(STAMP) browser
	$(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile

test: lint typecheck unit

bench: $(STAMP) browser
	for b in benchmarks/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .mypy_cache .ruff_cache
