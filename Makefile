# `make run` and `make test` each create or reuse .venv and install the package with its
# test extras, so a fresh clone needs nothing else.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
OUT ?= out/run

# Offline by default: Meshcat may listen on localhost, nothing may be downloaded.
export DRAKE_ALLOW_NETWORK ?= meshcat
export MPLBACKEND ?= Agg

.PHONY: run test lint bench results clean

$(STAMP): pyproject.toml
	@# Drake's VTK renderer draws headless through EGL; Debian ships it as libegl1.
	@ldconfig -p | grep -q 'libEGL.so.1' || { command -v apt-get >/dev/null && \
	  (apt-get install -y -qq libegl1 libegl-mesa0 || { apt-get update -qq && apt-get install -y -qq libegl1 libegl-mesa0; }); } || \
	  { echo 'error: libEGL.so.1 is missing; install libegl1 (Debian/Ubuntu) for the simulated sensor'; exit 1; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	@# setuptools warns on every editable install that a folder named like the package shadows it:
	@# here that folder is the package itself, so the warning says nothing.
	PYTHONWARNINGS='ignore:Editable installation' $(BIN)/python -m pip install --quiet -e '.[test]'
	@# Compile the loop's numba kernels (the estimate, the map, the gains, the kinematics) into
	@# their on-disk cache now, about 30 s, which an episode would otherwise spend before it
	@# starts (it compiles what a cold cache lacks, core/kernels.py).
	$(BIN)/python -m lrnbv_drake.core.kernels
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/lrnbv run --planner lrnbv --object horizontal_box --seed 0 --out $(OUT) --overwrite

test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports
	$(BIN)/python -m pytest -n 2 -q

# The campaigns docs/results.md cites (benchmarks/campaigns/), their tables written into it.
results: $(STAMP)
	$(BIN)/lrnbv results

bench: $(STAMP)
	for b in benchmarks/bench_*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) out
	find lrnbv_drake -name __pycache__ -prune -exec rm -rf {} +
