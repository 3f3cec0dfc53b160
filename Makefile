# Every target creates .venv and installs from the package registry on a fresh machine.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out/paper

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[dev]'
	# MAVProxy's full dependency set is over 1 GB (wx, opencv...); the console needs none of it
	$(BIN)/pip install --quiet --no-deps mavproxy
	# the view's browser test (tests/test_view.py) drives Debian's chromium and chromedriver:
	# installed here where the set-up may (root with apt); elsewhere that test skips, saying why
	@if ! command -v chromium >/dev/null || ! command -v chromedriver >/dev/null; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing Debian's chromium and chromium-driver (the view's browser test)"; \
	    (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium chromium-driver \
	      >/dev/null) || echo "chromium could not be installed: tests/test_view.py will skip"; \
	  else echo "no chromium and no root apt: tests/test_view.py will skip"; fi; \
	fi
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/heli-sitl simulate --scenario paper --out $(OUT)
	@echo "demo outputs in $(OUT)/ (run.csv, flight.mcap, summary.json, fig5..fig9 PNGs)"

lint: $(STAMP)
	$(BIN)/ruff check heli_common heli_plant heli_sitl autopilot ground tests benchmarks docs/examples
	$(BIN)/mypy
	$(BIN)/lint-imports --no-cache

test: lint
	$(BIN)/python -m heli_sitl.warmup
	# a real-time and a CPU worker per core (at most four, in the lanes of tests/lanes.py),
	# handed the tests file by file so that a module's fixtures are built once
	# (tests/conftest.py); the 25 slowest tests printed at the end
	$(BIN)/pytest -q -n auto --maxprocesses 4 --dist loadfile --durations 25

# prints the table and writes it into docs/performance.md between its markers (nothing copied by hand)
bench: $(STAMP)
	$(BIN)/python -m benchmarks --table docs/performance.md

clean:
	rm -rf $(VENV) out .pytest_cache .mypy_cache .ruff_cache
