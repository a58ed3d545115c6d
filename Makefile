# Fresh clone -> working environment. Every target creates .venv on first use.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: run test bench docs docs-regen check-install clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test,arviz,docs]"
	touch $(STAMP)

run: $(STAMP)        ## the main job: the Coulomb-friction study on the bundled real data (quick variant)
	$(VENV)/bin/seqbayes example coulomb --quick --out coulomb_results

test: $(STAMP)       ## the whole test suite
	$(PY) -m pytest -q

bench: $(STAMP)       ## benchmarks against emcee, particles, filterpy, pocomc (installs the bench extra)
	$(PY) -m pip install --quiet -e ".[bench]"
	$(PY) -m pip install --quiet --no-deps "particles>=0.4"   # its numpy<2 pin would break pandas 3
	for script in benchmarks/bench_*.py; do echo "== $$script"; $(PY) $$script || exit 1; done

docs: $(STAMP)        ## the documentation site (API reference from docstrings), strict
	$(VENV)/bin/mkdocs build --strict --site-dir site

docs-regen: $(STAMP)  ## rewrite the guide's outputs and the docs' generated tables and figures from a rerun
	OPENBLAS_NUM_THREADS=1 $(PY) tools/docgen.py --write

check-install:       ## a clean venv with only the built wheel (no extras) runs examples and a run-store cycle
	bash .ci/clean_install

clean:
	rm -rf $(VENV) build *.egg-info
