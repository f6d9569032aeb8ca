# Two commands do everything on a fresh machine (Python 3.11+, gcc):
#   make run    set up, build the vehicle FMU, co-simulate the default scenario
#   make test   set up, build the vehicle FMU, run the tests
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
SCENARIO ?= paper-sim
OUT ?= runs/$(SCENARIO)
# pytest-xdist workers for make test; the two browser tests share one (their xdist_group)
TEST_WORKERS ?= 2

.PHONY: setup fmu run test bench docs-images clean

$(BIN)/tirefilter: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test]'
	touch $@

setup: $(BIN)/tirefilter

fmu: setup
	$(BIN)/tirefilter fmu build vehicle

run: fmu
	$(BIN)/tirefilter run --scenario $(SCENARIO) --out $(OUT) --rrd $(OUT)/$(SCENARIO).rrd

test: fmu
	$(BIN)/python -m pytest tests -n $(TEST_WORKERS) --dist loadgroup

bench: fmu
	$(BIN)/python benchmarks/bench_cosim.py

docs-images: fmu
	$(BIN)/python tools/docs_images.py

clean:
	rm -rf fmu/build runs
