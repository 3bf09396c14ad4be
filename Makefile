# Set-up and everyday targets. Each target creates .venv on first use and installs once (stamp file).
#   make demo   run sparself on the bundled sample scene (samples/bird) -> demo_out/
#   make test   run the test suite: .venv/bin/python -m pytest -q tests
#   make bench  run the benchmarks in benchmarks/ (if any)
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
DEMO_SCENE ?= samples/bird
DEMO_OUT   ?= demo_out

.PHONY: demo test bench clean distclean install

install: $(STAMP)

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PIP) install $(TORCH_PIP_ARGS) "$(TORCH)"
	$(PIP) install -e ".[test]"
	touch $(STAMP)

demo: $(STAMP)
	mkdir -p $(DEMO_OUT)
	$(VENV)/bin/sparself info $(DEMO_SCENE)
	$(VENV)/bin/sparself plan $(DEMO_SCENE) --out $(DEMO_OUT)/plan.json --plot $(DEMO_OUT)/cameras.png --overwrite
	@echo "demo outputs in $(DEMO_OUT)/"

test: $(STAMP)
	$(PY) -m pytest -q tests

bench: $(STAMP)
	@set -e; found=0; for f in benchmarks/*.py; do \
	  [ -e "$$f" ] || continue; found=1; echo "== $$f"; $(PY) "$$f"; done; \
	  [ $$found = 1 ] || echo "no benchmarks yet (benchmarks/*.py)"

clean:
	rm -rf $(DEMO_OUT) .pytest_cache build dist
	find . -name __pycache__ -type d -not -path "./$(VENV)/*" -prune -exec rm -rf {} +

distclean: clean
	rm -rf $(VENV)
