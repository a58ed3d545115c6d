# Fresh clone -> working environment. Every target creates .venv on first use.
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: run test bench docs clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[test,bench,arviz,docs]"
	touch $(STAMP)

run: $(STAMP)        ## the main job: the Coulomb-friction study on the bundled real data (quick variant)
	$(VENV)/bin/seqbayes example coulomb --quick --out coulomb_results

test: $(STAMP)       ## the whole test suite
	$(PY) -m pytest -q

bench: $(STAMP)
	$(PY) benchmarks/run_all.py

clean:
	rm -rf $(VENV) build *.egg-info
