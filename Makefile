# Quick start: `make demo` (main job on the embedded defaults) and `make test`. Each creates .venv on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint bench sim-demo docs clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install --upgrade --quiet --no-cache-dir pip
	# torch first and pinned: the local CPU-usable wheels, never a fresh multi-GB download by a resolver. The x86_64
	# 2.14.1 wheel is a CUDA build: ~5.6 GB in .venv. --no-cache-dir: no second copy of the downloads in ~/.cache/pip
	$(BIN)/pip install --quiet --no-cache-dir torch==2.14.1 torchvision==0.29.1
	$(BIN)/pip install --quiet --no-cache-dir -e '.[dev,robot,mujoco,docs]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/python train.py experiment=smoke

sim-demo: $(STAMP)
	$(BIN)/python -m tvrecon.sim press --shape torus --direction 0 0 -1 --out outputs/sim_demo

test: $(STAMP)
	# one worker per core (pytest-xdist; work stealing, so the two long compile tests do not end the run alone), one
	# torch thread each: the workers would otherwise oversubscribe the cores
	OMP_NUM_THREADS=1 $(BIN)/python -m pytest -q -n auto --dist worksteal

docs: $(STAMP)
	$(BIN)/mkdocs build --strict

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/python -m benchmarks.run

clean:
	rm -rf outputs multirun lightning_logs .pytest_cache site
