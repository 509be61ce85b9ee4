# Two commands on a fresh machine with Python 3.11: `make bench` and `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
TORCH ?= torch==2.13.0
TGT ?= torch-geometric-temporal==0.56.2

.PHONY: install bench test lint benchmarks tables compact-results docs clean wheel-check min-check

# Two installs into the one venv, each with its own stamp, so neither undoes the other: `make bench` installs what the
# bench needs (torch, then the package alone); `make test` (and every target below that needs the tools) upgrades the
# same venv with the extras. A change to pyproject.toml or constraints.txt redoes both, in that order.
BENCH_STAMP := $(VENV)/.installed-bench
TEST_STAMP := $(VENV)/.installed-test

$(BENCH_STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	# torch first: the CPU build on disk; a looser requirement would drag in several GB of CUDA packages
	$(BIN)/python -m pip install -q "$(TORCH)"
	# the package and its runtime dependencies, no extra: all `tactile-zoo bench` on the simulators needs
	$(BIN)/python -m pip install -q -c constraints.txt -e .
	touch $@

$(TEST_STAMP): $(BENCH_STAMP)
	# [test] holds every optional extra ([export]: onnx, onnxscript and onnxruntime, so the suite checks every ONNX
	# export; [docs]: mkdocs-material and mkdocstrings, so the suite builds the docs site)
	$(BIN)/python -m pip install -q -c constraints.txt -e ".[test]"
	# x_tacformer's temporal_backend="tgt": --no-deps, its release requires torch-sparse (source-only, does not build
	# against this torch); the one module we load (TGCN2) needs only torch and torch-geometric, installed above
	$(BIN)/python -m pip install -q --no-deps "$(TGT)"
	touch $@

# the published set that `tactile-zoo study compare` reads: package data built from the committed cells (results are
# committed in benchmarks/results only), 10 s; setup.py refuses to build a wheel without it
PUBLISHED_SET := tactile_zoo/published/table1-v1.json.gz
$(PUBLISHED_SET): $(BENCH_STAMP)
	$(BIN)/python -m tools.published_set > /dev/null

# the full install: the package with every extra and the tools (what `make test`, lint, docs and the checks need)
install: $(TEST_STAMP) $(PUBLISHED_SET)

bench: $(BENCH_STAMP)
	$(BIN)/tactile-zoo bench --models all --executor process --workers 2

test: install
	# the checkout's modules compiled once (1 s) for the suite's child interpreters: where PYTHONDONTWRITEBYTECODE is
	# set, each child would compile every module of the package it imports again
	$(BIN)/python -m compileall -q -j 0 tactile_zoo tests benchmarks tools examples plugins hubconf.py > /dev/null
	# numba's kernels compiled into their on-disk cache in the background while pytest collects (a fresh checkout
	# has none, and both workers would compile the same kernels at once): tools/warm_kernels.py
	OMP_NUM_THREADS=1 $(BIN)/python -m tools.warm_kernels > /dev/null 2>&1 &
	# one BLAS/OpenMP thread per xdist worker: two workers on two cores, no oversubscription
	OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -q -n 2 --dist loadgroup

# CI, after `make test`: the built sdist and wheels, installed into a fresh virtualenv outside the checkout
wheel-check: install
	BASE_PYTHON=$(PYTHON) .ci/wheel-check $(BIN)/python

# the declared minimum versions (constraints-min.txt) in a fresh virtualenv, running the smoke subset (tests/smoke.txt)
MIN_VENV ?= $(or $(TMPDIR),/tmp)/tactile-zoo-min-venv
min-check:
	$(PYTHON) -m venv $(MIN_VENV)
	$(MIN_VENV)/bin/python -m pip install -q "$(TORCH)"
	$(MIN_VENV)/bin/python -m pip install -q --only-binary=:all: -c constraints-min.txt -c constraints.txt \
		-e ".[export,dask,keras]" "pytest>=7" "hypothesis>=6"
	OMP_NUM_THREADS=1 $(MIN_VENV)/bin/python -m pytest -q -p no:cacheprovider $$(grep -v '^#' tests/smoke.txt)

lint: install
	$(BIN)/ruff check tactile_zoo tests benchmarks examples plugins

benchmarks: install
	$(BIN)/python -m benchmarks.run $(BENCHMARK_ARGS)

# store the committed results' cell records compact (cells/<id>.json.gz), each verified first (issue 51)
compact-results: install
	$(BIN)/python -m tactile_zoo.bench.compact benchmarks/results

# every generated page, checked by the suite: after committing new cells, the fidelity ledger and the published result
# tables from the studies (README headline, docs/table1.md, docs/published-results.md, the results index); after
# changing a command's flags, the command-line reference (docs/cli.md); after adding or changing a model's registry
# metadata, the model pages (models table, citing, CITATION.cff, API page, counts)
tables: install
	$(BIN)/python -m tools.model_pages
	$(BIN)/python -m tools.fidelity
	$(BIN)/python -m tools.published_tables
	$(BIN)/python -m tools.cli_reference

# the docs site, into site/ (gitignored); --strict: a broken link or anchor, or a page left out of the nav, fails
docs: install
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

clean:
	rm -rf $(VENV) build site *.egg-info
