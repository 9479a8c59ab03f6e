# Fresh-machine entry points. Every target builds the local virtual environment first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= results

.PHONY: venv compare lint test bench clean

venv: $(STAMP)

# torch first, pinned to 2.13.0, so stable-baselines3 does not pull a newer (CUDA) build. pip takes
# the CPU build where its configuration finds one (this project's machines: a local wheel); from
# PyPI alone torch==2.13.0 is a CUDA build of several GB: there, give the CPU index, e.g.
# make test TORCH_INDEX=https://download.pytorch.org/whl/cpu
TORCH_INDEX ?=
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet torch==2.13.0 $(if $(TORCH_INDEX),--index-url $(TORCH_INDEX))
	$(BIN)/pip install --quiet -e '.[rl,ray,plots,video,bench,logs,dev]'
	touch $(STAMP)

compare: $(STAMP)
	$(BIN)/fourwis compare --out $(OUT)/compare

# ruff's lint and format rules (pyproject.toml); the import-layer contracts run in the tests
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

test: lint
	$(BIN)/python -m pytest -q -n 2 --dist loadgroup tests

bench: $(STAMP)
	$(BIN)/fourwis bench

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info .numba_cache
