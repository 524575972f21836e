# Two entry points for a fresh machine (Python 3.11 + pip): `make demo` and `make test`; `make docs`
# builds the guide.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# The test environment's exact versions (Textual, numpy, scipy, ...): a new release changes the
# suite only when this file is regenerated on purpose (`make constraints`, then `make test`, then
# commit both). The product's own requirements in pyproject.toml stay ranges.
CONSTRAINTS := constraints.txt

.PHONY: demo test test-fast docs constraints mutants bench clean

$(STAMP): pyproject.toml $(CONSTRAINTS)
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -c $(CONSTRAINTS) -e '.[test,docs]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/fieldcal run --config configs/sim.yaml --procedure field-18 --headless --seed 1

# Bytecode caches (the gitignored __pycache__ folders) are written even where PYTHONDONTWRITEBYTECODE
# is set: without them every xdist worker compiles and assert-rewrites all the test modules again
# (4 s of CPU each at every run, half of its start-up) and every CLI subprocess compiles fieldcal.
test test-fast: export PYTHONDONTWRITEBYTECODE =

# One worker per core and one more (pytest-xdist `-n auto`: tests/conftest.py says why); `make test
# PYTEST_ARGS=...` adds options. loadgroup: the
# tests sharing an expensive module fixture run on one worker, which builds it once (conftest.py).
test: $(STAMP)
	$(BIN)/python -m pytest -n auto --dist loadgroup $(PYTEST_ARGS)

# The quick loop while working: every module, without the tests marked slow (long statistics,
# end-to-end runs); `make test` runs them all.
test-fast: $(STAMP)
	$(BIN)/python -m pytest -n auto --dist loadgroup -m "not slow" $(PYTEST_ARGS)

# The guide (mkdocs.yml, docs/) into site/, strictly: a broken link, a page missing from the nav or
# any other warning fails. (NO_MKDOCS_2_WARNING: Material's notice about MkDocs 2 on every build.)
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

# Regenerate constraints.txt from the newest releases pyproject.toml's ranges allow, in a
# scratch environment (the working .venv is left alone).
constraints:
	rm -rf .venv-constraints
	$(PYTHON) -m venv .venv-constraints
	.venv-constraints/bin/pip install --quiet --upgrade pip
	.venv-constraints/bin/pip install --quiet -e '.[test,docs]'
	{ echo "# Exact versions for the test environment (make test): regenerate with make constraints."; \
	  .venv-constraints/bin/pip freeze --exclude-editable; } > $(CONSTRAINTS).new
	mv $(CONSTRAINTS).new $(CONSTRAINTS)
	rm -rf .venv-constraints

# Mutation testing of the core ([tool.mutmut] in pyproject.toml), not in CI: hours on 2 cores.
# mutmut generates the mutants, in its own environment so its dependencies stay out of the tests';
# pinned, since tools/mutation uses its internals and tools/mutation/equivalent.txt its mutant names,
# both of which change between releases. tools/mutation/run.py runs each module's mutants in one
# niced pytest process against the quick tests tools/mutation/tests.toml lists, keeps the verdicts
# in mutants/results/ (a second run only reports) and prints a table against the 90 % goal.
# MODULES='procedure/positions.py session/*' runs some; AGAIN=survived re-runs their survivors;
# JOBS=3 runs a module in 3 niced processes (on a busy machine each niced one gets a small share).
# SAMPLE=100 runs 100 of each module's mutants (a fixed random draw) and gives each rate a 95 % interval.
MUTANTS_VENV := .venv-mutants
MUTMUT := mutmut==3.8.1
$(MUTANTS_VENV)/.installed: pyproject.toml $(CONSTRAINTS)
	$(PYTHON) -m venv $(MUTANTS_VENV)
	$(MUTANTS_VENV)/bin/pip install --quiet -c $(CONSTRAINTS) -e '.[test]' '$(MUTMUT)'
	touch $@

mutants: $(MUTANTS_VENV)/.installed
	$(MUTANTS_VENV)/bin/python tools/mutation/run.py --modules '$(MODULES)' $(if $(AGAIN),--again $(AGAIN)) $(if $(SAMPLE),--sample $(SAMPLE)) $(if $(JOBS),--jobs $(JOBS))

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
	rm -rf $(VENV) .venv-constraints $(MUTANTS_VENV) mutants build site *.egg-info
