# Two commands on a fresh machine: `make run` (Table I) and `make test`.
# Both create .venv with pip when it is missing and install the project into it.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test results clean-venv

$(STAMP): pyproject.toml
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test,cluster]'
	@touch $(STAMP)

run: $(STAMP)
	$(BIN)/slot run experiment=perturb

test: $(STAMP)
	$(BIN)/python -m pytest -q

# Regenerate everything committed under results/ (about two hours on 2 cores, most of it the gait search).
results: $(STAMP)
	$(BIN)/python scripts/make_results.py

clean-venv:
	rm -rf $(VENV)
