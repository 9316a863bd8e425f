# Two entry points for a newcomer: `make run` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
OUT    ?= out

.PHONY: run test venv bench clean verilator

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e .
	touch $(STAMP)

## Main job on the default scene: golden and bit-true runs, pictures, Verilog checked on Icarus, report, synthesis.
run: $(STAMP)
	$(BIN)/rheo run --out $(OUT)

## Whole test suite (builds the pinned Verilator once into ~/.cache/rheo-fpga if needed).
test: $(STAMP) verilator
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/rheo bench --backend golden --json

## Pinned Verilator 5.048 (cocotb 2.x needs >= 5.036), built once into $RHEO_CACHE (default ~/.cache/rheo-fpga).
verilator:
	bash tools/build-verilator.sh

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache
