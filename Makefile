# `make demo` and `make test` each set up what is missing (scripts/setup.sh), then run.
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup test demo build check clean

setup:
	@bash scripts/setup.sh

build: setup
	$(BIN)/myriadc build specs/

check: setup
	$(BIN)/myriadc build specs/ --check

test: setup
	$(BIN)/myriadc build specs/ --check
	$(BIN)/python -m pytest

demo: setup
	$(BIN)/myriadc build specs/ --check
	$(BIN)/myriadc list

clean:
	rm -rf $(VENV) build *.egg-info
