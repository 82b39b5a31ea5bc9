# rfir: every target sets up what it needs first (a fresh machine needs nothing but `make`).
VENV   ?= .venv
PY     := $(VENV)/bin/python
RFIR   := $(VENV)/bin/rfir
STAMP  := $(VENV)/.rfir-setup
DEPS   := pyproject.toml setup.py scripts/setup.sh $(wildcard ext/csrc/*)
DEMO   ?= demo_out

.PHONY: setup demo test test-all bench lint clean reproduce reproduce-quick \
	reproduce-rcs reproduce-rcs-po reproduce-wideband reproduce-rssi reproduce-extrapolation reproduce-edit reproduce-ablation \
	reproduce-diagnose reproduce-fullwave reproduce-measured

setup: $(STAMP)

$(STAMP): $(DEPS)
	bash scripts/setup.sh
	touch $(STAMP)

## The built-in demo: every stage that exists so far, at demo size.
demo: setup
	bash scripts/demo.sh $(DEMO)

## Fast default suite (slow end-to-end runs are deselected; `make test-all` runs them too).
test: setup
	$(PY) -m pytest -q

test-all: setup
	$(PY) -m pytest -q -m "slow or not slow"

## Paper-shaped tables: the Snakemake workflow (workflow/Snakefile) runs data, rfir and every baseline on
## the same splits -> results/reproduce/<target>.{md,csv,png,json}; data and fits in data/reproduce/.
## Steps rerun when their command, code or inputs changed. SMKARGS: more Snakemake options
## (-n: dry run; --forceall: rerun everything; --profile workflow/profiles/slurm: on a cluster).
SMK := $(VENV)/bin/snakemake -s workflow/Snakefile
reproduce: setup
	$(SMK) all $(SMKARGS)
reproduce-quick: setup
	$(SMK) all --config quick=true $(SMKARGS)
reproduce-rcs reproduce-rcs-po reproduce-wideband reproduce-rssi reproduce-extrapolation reproduce-edit reproduce-ablation reproduce-diagnose reproduce-fullwave reproduce-measured: setup
	$(SMK) $(patsubst reproduce-%,%,$@) $(SMKARGS)

bench: setup
	@for b in bench/bench_*.py; do echo "== $$b"; $(PY) $$b || exit 1; done

lint: setup
	$(VENV)/bin/python -m pip install -q ruff && $(VENV)/bin/ruff check src stages ext tests

clean:
	rm -rf build *.egg-info ext/rfir_tracer/*.so $(DEMO)
