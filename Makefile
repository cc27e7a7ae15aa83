# srmpc: every target needs only python3 and make on PATH.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export PATH := $(abspath $(BIN)):$(PATH)

.PHONY: install reproduce test test-slow lint ui bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

## The main job: regenerate every result (DVC pipeline: spawn statistics, training, evaluation, table).
reproduce: install
	dvc repro

## The default test suite (slow tests excluded).
test: install
	python -m pytest

## Long tests (marked slow).
test-slow: install
	python -m pytest -m slow

lint: install
	ruff check srmpc tests pipelines benchmarks

## MLflow UI on http://127.0.0.1:5000 over the local SQLite store.
ui: install
	mlflow ui --backend-store-uri sqlite:///mlflow.db --default-artifact-root ./mlruns --host 127.0.0.1 --port 5000

clean:
	rm -rf $(VENV) .pytest_cache outputs multirun
