# Two commands for a fresh machine with Python 3.10+ and make:
#   make demo   replay the bundled sample and write recordings/classic.rrd
#   make test   ruff, mypy, pytest and the documentation site
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
RECORDING := recordings/classic.rrd

.PHONY: test-all demo test typecheck unit-tests site bench sample clean screenshots docs

# uv installs into the environment what pip would, in seconds rather than a minute and a
# half. The commands' own dependencies are installed with their bytecode: an install
# compiles none by itself and, where PYTHONDONTWRITEBYTECODE is set (as on CI machines),
# every start would compile their modules from source again. The tests' and the
# documentation's many more are installed without it: the test run writes the bytecode of
# what it imports, once (see WRITE_BYTECODE); compiling all of them took longer.
UV := $(BIN)/uv pip install --quiet

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(BIN)/uv: | $(BIN)/python
	$(BIN)/python -m pip install --quiet 'uv>=0.5'

# setup.py builds the compiled kernel of small maps (ekfviz/filters/_kernel.c) and JCBB's
# search (ekfviz/association/_search.c) in place; both take their float64 arrays by
# ekfviz/_doubles.h
BUILD_INPUTS := pyproject.toml setup.py ekfviz/filters/_kernel.c ekfviz/_doubles.h \
	ekfviz/association/_search.c

$(VENV)/.installed: $(BUILD_INPUTS) | $(BIN)/uv
	$(UV) --compile-bytecode --python $(BIN)/python -e .
	touch $@

$(VENV)/.installed-dev: $(BUILD_INPUTS) | $(BIN)/uv
	$(UV) --python $(BIN)/python -e '.[dev]'
	touch $(VENV)/.installed $@

# ekfviz's bytecode, written once its sources change: an editable install compiles none,
# and where PYTHONDONTWRITEBYTECODE is set (as on CI machines) every command would compile
# its ~90 modules from source at each start (0.1-0.3 s; see benchmarks/RESULTS.md)
SOURCES := $(shell find ekfviz -name '*.py')
$(VENV)/.compiled: $(SOURCES) | $(BIN)/python
	$(BIN)/python -m compileall -q ekfviz
	touch $@

demo: $(VENV)/.installed $(VENV)/.compiled
	$(BIN)/ekfviz replay data/classic.txt --truth data/classic_truth.json \
		--save $(RECORDING) --report recordings/classic.json

# an interpreter with numpy 1 (no ekfviz), for the tests of --python: students' code written
# for numpy 1 runs under it (1.23 still builds ragged arrays; Python 3.12+ gets 1.26)
NUMPY1 := .venv-numpy1/bin/python
$(NUMPY1): | $(BIN)/uv
	$(PYTHON) -m venv --without-pip .venv-numpy1
	$(UV) --compile-bytecode --python $(NUMPY1) \
		"numpy==$$($(PYTHON) -c 'import sys; print("1.23.5" if sys.version_info < (3, 12) else "1.26.4")')"

# the modules a run imports are compiled as they are first imported and kept (within the
# environment and the source tree), whatever PYTHONDONTWRITEBYTECODE says outside
WRITE_BYTECODE := PYTHONDONTWRITEBYTECODE=

# ruff first (a second), then the type check and the documentation site beside the tests:
# mypy takes one core for half a minute, which the tests' two workers would otherwise leave
# to it alone
test: $(VENV)/.installed-dev $(VENV)/.compiled $(NUMPY1)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(WRITE_BYTECODE) $(MAKE) --no-print-directory -j3 typecheck unit-tests site

typecheck:
	$(BIN)/mypy

unit-tests:
	$(BIN)/pytest

site:
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet --site-dir site

# The tests marked slow, which make test leaves out (the corpora of hostile submissions and of
# students' modules, the mutation search over every operation): CI runs them after make test.
test-all: test
	$(WRITE_BYTECODE) $(BIN)/pytest -m slow

# Regenerate the bundled sample (a test checks data/ matches this).
sample: $(VENV)/.installed $(VENV)/.compiled
	$(BIN)/python -m ekfviz.samples data

clean:
	rm -rf $(VENV) .venv-numpy1 .mypy_cache .ruff_cache .pytest_cache .hypothesis build site
	rm -f ekfviz/filters/_kernel*.so ekfviz/association/_search*.so

# Benchmarks (not part of make test): core against dense, the bandwidth bound, end-to-end
# replays, each command's start-up and wrap-up, and the scaling curves (drawn as PNGs beside
# RESULTS.md), measured in one run; writes benchmarks/RESULTS.md. The 1,000,000-step replay
# of the scaling curves alone takes a few minutes; BENCH_ARGS=--quick runs smaller cases
# without it (a smoke test, not the reference numbers).
bench: $(VENV)/.installed-dev $(VENV)/.compiled
	$(BIN)/python benchmarks/bench.py $(BENCH_ARGS)

# The documentation's screenshots (docs/*.png, 1600x1000) of every default layout, from
# generated data, in the real viewer run headless once each recording has loaded (not part
# of make test; needs a GPU or Mesa's lavapipe: apt-get install mesa-vulkan-drivers). With
# the datasets: make screenshots MRCLAM=PATH/MRCLAM_Dataset6 VICTORIA=PATH/VictoriaPark
# (else a simulated MRCLAM directory and a generated Victoria Park run).
screenshots: $(VENV)/.installed-dev $(VENV)/.compiled
	$(BIN)/python docs/screenshots.py $(if $(MRCLAM),--mrclam $(MRCLAM)) $(if $(VICTORIA),--victoria $(VICTORIA))

# The documentation site, served at http://127.0.0.1:8000 while its sources change (make
# test builds it into site/ with --strict: a broken link or a missing page fails)
docs: $(VENV)/.installed-dev
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs serve
