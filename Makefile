# Fresh clone -> working environment. Every target creates .venv on first use, from the lock file.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
LOCK   := requirements.lock
# pytest workers: the machine's cores (2 here); WORKERS=0 runs in one process
WORKERS ?= auto
# one BLAS thread per process: the pytest workers (or the studies' worker processes) use the cores, and
# OpenBLAS's own threads would compete with them and spin (tests/conftest.py sets the same for a bare pytest)
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1

.PHONY: run test check layers comments bench docs docs-regen docs-check check-install lock clean

$(STAMP): pyproject.toml $(LOCK)
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c $(LOCK) -e ".[test,arviz,docs]"
	touch $(STAMP)

run: $(STAMP)        ## the main job: the Coulomb-friction study on the bundled real data (quick variant)
	$(VENV)/bin/seqbayes example coulomb --quick --out coulomb_results

test: $(STAMP) layers ## the whole test suite (every tier), in parallel over the cores; prints the slowest tests (wall and CPU)
	$(PY) -m pytest -q -n $(WORKERS) --durations=15 --cpu-durations=15

check: $(STAMP) layers ## the fast tier for the working loop: unit tests not marked slow, under 45 s on 2 idle cores
	$(PY) -m pytest -q -n $(WORKERS) -m "not slow" tests/unit

comments: $(STAMP)   ## source comments holding run results or history (tests/unit/test_check_comments.py runs it in CI)
	$(PY) tools/check_comments.py

layers: $(STAMP)     ## the import-layers contract (.importlinter): no cycles, no upward imports
	$(VENV)/bin/lint-imports --no-cache

bench: $(STAMP)       ## benchmarks against emcee, particles, filterpy, pocomc (installs the bench extra)
	$(PY) -m pip install --quiet -c $(LOCK) -e ".[bench]"
	$(PY) -m pip install --quiet --no-deps "particles>=0.4"   # its numpy<2 pin would break pandas 3
	for script in benchmarks/bench_*.py; do echo "== $$script"; $(PY) $$script || exit 1; done

docs: $(STAMP)        ## the documentation site (API reference from docstrings), strict
	$(VENV)/bin/mkdocs build --strict --site-dir site

docs-regen: $(STAMP)  ## rewrite the guide's outputs and the docs' generated tables and figures from a rerun
	OPENBLAS_NUM_THREADS=1 $(PY) tools/docgen.py --write

docs-check: $(STAMP)  ## rerun the full studies behind the docs' generated tables (about 10 CPU minutes); fails if one differs
	OPENBLAS_NUM_THREADS=1 $(PY) tools/docgen.py sections

check-install:       ## a clean venv with only the built wheel (no extras) runs examples and a run-store cycle
	bash .ci/clean_install

lock:                ## re-resolve every dependency to today's newest and rewrite the lock (a deliberate commit)
	rm -rf .lockenv
	$(PYTHON) -m venv .lockenv
	.lockenv/bin/python -m pip install --quiet --upgrade pip
	.lockenv/bin/python -m pip install --quiet ".[test,arviz,docs]"
	{ sed -n '1,3p' $(LOCK); .lockenv/bin/pip freeze --exclude-editable | grep -v '^seqbayes'; } > $(LOCK).new
	mv $(LOCK).new $(LOCK)
	rm -rf .lockenv

clean:
	rm -rf $(VENV) build *.egg-info
