# Two commands set everything up: `make demo` and `make test` (see README.md).
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.taskrl-installed
TEST_WORKERS ?= 2

.PHONY: demo test test-fast docs lint install clean bench

# torch is pinned first so the project's `torch>=2.3` is satisfied by the local CPU build
# instead of pulling a multi-GB CUDA build.
$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[test,bench,robotics,language,metaworld,video,imitation,distributed,docs,wandb,grasp]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	rm -rf runs/demo
	$(VENV)/bin/taskrl train bitflip-her --out runs/demo

lint: $(STAMP)
	$(VENV)/bin/ruff check src tests benchmarks
	$(VENV)/bin/ruff format --check src tests benchmarks

# the documentation site, strictly: a broken link or an undocumented docstring parameter fails
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(VENV)/bin/mkdocs build --strict

# the suite in TEST_WORKERS processes (tests that start Ray share one: tests/test_distributed.py's ON_RAY)
test: lint docs
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadgroup --durations=15

# everything but the tests marked slow (learning gates, Ray, compiling, videos, Meta-World)
test-fast: lint
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadgroup -m "not slow" --durations=10

clean:
	rm -rf $(VENV) runs .pytest_cache site
