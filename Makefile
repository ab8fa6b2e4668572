# fwdlook: strict make.  `make help` lists the targets.
SHELL := bash
.SHELLFLAGS := -eu -o pipefail -c
.DEFAULT_GOAL := help
MAKEFLAGS += --warn-undefined-variables --no-builtin-rules

PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
SCENARIO ?= scenarios/paper_fig6_a50.yaml
RUN_DIR ?= runs/default
CONFIG ?= configs/tracking.yaml
SCALE ?= full

.PHONY: help install bytecode run test test-slow bench reproduce clean

help: ## list the targets
	@grep -E '^[a-z-]+:.*## ' $(MAKEFILE_LIST) | awk -F':.*## ' '{printf "  make %-10s %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,xarray,dask]'
	touch $(STAMP)

install: $(STAMP) ## create .venv and install fwdlook (editable) with its test, xarray and dask extras

# fwdlook's own modules byte-compiled where they lie (io/painter's child and every command import them): a shell
# with PYTHONDONTWRITEBYTECODE set (this project's sandboxes set it) had every command compile them from source,
# 0.13-0.15 s of a `fwdlook process` of the paper cube (README, Speed); only changed files are compiled again
bytecode: $(STAMP) ## byte-compile fwdlook's modules (run, test, bench and reproduce do it first)
	@$(BIN)/python -m compileall -q fwdlook_cli

run: bytecode ## simulate and process the default scenario end to end (SCENARIO=, CONFIG=, RUN_DIR=)
	$(BIN)/fwdlook run $(SCENARIO) -c $(CONFIG) -o $(RUN_DIR)
	$(BIN)/fwdlook info $(RUN_DIR)/raw.h5
	@echo "image: $(RUN_DIR)/image.png  metrics: $(RUN_DIR)/metrics.json  stages: $(RUN_DIR)/stages/"

test: bytecode ## run the test suite (fast tests; a few minutes on 2 cores)
	$(BIN)/python -m pytest -q

test-slow: bytecode ## the slow tests only: every lattice target placed, on the three paper scenarios
	$(BIN)/python -m pytest -q -m slow

bench: bytecode ## timings in one process on the paper cube
	$(BIN)/fwdlook bench

reproduce: bytecode ## the papers' tables and figures beside ours (SCALE=quick|full) in reports/reproduce
	$(BIN)/python -m fwdlook_cli.report.reproduce --out reports/reproduce --scale $(SCALE)

clean: ## remove generated outputs (keeps .venv)
	rm -rf runs reports .pytest_cache .hypothesis
