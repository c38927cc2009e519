# Two commands on a fresh machine: `make run` (Table I) and `make test`.
# Both create .venv with pip when it is missing and install the project into it.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test results results-check clean-venv

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,cluster,rigid,hardware,docs]'
	@touch $(STAMP)

run: $(STAMP)
	$(BIN)/slot run experiment=perturb

# Two passes: the suite on every core (worksteal: an idle worker takes half of another's queue, so no long file
# holds the end up), then the real-time tests (marked serial: a servo emulator on a pseudo-terminal, the live
# view's pacing) alone.
test: $(STAMP) results-check
	$(BIN)/python -m pytest -q -n auto --dist worksteal -m "not serial"
	$(BIN)/python -m pytest -q -m serial

# Regenerate everything committed under results/ (about four and a half hours on 2 cores, most of it the identifications and the gait search),
# then render the results manual's tables (docs/results/) from what it wrote.
results: $(STAMP)
	$(BIN)/python scripts/make_results.py

# The results manual's tables against the result files (reads files, runs no simulation): fails naming the
# page and the table that differ; `slot manual` renders them.
results-check: $(STAMP)
	$(BIN)/slot manual --check

clean-venv:
	rm -rf $(VENV)
