# The two entry points of the README: `make run` and `make test`.
# Both create the virtual environment .venv and install the project on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
CORES ?= 2

.PHONY: setup run test smoke paper clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e '.[test,cluster]'
	touch $(STAMP)

setup: $(STAMP)

# `make run CONFIG=my.yaml` runs another config file.
CONFIG ?= config/config.yaml
# Before Snakemake: one line for a missing, empty or malformed config file, and removal of a
# stale lock left by a killed run when no Snakemake process runs here (ssmobs/preflight.py).
PREFLIGHT := $(BIN)/python -m ssmobs.preflight --unlock-stale

run: setup
	$(PREFLIGHT) $(CONFIG)
	$(BIN)/snakemake --cores $(CORES) $(if $(filter config/config.yaml,$(CONFIG)),,--configfile $(CONFIG))

test: setup
	$(BIN)/pytest

smoke: setup
	$(PREFLIGHT) config/smoke.yaml
	$(BIN)/snakemake --cores $(CORES) --configfile config/smoke.yaml

paper: setup
	$(PREFLIGHT) config/paper.yaml
	$(BIN)/snakemake --cores $(CORES) --configfile config/paper.yaml

clean:
	rm -rf results .snakemake
