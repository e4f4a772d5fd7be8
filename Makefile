# scenenav — two commands: `make demo` and `make test`. Both create .venv through `make install`.
# `make lint` runs the house-rule checkers (ruff, import-linter, mypy); `make test` runs it first.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(VENV)/bin/pip
STAMP  := $(VENV)/.installed

.PHONY: install demo lint test bench clean

install: $(STAMP)

# One pip call resolves torch, the project and the test and lint tools together. pip's byte-compiling
# is about half of the ~2 min set-up, but it stays: without the .pyc files every process of every
# test would compile its imports again where PYTHONDONTWRITEBYTECODE is set.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip setuptools wheel
	# torch must be the CPU build: 2.13.0 resolves to the local CPU wheel, never to the CUDA wheels.
	$(PIP) install torch==2.13.0 -e '.[test,lint]'
	touch $(STAMP)

demo: install
	$(VENV)/bin/scenenav run scenarios/demo.yaml --out runs/demo-$$(date +%Y%m%d-%H%M%S)

# ruff: pyflakes, import order, bugbear, module docstrings; lint-imports: the layering contracts
# ([tool.importlinter] in pyproject.toml); mypy: the bottom layer scenenav/core. All three run, so one
# report shows every finding; the target fails if any of them failed.
lint: install
	@status=0; \
	echo '== ruff'; $(VENV)/bin/ruff check . || status=1; \
	echo '== lint-imports'; $(VENV)/bin/lint-imports || status=1; \
	echo '== mypy'; $(VENV)/bin/mypy || status=1; \
	echo '== module map'; PYTHONPATH=. $(VENV)/bin/python tools/module_map.py --check docs/architecture.md || status=1; \
	exit $$status

# Two pytest workers (pytest-xdist): most tests are real runs whose processes wait on each other, the
# bus or the wall clock (MAVProxy, MAVSDK and the failsafe tests fly in real time), so one worker
# leaves a core idle much of the time. --dist loadscope keeps each module on one worker, so a module's
# shared flights (module-scoped fixtures) are flown once. TEST_WORKERS=0 runs the suite in one process.
TEST_WORKERS ?= 2

# The real-time SITL flights (marker `realtime`: MAVProxy, MAVSDK, the failsafes, ...) run
# afterwards, apart from the lockstep part: beside its full-speed flights MAVSDK's mission, the
# failsafe RTL's landing and the swap flight fell behind the wall clock, which is a test of the
# machine, not of the code. Two of them at a time fit the two cores (paced flights leave CPU idle;
# the physics waits for the autopilot, so a busy moment slows a flight instead of spoiling it);
# they share no module fixtures, so they are dealt out one test at a time (--dist load).
# `make lint` is its own target (CI runs both): `make test` is the suite alone.
test: install
	$(PY) -m pytest -q -ra -n $(TEST_WORKERS) --dist loadscope --durations=40 -m "not realtime"
	$(PY) -m pytest -q -ra -n $(TEST_WORKERS) --dist load --durations=10 -m realtime

bench: install
	$(VENV)/bin/scenenav bench sim

clean:
	rm -rf $(VENV) runs .pytest_cache
