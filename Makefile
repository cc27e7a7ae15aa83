# srmpc: every target needs only python3 and make on PATH.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export PATH := $(abspath $(BIN)):$(PATH)

.PHONY: install lock reproduce videos check test test-slow lint ui bench clean

## Exactly the versions of requirements.lock, every file checked against its hash, then srmpc itself, resolving
## nothing (`--no-deps`; `--no-build-isolation`: built with the locked setuptools). `--retries 0`: an index that
## cannot be reached (PyTorch's, offline) is skipped at once instead of retried for every package.
$(STAMP): pyproject.toml requirements.lock
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet --retries 0 --require-hashes --no-deps -r requirements.lock
	$(BIN)/python -m pip install --quiet --no-deps --no-build-isolation -e .
	touch $(STAMP)

install: $(STAMP)

## Rewrite requirements.lock from pyproject.toml: pip's own resolver, ignoring what is installed, reports every package
## `pip install -e '.[dev,nmpc]'` would install (version, file hash); .ci/lock.py writes them. Then `make install`.
LOCK_RESOLVE := pip install --dry-run --ignore-installed --quiet --extra-index-url https://download.pytorch.org/whl/cpu
lock:
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	report=$$(mktemp) && trap 'rm -f "$$report"' EXIT \
	  && $(BIN)/python -m $(LOCK_RESOLVE) --retries 0 --report "$$report" -e '.[dev,nmpc]' \
	  && $(BIN)/python .ci/lock.py "$$report" requirements.lock "$(LOCK_RESOLVE) --report REPORT -e '.[dev,nmpc]'"

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

## Does this repository reproduce on this machine? The first episodes of every committed evaluation and the first
## iterations of every training, recomputed and compared with the committed rows (pipelines/spot_check.py; minutes).
check: install
	python -m pipelines.spot_check

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
## (saved view "Results table"; before any `make reproduce`, every run with those columns). Without MLflow's job
## runner (MLFLOW_SERVER_ENABLE_JOB_EXECUTION=false): its 8 processes run GenAI jobs (LLM judges, prompt optimization).
ui: install
	@echo "Results: $$(python -m pipelines.mlflow_parent_run url 2>/dev/null)"
	MLFLOW_SERVER_ENABLE_JOB_EXECUTION=false \
	  mlflow ui --backend-store-uri sqlite:///mlflow.db --default-artifact-root ./mlruns --host 127.0.0.1 --port 5000

clean:
	rm -rf $(VENV) .pytest_cache outputs multirun
