# Two commands do all the set-up on a fresh machine with Python 3.11 and pip:
#   make demo   creates .venv, installs pe_drake, optimizes a Panda trajectory into results/panda
#   make test   creates .venv, installs pe_drake with its test tools, runs the whole test suite
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test bench clean

# pe_drake alone for the demo; its test tools (pytest, Ray) only for the tests.
$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(BIN)/.installed-test: $(BIN)/.installed
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@

demo: $(BIN)/.installed
	$(BIN)/pe-drake optimize --robot panda --out results/panda

test: $(BIN)/.installed-test
	$(BIN)/python -m pytest -q

bench: $(BIN)/.installed
	$(BIN)/python -m pe_drake.bench gradient
	$(BIN)/python -m pe_drake.bench identify
	$(BIN)/python -m pe_drake.bench diagnose

clean:
	rm -rf $(VENV) results
