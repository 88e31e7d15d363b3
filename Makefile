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

run: setup
	$(BIN)/snakemake --cores $(CORES)

test: setup
	$(BIN)/pytest

smoke: setup
	$(BIN)/snakemake --cores $(CORES) --configfile config/smoke.yaml

paper: setup
	$(BIN)/snakemake --cores $(CORES) --configfile config/paper.yaml

clean:
	rm -rf results .snakemake
