# srmpc: every target needs only python3 and make on PATH.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export PATH := $(abspath $(BIN)):$(PATH)

.PHONY: install reproduce videos test test-slow lint ui bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

## The main job: regenerate every result (DVC pipeline: spawn statistics, training, evaluation, table,
## figures, videos), then the smoke experiment; always ends by printing results/table.md.
## Committed results make `dvc repro` a no-op; `make reproduce FORCE=1` runs `dvc repro --force` (every stage).
## Every stage's MLflow run is a child of one parent run (pipelines/mlflow_parent_run.py), which gets the table,
## figures and videos as artifacts; then every evaluation and training result in dvc.lock that MLflow lacks
## is imported as a child run (pipelines/mlflow_import.py), so a fresh clone's MLflow holds them all.
FORCE ?=
reproduce: install
	@parent=$$(python -m pipelines.mlflow_parent_run start --name "make reproduce$(if $(FORCE), FORCE=1)") \
	  && echo "MLflow parent run $$parent (make ui)" || parent=""; \
	SRMPC_PARENT_RUN_ID=$$parent dvc repro $(if $(FORCE),--force); status=$$?; \
	[ -z "$$parent" ] || python -m pipelines.mlflow_parent_run import --parent $$parent || status=$$?; \
	[ -z "$$parent" ] || python -m pipelines.mlflow_parent_run finish $$parent --status $$status; \
	if [ $$status -eq 0 ]; then python -m srmpc +experiment=smoke || status=$$?; fi; \
	echo; echo "== results/table.md =="; cat results/table.md; \
	exit $$status

## The episode videos alone (results/videos/, DVC stage `videos`).
videos: install
	dvc repro --single-item videos

## The default test suite (slow tests excluded), on every core (pytest-xdist, one test file per worker at a time),
## after numba's cache is filled once (srmpc/precompile.py), so that the workers do not each compile the same kernels.
test: install
	python -m srmpc.precompile
	python -m pytest -n auto --dist loadfile

## Long tests (marked slow).
test-slow: install
	python -m pytest -m slow

lint: install
	ruff check srmpc tests pipelines benchmarks

## MLflow UI on http://127.0.0.1:5000 over the local SQLite store. The printed URL opens the runs table on
## the results: one row per method and traffic of results/table.json with J_c, rho_c, J_r, n_steps, v_x
## (saved view "Results table"; before any `make reproduce`, every run with those columns).
ui: install
	@echo "Results: $$(python -m pipelines.mlflow_parent_run url 2>/dev/null)"
	mlflow ui --backend-store-uri sqlite:///mlflow.db --default-artifact-root ./mlruns --host 127.0.0.1 --port 5000

clean:
	rm -rf $(VENV) .pytest_cache outputs multirun
