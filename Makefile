# scenenav — two commands: `make demo` and `make test`. Both create .venv through `make install`.
# `make lint` runs the house-rule checkers (ruff, import-linter, mypy); `make test` runs it first.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(VENV)/bin/pip
STAMP  := $(VENV)/.installed

.PHONY: install demo lint test bench clean

install: $(STAMP)

# One pip call resolves torch, the project and the test and lint tools together, without pip's
# byte-compiling: compiling all 12 000 modules of .venv was about 50 s of CPU, over half of the
# set-up, while a run imports a small part of them. Python compiles a module the first time it is
# imported and keeps the .pyc (written atomically, so processes importing at once are safe);
# PYTHONDONTWRITEBYTECODE would stop that and make every process of every test compile its
# imports again, so no target passes it on (unexport below).
unexport PYTHONDONTWRITEBYTECODE
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip setuptools wheel
	# torch must be the CPU build: 2.13.0 resolves to the local CPU wheel, never to the CUDA wheels.
	$(PIP) install --no-compile torch==2.13.0 -e '.[test,lint]'
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
# The lockstep part runs one worker more: a lockstep flight's processes take turns (each tick waits
# for the others over the bus), so two such flights leave part of the two cores idle. TEST_WORKERS=0
# runs it in one process too.
LOCK_WORKERS ?= $(if $(filter 0,$(TEST_WORKERS)),0,$(shell echo $$(( $(TEST_WORKERS) + 1 ))))

# The real-time SITL flights (marker `realtime`: MAVProxy, MAVSDK, the failsafes, ...) fly on the
# wall clock and leave most of a core idle; the lockstep part is bound by the CPU and by nothing
# else (a lockstep flight is the same flight however slowly it runs). So both run at once: the
# real-time flights two at a time at normal priority, the lockstep part at `nice` 10 beside them,
# taking whatever CPU they leave (a real-time flight once fell behind the wall clock beside
# full-speed flights of equal priority: MAVSDK's mission, the failsafe RTL's landing, the swap
# flight). The real-time part's report is printed after the lockstep part's; the target fails if
# either failed. The real-time tests share no module fixtures: dealt out one test at a time.
# `make lint` is its own target (CI runs both): `make test` is the suite alone.
RT_LOG := .pytest-realtime.log
test: install
	@$(PY) -m pytest -q -ra -n $(TEST_WORKERS) --dist load --durations=10 -m realtime > $(RT_LOG) 2>&1 & rt=$$!; \
	nice -n 10 $(PY) -m pytest -q -ra -n $(LOCK_WORKERS) --dist loadscope --durations=40 -m "not realtime"; lock=$$?; \
	wait $$rt; rts=$$?; \
	echo "== the real-time tests (marker realtime), run alongside at normal priority"; cat $(RT_LOG); \
	test $$lock -eq 0 && test $$rts -eq 0

bench: install
	$(VENV)/bin/scenenav bench sim

clean:
	rm -rf $(VENV) runs .pytest_cache
