# Fresh-machine entry points. Every target builds the local virtual environment first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= results

.PHONY: venv compare test bench clean

venv: $(STAMP)

# torch first, pinned to the local CPU build, so stable-baselines3 does not pull a CUDA build.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e '.[rl,plots,video,bench,dev]'
	touch $(STAMP)

compare: $(STAMP)
	$(BIN)/fourwis compare --out $(OUT)/compare

test: $(STAMP)
	$(BIN)/python -m pytest -q -n 2 tests

bench: $(STAMP)
	$(BIN)/fourwis bench

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info .numba_cache
