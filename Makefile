# `make demo` and `make test` each set up what is missing (scripts/setup.sh), then run.
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup test demo build check lint clean

setup:
	@bash scripts/setup.sh

build: setup
	$(BIN)/myriadc build specs/

lint: setup
	$(BIN)/ruff check .

check: setup
	$(BIN)/myriadc build specs/ --check

test: setup
	$(BIN)/ruff check .
	$(BIN)/myriadc build specs/ --check
	$(BIN)/python -m pytest

# The main job: the reference table of all 18 systems (published setting + best over all transcriptions),
# written to out/ as Markdown and JSON, with one plot per system.
demo: setup
	$(BIN)/myriadc build specs/ --check
	$(BIN)/myriadc list
	mkdir -p out
	$(BIN)/myriad bench --json out/bench.json --markdown out/bench.md --plots out/plots

clean:
	rm -rf $(VENV) build *.egg-info
