# scenenav — two commands: `make demo` and `make test`. Both create .venv through `make install`.
PYTHON ?= python3.11
VENV   := .venv
PY     := $(VENV)/bin/python
PIP    := $(VENV)/bin/pip
STAMP  := $(VENV)/.installed

.PHONY: install demo test bench clean

install: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip setuptools wheel
	# torch must be the CPU build: 2.13.0 resolves to the local CPU wheel, never to the CUDA wheels.
	$(PIP) install torch==2.13.0
	$(PIP) install -e '.[test]'
	touch $(STAMP)

demo: install
	$(VENV)/bin/scenenav run scenarios/demo.yaml --out runs/demo-$$(date +%Y%m%d-%H%M%S)

test: install
	$(PY) -m pytest -q -ra

bench: install
	$(VENV)/bin/scenenav bench sim

clean:
	rm -rf $(VENV) runs .pytest_cache
