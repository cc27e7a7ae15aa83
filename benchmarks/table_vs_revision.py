"""Every cell of the paper's table now against the same cell at another git revision, paired on the seeds.

    python benchmarks/table_vs_revision.py --revision <commit> [--out results/benchmarks/table_vs_revision.json]

A change that alters floating-point results (a faster solver, a new kernel) regenerates every evaluation;
this says whether the table moved more than its own noise. For each traffic level and each method of
``pipelines/reporting.py`` (the episodes of ``results/evaluation/twin/<method>_<traffic>`` and
``results/evaluation/confirmation/srmpc_recommended_<traffic>``), it reads that ``episodes.csv`` in the
working tree ("after") and at ``--revision`` (``git show``, "before"), and gives per metric (J_r, J_c,
n_steps, v_x):

- ``before`` and ``after``, each with its 95% interval (as the table computes it);
- ``paired``: the mean of after - before over the episodes run from the same seed, with its 95% bootstrap
  interval (``srmpc.confidence_intervals.paired_differences``, the table's resamples and seed);
- ``agrees``: the paired interval contains 0, and each value lies in the other's interval;
- ``identical_episodes``: how many episodes gave exactly the same row (all four metrics).

``all_agree`` is true when every cell of the table agrees. Nothing here is a test: a cell that moves is a finding.
The pairing is ``pipelines/revision_pairing.py``'s, which ``python -m pipelines.reproduction_check`` shares.

The same comparison for every other evaluation under ``results/evaluation/<group>/<name>_<traffic>`` (the
operating point's, the NMPC's, the trade-off's, ...), keyed by experiment and traffic under ``experiments``
(``experiments_all_agree``, and ``moved``: the cells that do not agree, ``experiment traffic metric``); an
evaluation that the revision does not have is listed under ``new``. ``counts``: evaluations compared, those
identical in every episode, those with a metric that moved, metric cells compared and moved, and new ones.

``--after DIR`` takes "after" from another checkout's working tree instead of this one: the results that
``dvc repro`` regenerated there (on another machine, from nothing: ``benchmarks/pipeline_time.py --keep``'s clone)
against the committed ones (``--revision HEAD``), e.g. ``--out results/benchmarks/regeneration_vs_committed.json``.
Its commit and path are recorded (``after``).
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a script, this folder is first on the path: the repository's pipelines too
    sys.path.insert(0, str(ROOT))
from pipelines.reporting import EXPERIMENTS, METHODS, run_of  # noqa: E402  (the table's rows, their experiments)
from pipelines.revision_pairing import (  # noqa: E402  (the pairing, shared with pipelines/reproduction_check.py)
    TRAFFIC,
    compare_cells,
    evaluation_cells,
    show_at_revision,
)

OUTPUT = ROOT / "results" / "benchmarks" / "table_vs_revision.json"


def episodes_path(method: str, traffic: str) -> str:
    return (run_of(EXPERIMENTS[method], traffic) / "episodes.csv").as_posix()


def at_revision(revision: str, path: str, missing_ok: bool = False) -> pd.DataFrame | None:
    """``path``'s episodes at ``revision``; where it has none, None with ``missing_ok``, else a one-line exit."""
    shown = show_at_revision(ROOT, revision, path)
    if shown.returncode != 0:
        if missing_ok:
            return None
        raise SystemExit(f"table_vs_revision: --revision {revision}: no {path} there "
                         f"({shown.stderr.strip().splitlines()[-1] if shown.stderr.strip() else 'git show failed'})")
    return pd.read_csv(io.StringIO(shown.stdout))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--revision", required=True, help="the git revision whose results are 'before'")
    parser.add_argument("--out", type=Path, default=OUTPUT)
    parser.add_argument("--after", type=Path, default=ROOT,
                        help="the checkout whose working tree's evaluations are 'after' (default: this one)")
    args = parser.parse_args()
    after = args.after.resolve()
    if not (after / "results" / "evaluation").is_dir():
        raise SystemExit(f"table_vs_revision: --after {args.after}: no results/evaluation/ there")
    commit = subprocess.run(["git", "rev-parse", args.revision], cwd=ROOT, capture_output=True, text=True)
    if commit.returncode != 0:
        raise SystemExit(f"table_vs_revision: --revision {args.revision}: not a git revision")
    after_commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=after, capture_output=True, text=True)
    result = {"revision": commit.stdout.strip(), "traffic": {},
              "after": {"commit": after_commit.stdout.strip() or None,
                        "path": "." if after == ROOT else str(after)}}
    for traffic in TRAFFIC:
        for method in METHODS:
            path = episodes_path(method, traffic)
            if not (after / path).is_file():
                raise SystemExit(f"table_vs_revision: {after / path}: missing (dvc repro first)")
            comparison = compare_cells(at_revision(args.revision, path), pd.read_csv(after / path))
            result["traffic"].setdefault(traffic, {})[method] = comparison
            print(f"{traffic:5s} {method:18s} identical {comparison['identical_episodes']:4d}/"
                  f"{comparison['episodes_paired']}  " + "  ".join(
                      f"{m} {c['paired']:+.3g} [{c['paired_ci95'][0]:+.3g}, {c['paired_ci95'][1]:+.3g}]"
                      f"{'' if c['agrees'] else ' MOVED'}" for m, c in comparison["cells"].items()))
    result["all_agree"] = all(cell["agrees"] for level in result["traffic"].values()
                              for row in level.values() for cell in row["cells"].values())
    result["experiments"], result["new"], result["moved"] = {}, [], []
    for experiment, traffic, path in evaluation_cells(after):
        before = at_revision(args.revision, path, missing_ok=True)
        if before is None:
            result["new"].append(f"{experiment} {traffic}")
            continue
        comparison = compare_cells(before, pd.read_csv(after / path))
        result["experiments"].setdefault(experiment, {})[traffic] = comparison
        moved = [f"{experiment} {traffic} {m}" for m, c in comparison["cells"].items() if not c["agrees"]]
        result["moved"] += moved
        print(f"{experiment:55s} {traffic:5s} identical {comparison['identical_episodes']:4d}/"
              f"{comparison['episodes_paired']}{'  MOVED' if moved else ''}")
    result["experiments_all_agree"] = not result["moved"]
    compared = [row for level in result["experiments"].values() for row in level.values()]
    result["counts"] = {
        "evaluations": len(compared),
        "evaluations_identical": sum(row["identical_episodes"] == row["episodes_paired"] for row in compared),
        "evaluations_moved": len({" ".join(cell.split()[:2]) for cell in result["moved"]}),
        "metric_cells": sum(len(row["cells"]) for row in compared),
        "metric_cells_moved": len(result["moved"]),
        "new": len(result["new"]),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    temporary = args.out.with_name(args.out.name + ".tmp")
    temporary.write_text(json.dumps(result, indent=1) + "\n")
    os.replace(temporary, args.out)
    print(f"all table cells agree: {result['all_agree']}; every evaluation: {result['experiments_all_agree']} "
          f"({len(result['moved'])} cells moved, {len(result['new'])} new; {args.out})")


if __name__ == "__main__":
    main()
