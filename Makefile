# Set-up and everyday targets. Each target creates .venv on first use and installs once (stamp file).
#   make demo   densify the bundled sample capture (samples/bird: photos -> poses -> plan -> train
#               -> synthesize) -> demo_out/
#   make evaluate  held-out evaluation of the sample, quick settings -> eval_out/
#   make lint   formatting, lint and type check: ruff format --check, ruff check, mypy (pyproject.toml)
#   make test   run the test suite on every core (at most 4): .venv/bin/python -m pytest tests -n auto ...
#   make bench  speed and memory table: .venv/bin/python benchmarks/run.py
#   make clean  remove demo output and caches (keeps .venv; `make distclean` removes it too)

PYTHON   ?= python3
VENV     ?= .venv
PY       := $(VENV)/bin/python
PIP      := $(PY) -m pip
STAMP    := $(VENV)/.sparself-installed
# torch is pinned and installed FIRST: an unpinned torch requirement can pull a multi-GB CUDA build.
# On a machine without a local CPU wheel, add the PyTorch CPU wheel index, e.g.
#   make test TORCH_PIP_ARGS="--index-url <PyTorch CPU wheel index URL>"
TORCH    ?= torch==2.13.0
TORCH_PIP_ARGS ?=

# The demo: change these to change what `make demo` runs.
DEMO_SCENE  ?= samples/bird
DEMO_OUT    ?= demo_out
DEMO_SIZE   ?= 240
DEMO_EPOCHS ?= 30
EVAL_OUT    ?= eval_out

.PHONY: demo evaluate lint test bench clean distclean install

install: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install $(TORCH_PIP_ARGS) "$(TORCH)"
	$(PIP) install -e ".[test]"
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/sparself densify $(DEMO_SCENE)/images --out $(DEMO_OUT) --out-size $(DEMO_SIZE) \
	  --epochs $(DEMO_EPOCHS) --seed 0 --overwrite
	$(VENV)/bin/sparself info $(DEMO_OUT)/scene
	@echo "demo: dense scene in $(DEMO_OUT)/scene (COLMAP sparse/0, poses_bounds.npy, transforms.json),"
	@echo "      the synthesized views the 3DGS self-check kept, if any paid: $(DEMO_OUT)/scene/images/*novel_*, marked in"
	@echo "      sparself.json (its 'selfcheck' entry says which views paid, by how much, and why the others were dropped;"
	@echo "      'info' above counts them: with none kept the scene is the photos alone);"
	@echo "      plan and camera plot in $(DEMO_OUT)/"

# held-out evaluation of the sample (minutes on a CPU with --quick; see README)
evaluate: $(STAMP)
	$(VENV)/bin/sparself evaluate $(DEMO_SCENE) --out $(EVAL_OUT) --quick --overwrite

lint: $(STAMP)
	$(VENV)/bin/ruff format --check src tests benchmarks
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/mypy

test: $(STAMP)
	$(PY) -m pytest tests -n auto --maxprocesses 4 --dist worksteal --durations=10

bench: $(STAMP)
	$(PY) benchmarks/run.py

clean:
	rm -rf $(DEMO_OUT) $(EVAL_OUT) .pytest_cache build dist
	find . -name __pycache__ -type d -not -path "./$(VENV)/*" -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
