# Two commands do all set-up: `make run` and `make test`. Both create .venv when missing.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
DATA_DIR ?= var

.PHONY: install run test lint typecheck unit spin browser bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	# torch first and pinned: the CPU wheel on disk; unpinned it pulls GBs of CUDA packages.
	$(BIN)/python -m pip install --quiet torch==2.13.0
	$(BIN)/python -m pip install --quiet -e '.[dev,sbx]'
	touch $(STAMP)

install: $(STAMP)

# spin is the independent LTL translator the tests compare against.
spin:
	@command -v spin >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ]; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq spin >/dev/null) \
	      || echo "warning: could not install spin; the spin comparison tests will skip"; \
	  else echo "warning: spin missing and not root; the spin comparison tests will skip"; fi; }

# Debian's Chromium drives the dashboard test (Playwright never downloads a browser here).
browser:
	@command -v chromium >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ]; then \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver >/dev/null) \
	      || echo "warning: could not install chromium; the dashboard browser test will skip"; \
	  else echo "warning: chromium missing and not root; the dashboard browser test will skip"; fi; }

# The API and one worker on SQLite + an embedded broker under $(DATA_DIR); Ctrl-C stops both.
run: install
	LTLNAV_DATA_DIR=$(DATA_DIR) $(BIN)/ltlnav serve

lint: install
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: install
	$(BIN)/mypy

unit: install spin browser
	$(BIN)/pytest -q

test: lint typecheck unit

bench: install
	$(BIN)/python -m pip install --quiet ompl || echo "warning: ompl unavailable; OMPL comparison skipped"
	$(BIN)/python bench/planner.py

clean:
	rm -rf $(VENV) .mypy_cache .ruff_cache .pytest_cache
