# The two entry points of the README: `make run` and `make test`.
# Both create the virtual environment .venv and install the project on first use.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
CORES ?= 2

.PHONY: setup run lint docs test test-slow smoke paper tables section4 section4-rows variant-table map committed clean

# envs/constraints.txt pins every package to the version the committed outputs were made with.
# uv installs them (several times faster than pip; BENCHMARKS.md, "Set-up"), taking pip's wheel
# where a version has two (envs/uv-wheels.txt); pip is the fallback where uv cannot be installed
# or fails (e.g. an index only pip's configuration names).
# --compile-bytecode: pip compiles the .pyc files at install, uv only when asked; without them
# every job compiles what it imports (seconds per job where PYTHONDONTWRITEBYTECODE is set).
UV_INSTALL = $(BIN)/pip install --quiet -c envs/constraints.txt uv \
	&& $(BIN)/uv pip install --quiet --compile-bytecode --python $(BIN)/python \
		-c envs/constraints.txt -c envs/uv-wheels.txt -e '.[test,cluster]'
PIP_INSTALL = $(BIN)/pip install --quiet --upgrade pip \
	&& $(BIN)/pip install --quiet -c envs/constraints.txt -e '.[test,cluster]'

$(STAMP): pyproject.toml envs/constraints.txt envs/uv-wheels.txt
	$(PYTHON) -m venv $(VENV)
	$(UV_INSTALL) || { echo "make setup: uv failed, installing with pip" >&2; $(PIP_INSTALL); }
	touch $(STAMP)

setup: $(STAMP)

# `make run CONFIG=my.yaml` runs another config file.
CONFIG ?= config/config.yaml
# Before Snakemake: one line for a missing, empty or malformed config file, and removal of a
# stale lock left by a killed run when no Snakemake process runs here (ssmobs/config/preflight.py).
PREFLIGHT := $(BIN)/python -m ssmobs.config.preflight --unlock-stale
# Every target resumes a killed run with the same command: --rerun-incomplete redoes the
# jobs a kill left half done (their outputs are also written atomically).
SNAKEMAKE := $(BIN)/snakemake --cores $(CORES) --rerun-incomplete

run: setup
	$(PREFLIGHT) $(CONFIG)
	$(SNAKEMAKE) $(if $(filter config/config.yaml,$(CONFIG)),,--configfile $(CONFIG))

# Style and types (ruff, snakefmt, mypy; settings in pyproject.toml) and the documentation
# site, built strictly (a broken link fails); `make test` runs it first.
lint: setup docs
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/snakefmt --check Snakefile workflow/rules
	$(BIN)/mypy

# The documentation site (mkdocs.yml, docs/) into site/; the configuration reference page
# must be the one the schema gives (`python -m ssmobs.config.reference` rewrites it), the
# profiles tables of README.md and config/README.md the generated one
# (`python -m ssmobs.config.profiles` rewrites them).
docs: setup
	$(BIN)/python -m ssmobs.config.reference --check
	$(BIN)/python -m ssmobs.config.profiles --check
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet

# `make test`: every test but the slow ones (marker `slow`: the mutation suite, the kill and
# damage tests, the cluster runs, the PyStan smoke run, and the rare paths that cost a compile
# or workflow runs: broken Stan programs, fresh-cache builds, read-only caches, live locks, the
# SLURM profile, the paper and tables profiles' dry runs, a broken own model, the analytic
# gradients of models other than Same; BENCHMARKS.md, "make test in five minutes") and those
# that build with PyStan (marker `pystan`: the second backend and the native backend's
# oracle); `make test-slow` runs those (CI runs both).
# Both run on $(CORES) worker processes (pytest-xdist); tests/conftest.py keeps each test
# module, and every module of the shared smoke run, on one worker, and starts the longest
# first (the mutation suite, the smoke run, the kernels test, ...) so that none ends alone.
test: setup lint
	$(BIN)/pytest -n $(CORES) --dist loadscope -m "not slow and not pystan"

test-slow: setup
	$(BIN)/pytest -n $(CORES) --dist loadscope -m "slow or pystan"

# `make smoke`: the smoke profile (every rule, tiny sizes).  `make smoke CONFIG=my.yaml`: that
# study on the smoke profile's sizes (ssmobs/config/smoke.py writes the overlay to
# results/smoke_configs/; its tables and figures go to paper_figures/smoke_<name>/).
SMOKE_OWN = $(filter-out config/config.yaml config/smoke.yaml,$(CONFIG))
SMOKE_CONFIG = $(if $(SMOKE_OWN),results/smoke_configs/$(basename $(notdir $(CONFIG))).yaml,config/smoke.yaml)

smoke: setup
	$(if $(SMOKE_OWN),$(BIN)/python -m ssmobs.config.smoke $(CONFIG) --out $(SMOKE_CONFIG))
	$(PREFLIGHT) $(SMOKE_CONFIG)
	$(SNAKEMAKE) --configfile $(SMOKE_CONFIG)

paper: setup
	$(PREFLIGHT) config/paper.yaml
	$(SNAKEMAKE) --configfile config/paper.yaml

# A committed reproduction: the preflight, then Snakemake under ssmobs.provenance, which writes
# provenance.json into the config's outputs_dir when the run succeeds.  Arguments: the config
# file, the command to record, the NAME of the variable holding the note (free text may
# contain commas) and optional Snakemake targets.
define with_provenance
	$(PREFLIGHT) $(1)
	$(BIN)/python -m ssmobs.provenance --config $(1) \
		--command "$(2)" --note "$($(3))" -- $(SNAKEMAKE) $(4) --configfile $(1)
endef

# Tables II, III and Figure 3 at the paper's settings, with a provenance file (committed).
TABLES_DIR := paper_figures/paper_settings
TABLES_TARGETS := $(foreach s,table2_joint_vs_marginal table3_coverage section4_summary,$(foreach e,csv md tex,$(TABLES_DIR)/$(s).$(e))) \
	$(foreach s,fig3_joint_vs_marginal $(foreach T,20 50,fig_exact_vs_stan_tables_same_a09_T$(T)),$(foreach e,pdf png,$(TABLES_DIR)/$(s).$(e))) \
	$(foreach T,20 50,$(foreach e,csv md,$(TABLES_DIR)/exact_vs_stan_tables_same_a09_T$(T).$(e)))
# free text for the provenance file (e.g. that Stan records of an earlier run were reused)
TABLES_NOTE ?=

tables: setup
	$(call with_provenance,config/tables.yaml,make tables,TABLES_NOTE,$(TABLES_TARGETS))

# One Section IV row at the paper's settings (issue 10), with a provenance file (committed);
# SECTION4_CONFIG=config/section4_rows/<row>.yaml for a row at the paper's iterations on a
# subset of its design set (issue 20). Its outputs go to the config's outputs_dir.
SECTION4_CONFIG := config/section4_sep_d2_p1.yaml
SECTION4_NOTE ?=
SECTION4_ROWS := $(sort $(wildcard config/section4_rows/*.yaml))

section4: setup
	$(call with_provenance,$(SECTION4_CONFIG),make section4 SECTION4_CONFIG=$(SECTION4_CONFIG),SECTION4_NOTE)

# Every row of config/section4_rows/, one after another (their committed runs took 8,518
# CPU-s, 2.3 CPU-hours, in all with the analytic gradients: each row's provenance.json).
section4-rows: setup
	set -e; for c in $(SECTION4_ROWS); do $(MAKE) --no-print-directory section4 SECTION4_CONFIG=$$c; done

# The variant x row table of Section IV (issue 20), from the committed studies that
# config/tables/stan_variants_by_row.yaml names (no sampling; seconds).
variant-table: setup
	$(PREFLIGHT) config/config.yaml
	$(SNAKEMAKE) stan_variant_table

# The observability maps (issue 21, ours), with a provenance file (committed).
MAP_CONFIG := config/map.yaml
MAP_NOTE ?=

map: setup
	$(call with_provenance,$(MAP_CONFIG),make map,MAP_NOTE)

# Any config whose outputs are committed (e.g. CONFIG=config/stoch_vol.yaml): the run with a
# provenance file in the config's outputs_dir.
NOTE ?=

committed: setup
	$(call with_provenance,$(CONFIG),make committed CONFIG=$(CONFIG),NOTE)

clean:
	rm -rf results .snakemake
