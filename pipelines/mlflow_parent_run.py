"""The MLflow parent run of one pipeline invocation (``make reproduce``).

    python -m pipelines.mlflow_parent_run start [--name NAME]        # prints the new run's id
    python -m pipelines.mlflow_parent_run finish RUN_ID [--status N]  # logs results, ends the run
    python -m pipelines.mlflow_parent_run import [--parent RUN_ID]  # dvc.lock's results as (child) runs
    python -m pipelines.mlflow_parent_run url [--base http://127.0.0.1:5000]   # the UI's runs table

``make reproduce`` starts the parent, runs ``dvc repro`` with ``SRMPC_PARENT_RUN_ID`` set to its id (every
``python -m srmpc`` of a stage becomes a child run, tagged method, traffic and seed: srmpc/tracking.py)
and finishes it with ``dvc repro``'s exit status: 0 ends it FINISHED, anything else FAILED. ``finish``
logs as the parent's artifacts what exists of the paper's table (``table/``), the figures
(``figures/``), the episode videos (``videos/``) and the training summary (``training/``).
Between the two, ``import --parent RUN_ID`` logs every evaluation and training result that ``dvc.lock`` records as
a child run, once per stage hash (pipelines/mlflow_import.py), so a fresh clone's MLflow holds them all.
``url`` prints the runs table opened on the saved view ``results`` (the rows of ``results/table.json``, flat,
sorted by run name, with their tags and J_c, rho_c, J_r, n_steps, v_x), or, when no run is such a row yet,
on ``metrics`` (every run, with those columns): srmpc/tracking.py ``EXPERIMENT_TAGS``.
The tracking store and experiment are the ones ``python -m srmpc`` uses (``conf/tracking``), with
``tracking.*`` overrides passed after ``--``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from srmpc.config.compose import compose_config, to_objects
from srmpc.tracking import (
    METRICS_VIEW,
    RESULTS_FILTER,
    RESULTS_VIEW,
    TrackingStoreUnusable,
    check_tracking_store,
    ensure_experiment,
    finish_parent_run,
    runs_table_url,
    start_parent_run,
)

ROOT = Path(__file__).resolve().parents[1]

ARTIFACTS = (  # (artifact folder of the parent run, local file or folder)
    ("table", ROOT / "results" / "table.md"),
    ("table", ROOT / "results" / "table.json"),
    ("table", ROOT / "results" / "ablation.md"),
    ("figures", ROOT / "results" / "figures"),
    ("videos", ROOT / "results" / "videos"),
    ("training", ROOT / "results" / "training" / "summary.json"),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    start = commands.add_parser("start", help="create the parent run and print its id")
    start.add_argument("--name", default="pipeline", help="run name")
    finish = commands.add_parser("finish", help="log the results as artifacts and end the run")
    finish.add_argument("run_id")
    finish.add_argument("--status", type=int, default=0, help="exit status of what ran under the parent")
    imports = commands.add_parser("import", help="log dvc.lock's evaluation and training results as runs")
    imports.add_argument("--parent", default=None, help="the parent run's id (default: the runs stand alone)")
    url = commands.add_parser("url", help="print the UI's runs table of the experiment, on the results table's runs")
    url.add_argument("--base", default="http://127.0.0.1:5000", help="where the UI is served")
    args, overrides = parser.parse_known_args()
    overrides = [o for o in overrides if o != "--"]
    tracking = to_objects(compose_config([f"tracking.{o.removeprefix('tracking.')}" for o in overrides])).tracking
    try:
        check_tracking_store(tracking.uri)
    except TrackingStoreUnusable as error:
        print(f"mlflow_parent_run: error: {error}", file=sys.stderr)
        sys.exit(2)
    if args.command == "start":
        print(start_parent_run(tracking.uri, tracking.experiment_name, tracking.artifact_location, args.name,
                               {"stage": "pipeline"}))
    elif args.command == "import":
        import mlflow

        from pipelines.mlflow_import import import_results

        client = mlflow.MlflowClient(tracking_uri=tracking.uri)
        experiment_id = ensure_experiment(client, tracking.experiment_name, tracking.artifact_location)
        counts = import_results(client, experiment_id, args.parent)
        print("MLflow: {imported} results imported from dvc.lock, {skipped} already there, "
              "{superseded} earlier runs superseded; {table_rows_with_run} of the {table_rows} rows of "
              "results/table.json have their run".format(**counts))
    elif args.command == "finish":
        finish_parent_run(tracking.uri, args.run_id, ARTIFACTS, succeeded=args.status == 0)
    else:
        import mlflow

        client = mlflow.MlflowClient(tracking_uri=tracking.uri)
        experiment_id = ensure_experiment(client, tracking.experiment_name, tracking.artifact_location)
        has_table = client.search_runs([experiment_id], filter_string=RESULTS_FILTER, max_results=1)
        print(runs_table_url(args.base, experiment_id, RESULTS_VIEW if has_table else METRICS_VIEW))


if __name__ == "__main__":
    main()
