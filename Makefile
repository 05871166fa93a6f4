# `make demo` and `make test` each set up what is missing (scripts/setup.sh), then run.
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: setup test test-fast demo build check lint clean cards docs

setup:
	@bash scripts/setup.sh

build: setup
	$(BIN)/myriadc build specs/
	$(BIN)/myriadc build specs/peers -o runtime/systems/peers
	$(BIN)/myriadc card specs/ -o docs/cards

lint: setup
	$(BIN)/ruff check .

check: setup
	$(BIN)/myriadc build specs/ --check
	$(BIN)/myriadc build specs/peers -o runtime/systems/peers --check
	$(BIN)/myriadc card specs/ -o docs/cards --check

test: setup
	$(BIN)/ruff check .
	$(BIN)/myriadc build specs/ --check
	$(BIN)/myriadc build specs/peers -o runtime/systems/peers --check
	$(BIN)/myriadc card specs/ -o docs/cards --check
	$(BIN)/python -m pytest -n 2 --dist loadfile --durations=25  # two workers, a file each; the 25 slowest tests listed

# What a developer runs while working: every test but those marked slow (tests/README.md), under 2 minutes on 2 cores.
# A file per worker, as in make test: a module's fixtures and compiled programs are built once.
test-fast: setup
	$(BIN)/python -m pytest -n 2 --dist loadfile -m "not slow"

# The main job: the reference table of all 18 systems (published setting + best over all transcriptions),
# written to out/ as Markdown and JSON, with one plot per system.
demo: setup
	$(BIN)/myriadc build specs/ --check
	$(BIN)/myriadc list
	mkdir -p out
	$(BIN)/myriad bench --json out/bench.json --markdown out/bench.md --plots out/plots

# The problem cards' recorded results and plots (docs/cards/results.json, img/): solves every system, then re-renders.
cards: setup
	$(BIN)/python -m bench.cards

# The user's guide and the API reference from the docstrings (mkdocs-material + mkdocstrings) into site/; --strict:
# a reference, page or link that does not resolve fails the build (tests/test_docs.py builds it too).
docs: setup
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

clean:
	rm -rf $(VENV) build site *.egg-info
