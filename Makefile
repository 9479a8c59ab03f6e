# Fresh-machine entry points. Every target builds the local virtual environment first.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= results

.PHONY: venv compare lint test bench docs serve-docs side-by-side clean

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
	$(BIN)/pip install --quiet -e '.[rl,ray,plots,video,bench,docs,logs,dev]'
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

# the results pages (docs/results/) from measured runs, then the site (build/site/); REUSE=1 reads
# the jobs' saved outputs in build/results/ where they exist
docs: $(STAMP)
	$(BIN)/python docs/generate.py $(if $(REUSE),--reuse)
	$(BIN)/mkdocs build --strict

serve-docs: $(STAMP)
	$(BIN)/mkdocs serve

# two versions' benchmarks in one run: make side-by-side BEFORE=<commit, branch or tag>
side-by-side: $(STAMP)
	$(BIN)/python benchmarks/side_by_side.py --before $(BEFORE) --out docs/results/side-by-side.md

clean:
	rm -rf $(VENV) $(OUT) build *.egg-info .numba_cache
