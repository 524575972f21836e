# Two entry points for a fresh machine (Python 3.11 + pip): `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/fieldcal run --config configs/sim.yaml --procedure field-18 --headless --seed 1

# One worker per core (pytest-xdist); `make test PYTEST_ARGS=...` adds options.
test: $(STAMP)
	$(BIN)/python -m pytest -n auto $(PYTEST_ARGS)

bench: $(STAMP)
	$(BIN)/python benchmarks/startup.py
	$(BIN)/python benchmarks/tui_start.py
	$(BIN)/python benchmarks/speed.py
	$(BIN)/python benchmarks/parse.py
	$(BIN)/python benchmarks/io.py
	$(BIN)/python benchmarks/replay.py
	$(BIN)/python benchmarks/recording.py
	$(BIN)/python benchmarks/accuracy.py

clean:
	rm -rf $(VENV) build *.egg-info
