# skyrig — two commands: `make demo` and `make test`. Both create the environment first.
PYTHON ?= python3.11
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test test-all env bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

env: $(STAMP)

demo: $(STAMP)
	$(BIN)/skyrig demo -o demo-output

test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 -m 'not slow' tests

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 tests

bench: $(STAMP)
	$(BIN)/python bench/georef.py
	$(BIN)/python examples/ign_world_to_image.py
	$(BIN)/python bench/simulate.py
	OMP_NUM_THREADS=1 $(BIN)/python bench/lidar.py
	$(BIN)/python bench/ign_block.py

clean:
	rm -rf $(VENV) demo-output
