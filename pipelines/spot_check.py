"""Does this repository reproduce on my machine? The first rows of every committed evaluation and training, in minutes.

    python -m pipelines.spot_check                       # every evaluation and training of dvc.lock (make check)
    python -m pipelines.spot_check --stages 'evaluate@table/*' --episodes 2
    SRMPC_NUMERICS=pinned python -m pipelines.spot_check --json outputs/spot_check_pinned.json

For each evaluation recorded in ``dvc.lock`` (every ``evaluate@...`` cell) it reruns the stage's own command
with ``evaluation.episodes=K`` into a temporary folder and compares those K rows byte for byte with the first K
rows of the committed ``episodes.csv`` (episode i runs from seed i whatever the count, so the prefix is a fair
sample). For each training (every run of a ``pipelines.train_runs`` stage) it retrains the first N iterations and
compares the first N rows of the committed ``metrics.csv``, wall-clock columns left out
(:mod:`pipelines.spot_check_cells` says exactly what is run and compared). Cells run ``--workers`` at a time, one
process each; the temporary folder is removed at the end, so an interrupted check is simply run again.

It prints one line per cell as it ends, then per stage ``equal`` or ``differs``. The committed trainings were made
on another CPU (an Intel Xeon with AVX-512) before ``SRMPC_NUMERICS=pinned`` existed, so a training's rows are
``reported``, never failed, until the pinned regeneration makes them comparable. Exit status: 0 when every
recomputed evaluation equals the committed rows, 1 when one differs or a command failed (the first stage that
differs is named, in the pipeline's order as ``pipelines.reproduction_check`` orders it), 2 with one line on bad
input (an option's value, a ``--stages`` pattern that matches nothing, a missing committed file or ``dvc.lock``).

The JSON report (``--json``, default ``results/benchmarks/spot_check.json``) holds each stage's result and wall
time, the CPU (``srmpc.numerics.cpu_summary``), the numerics mode (``SRMPC_NUMERICS``), the commit and the options.
"""

from __future__ import annotations

import argparse
import contextlib
import fnmatch
import json
import multiprocessing
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor, as_completed
from pathlib import Path

import yaml

from pipelines.reproduction_check import topological_order, upstream_stages
from pipelines.spot_check_cells import (
    BadInput,
    Cell,
    committed_lines,
    compare_episodes,
    compare_metrics,
    evaluation_cells,
    read_lock,
    training_cells,
)
from srmpc.episode_loop import SINGLE_THREAD_VARIABLES
from srmpc.numerics import NumericsError, cpu_summary, requested_mode

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = "spot_check"
DEFAULT_EPISODES = 3
"""Episodes recomputed per evaluation: the whole check (116 evaluations, 21 training runs) then took under 10 minutes on
2 cores (results/benchmarks/spot_check.json, ``wall_s``)."""
DEFAULT_ITERATIONS = 2
"""Training iterations recomputed per training run."""
DEFAULT_WORKERS = 2
"""Cells at once, one process each (the project's machine has 2 cores)."""
DEFAULT_REPORT = Path("results/benchmarks/spot_check.json")
CELL_TIMEOUT_S = 1800.0
"""Longest a cell's command may run before it counts as failed [s]."""
LAST_LINES = 3
"""Lines of a failed command's output the report keeps."""


class _Parser(argparse.ArgumentParser):
    """argparse whose errors are one line (``spot_check: ...``), exit status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        print(f"{PROGRAM}: {message}", file=sys.stderr)
        raise SystemExit(2)


def parse_arguments(argv: list[str] | None) -> argparse.Namespace:
    parser = _Parser(prog=f"python -m pipelines.{PROGRAM}", description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=DEFAULT_EPISODES, metavar="K",
                        help=f"episodes recomputed per evaluation ({DEFAULT_EPISODES})")
    parser.add_argument("--iterations", type=int, default=DEFAULT_ITERATIONS, metavar="N",
                        help=f"iterations retrained per training run ({DEFAULT_ITERATIONS})")
    parser.add_argument("--stages", action="append", default=[], metavar="PATTERN",
                        help="only the lock's stages matching these shell patterns (comma-separated or repeated), "
                             "e.g. 'evaluate@table/*,train'")
    parser.add_argument("--workers", type=int, default=DEFAULT_WORKERS, metavar="N",
                        help=f"cells at once, one process each ({DEFAULT_WORKERS})")
    parser.add_argument("--one-process-per-cell", action="store_true",
                        help="run each evaluation by its own 'python -m srmpc' command line (slower: a new "
                             "interpreter, imports and numba cache loads per cell)")
    parser.add_argument("--root", type=Path, default=ROOT,
                        help="the checkout whose dvc.lock and committed results are compared (this one)")
    parser.add_argument("--json", type=Path, default=None,
                        help=f"where the report goes ({DEFAULT_REPORT} under this checkout)")
    args = parser.parse_args(argv)
    for name in ("episodes", "iterations", "workers"):
        if getattr(args, name) < 1:
            parser.error(f"--{name}={getattr(args, name)}: must be at least 1")
    args.stages = [p.strip() for value in args.stages for p in value.split(",") if p.strip()]
    return args


def select_cells(root: Path, stages: dict, patterns: list[str]) -> list[Cell]:
    """The lock's evaluation and training cells whose stage matches one of ``patterns`` (all without patterns)."""
    chosen = {name: stage for name, stage in stages.items()
              if not patterns or any(fnmatch.fnmatchcase(name, p) for p in patterns)}
    cells = training_cells(chosen) + evaluation_cells(chosen)
    for pattern in patterns:
        if not any(fnmatch.fnmatchcase(cell.stage, pattern) for cell in cells):
            raise BadInput(f"--stages {pattern}: matches no evaluation or training stage of {root / 'dvc.lock'}")
    return cells


def set_rows(root: Path, cells: list[Cell], episodes: int, iterations: int) -> dict[str, list[bytes]]:
    """Each cell's committed lines; sets how many rows it compares (at most the committed file's)."""
    committed = {}
    for cell in cells:
        lines = committed_lines(root, cell)
        if len(lines) < 2:
            raise BadInput(f"{cell.committed}: committed file has no rows (dvc.lock's stage {cell.stage})")
        wanted = episodes if cell.kind == "evaluation" else (1 if cell.note else iterations)
        cell.rows = min(wanted, len(lines) - 1)
        committed[cell.name] = lines
    return committed


def single_threaded(environment: dict[str, str]) -> dict[str, str]:
    """``environment`` as the evaluate stage's own workers run (srmpc.episode_loop): one thread per library, one core
    per process; no progress bars, no pipeline parent run."""
    environment = {k: v for k, v in environment.items() if k != "SRMPC_PARENT_RUN_ID"}
    return {**environment, "TQDM_DISABLE": "1", **{name: "1" for name in SINGLE_THREAD_VARIABLES}}


def training_environment(environment: dict[str, str]) -> dict[str, str]:
    """``environment`` as ``pipelines.train_runs`` starts a training (its threads set by ``agent.num_threads``)."""
    return {**{k: v for k, v in environment.items() if k != "SRMPC_PARENT_RUN_ID"}, "TQDM_DISABLE": "1"}


def run_command(command: list[str], environment: dict[str, str]) -> tuple[int, str]:
    """(exit status, output) of ``command`` in this checkout's root; -1 after :data:`CELL_TIMEOUT_S`."""
    try:
        process = subprocess.run(command, cwd=ROOT, env=environment, capture_output=True, text=True,
                                 timeout=CELL_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        return -1, f"no result within {CELL_TIMEOUT_S:g} s"
    return process.returncode, process.stdout + process.stderr


def run_in_process(overrides: list[str], hydra_dir: str) -> tuple[int, str]:
    """In a worker process that outlives its cells: ``python -m srmpc <overrides>`` as the CLI runs it after Hydra
    composed it (srmpc.config.compose.compose_config, then srmpc.__main__.run, the CLI's own), without a new
    interpreter, imports and numba cache loads per cell. (exit status, the error's one line)."""
    from srmpc.__main__ import run

    try:
        from srmpc.config.compose import compose_config

        run(compose_config(overrides), Path(hydra_dir), overrides)
    except Exception as error:  # noqa: BLE001  (any failure is the cell's result, reported in one line)
        return 1, f"{type(error).__name__}: {str(error).splitlines()[0] if str(error) else ''}"
    return 0, ""


def recompute(cell: Cell, committed: list[bytes], scratch: Path, number: int, pool: ProcessPoolExecutor | None,
              environment: dict[str, str]) -> dict:
    """Recompute the cell into ``scratch`` (an evaluation in ``pool`` when given, else by its command line) and
    compare its rows; the cell's entry of the report."""
    output_dir = scratch / f"cell_{number:03d}"
    command = cell.command(sys.executable, output_dir)
    started = time.perf_counter()
    if cell.kind == "evaluation" and pool is not None:
        returncode, output = pool.submit(run_in_process, cell.overrides(output_dir), f"{output_dir}.hydra").result()
    else:
        environment = single_threaded(environment) if cell.kind == "evaluation" else training_environment(environment)
        returncode, output = run_command(command, environment)
    entry = {"stage": cell.stage, "kind": cell.kind, "committed": cell.committed, "rows": cell.rows,
             **({"controller": cell.controller, "simulator": cell.simulator} if cell.kind == "evaluation" else {}),
             "wall_s": round(time.perf_counter() - started, 3),
             "command": " ".join(["python", *command[1:-1]])}
    if cell.note:
        entry["note"] = cell.note
    recomputed_path = output_dir / cell.recomputed_name
    if returncode != 0 or not recomputed_path.is_file():
        lines = [line for line in output.strip().splitlines() if line.strip()][-LAST_LINES:]
        entry.update(result="failed", detail=f"exit {returncode}: " + " | ".join(lines))
        return entry
    recomputed = recomputed_path.read_bytes().splitlines(keepends=True)
    compare = compare_episodes if cell.kind == "evaluation" else compare_metrics
    comparison = compare(committed, recomputed, cell.rows)
    entry["result"] = "equal" if comparison.equal else "differs"
    if not comparison.equal:
        entry.update(row=comparison.row, detail=comparison.detail, columns=comparison.columns,
                     max_relative_difference=comparison.max_relative)
    return entry


@contextlib.contextmanager
def evaluation_pool(workers: int, separate: bool) -> Iterator[ProcessPoolExecutor | None]:
    """``workers`` fresh processes (spawned, single-threaded as the stage's own workers) that run evaluation cells
    one after another; None with ``separate`` (each cell its own ``python -m srmpc`` process)."""
    if separate:
        yield None
        return
    saved = dict(os.environ)
    os.environ.clear()
    os.environ.update(single_threaded(saved))  # what the spawned workers inherit
    try:
        with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"), initializer=os.chdir,
                                 initargs=(str(ROOT),)) as pool:  # the root: the configs' relative policy paths
            yield pool
    finally:
        os.environ.clear()
        os.environ.update(saved)


def cell_line(entry: dict) -> str:
    result = entry["result"] if entry["kind"] == "evaluation" or entry["result"] == "failed" else \
        f"reported: {entry['result']}"
    unit = "episodes" if entry["kind"] == "evaluation" else "iterations"
    name = entry["stage"] if entry["kind"] == "evaluation" else f"{entry['stage']}: {Path(entry['committed']).parent}"
    line = f"{result:<18} {name} ({entry['rows']} {unit}, {entry['wall_s']:.1f} s)"
    if entry["result"] != "equal":
        line += f": row {entry.get('row', '?')}, {entry.get('detail', '')}" if entry["result"] == "differs" else \
            f": {entry.get('detail', '')}"
    return line


def stage_results(cells: list[dict]) -> dict[str, dict]:
    """Per stage: ``equal`` when every cell is, ``failed`` when one failed, else ``differs``; a training stage is
    ``reported``; its cells' wall time summed."""
    stages: dict[str, dict] = {}
    for entry in cells:
        stage = stages.setdefault(entry["stage"], {"kind": entry["kind"], "cells": 0, "wall_s": 0.0, "results": []})
        stage["cells"] += 1
        stage["wall_s"] = round(stage["wall_s"] + entry["wall_s"], 3)
        stage["results"].append(entry["result"])
    for stage in stages.values():
        results = stage.pop("results")
        stage["result"] = ("failed" if "failed" in results else "differs" if "differs" in results else "equal")
        stage["reported"] = stage["kind"] == "training"
    return stages


def pipeline_order(root: Path, lock: dict) -> list[str]:
    """The lock's stages in the pipeline's order (pipelines.reproduction_check's: upstream first, then
    ``dvc.yaml``'s order)."""
    try:
        names = list((yaml.safe_load((root / "dvc.yaml").read_text()) or {}).get("stages", {}))
    except (OSError, yaml.YAMLError, AttributeError):
        names = []
    return topological_order(upstream_stages(lock), {name: i for i, name in enumerate(names)})


def git_commit(root: Path) -> dict:
    """The commit of the code that ran (``HEAD``) and whether its working tree had changes."""
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True)
    status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=root, capture_output=True,
                            text=True)
    return {"commit": head.stdout.strip() or None, "dirty": bool(status.stdout.strip())}


def write_report(path: Path, report: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(json.dumps(report, indent=1) + "\n")
    os.replace(temporary, path)


def run_check(args: argparse.Namespace) -> dict:
    """Recompute the selected cells and return the report (what :func:`main` prints and writes)."""
    root = args.root.resolve()
    mode = requested_mode()
    code = git_commit(ROOT)  # the code that runs, before anything runs
    stages = read_lock(root)
    cells = select_cells(root, stages, args.stages)
    committed = set_rows(root, cells, args.episodes, args.iterations)
    evaluations = sum(c.kind == "evaluation" for c in cells)
    print(f"{PROGRAM}: {len(cells)} cells ({evaluations} evaluations, {len(cells) - evaluations} training runs) of "
          f"{root / 'dvc.lock'}, {args.workers} at a time; SRMPC_NUMERICS={mode}", flush=True)
    started = time.perf_counter()
    entries: list[dict | None] = [None] * len(cells)
    environment = dict(os.environ)
    with (tempfile.TemporaryDirectory(prefix="spot_check-") as scratch,
          evaluation_pool(args.workers, args.one_process_per_cell) as pool,
          ThreadPoolExecutor(args.workers) as threads):
        futures = {threads.submit(recompute, cell, committed[cell.name], Path(scratch), i, pool, environment): i
                   for i, cell in enumerate(cells)}
        try:
            for done, future in enumerate(as_completed(futures), start=1):
                entry = future.result()
                entries[futures[future]] = entry
                print(f"[{done}/{len(cells)}] {cell_line(entry)}", flush=True)
        except BaseException:  # Ctrl-C, SIGTERM: start no more cells; the scratch folder goes when they end
            threads.shutdown(wait=False, cancel_futures=True)
            raise
    wall_s = time.perf_counter() - started
    cell_entries = [e for e in entries if e is not None]
    per_stage = stage_results(cell_entries)
    order = [name for name in pipeline_order(root, {"stages": stages}) if name in per_stage]
    per_stage = {name: per_stage[name] for name in order}
    bad = [name for name, s in per_stage.items() if s["kind"] == "evaluation" and s["result"] != "equal"]
    failed_trainings = [name for name, s in per_stage.items() if s["kind"] == "training" and s["result"] == "failed"]
    differing_trainings = [name for name, s in per_stage.items() if s["kind"] == "training" and s["result"] != "equal"]

    def count(kind: str, result: str) -> int:
        return sum(s["kind"] == kind and s["result"] == result for s in per_stage.values())

    return {
        "program": f"python -m pipelines.{PROGRAM}", **code, "root": str(root),
        "numerics": mode, "cpu": cpu_summary(),
        "episodes": args.episodes, "iterations": args.iterations, "workers": args.workers,
        "stages_patterns": args.stages,
        "evaluations_run": "one python -m srmpc process per cell" if args.one_process_per_cell else
        "in worker processes, one cell after another (srmpc.__main__.run)",
        "wall_s": round(wall_s, 1),
        "evaluation_stages": {r: count("evaluation", r) for r in ("equal", "differs", "failed")},
        "training_stages": {r: count("training", r) for r in ("equal", "differs", "failed")},
        "training_runs": {r: sum(e["kind"] == "training" and e["result"] == r for e in cell_entries)
                          for r in ("equal", "differs", "failed")},
        "differing_evaluation_stages": bad,
        "differing_columns": {kind: sorted({c for e in cell_entries if e["kind"] == kind and e["result"] == "differs"
                                            for c in e["columns"]}) for kind in ("evaluation", "training")},
        "largest_relative_difference": {kind: max((e["max_relative_difference"] or 0.0 for e in cell_entries
                                                   if e["kind"] == kind and e["result"] == "differs"), default=None)
                                        for kind in ("evaluation", "training")},
        "evaluations_by_controller": tally(cell_entries, "controller"),
        "evaluations_by_simulator": tally(cell_entries, "simulator"),
        "first_differing_stage": bad[0] if bad else None,
        "first_differing_training": differing_trainings[0] if differing_trainings else None,
        "passed": not bad and not failed_trainings,
        "stages": per_stage,
        "cells": cell_entries,
    }


def tally(entries: list[dict], key: str) -> dict[str, dict[str, int]]:
    """Evaluation cells' results counted per value of ``key`` (their controller, their simulator)."""
    counts: dict[str, dict[str, int]] = {}
    for entry in entries:
        if entry["kind"] == "evaluation":
            group = counts.setdefault(entry[key] or "?", {"equal": 0, "differs": 0, "failed": 0})
            group[entry["result"]] += 1
    return dict(sorted(counts.items()))


def summary_lines(report: dict) -> list[str]:
    lines = ["", "per stage:"]
    for name, stage in report["stages"].items():
        result = stage["result"]
        if stage["reported"] and result != "failed":
            result = f"reported: {result}"
        lines.append(f"  {result:<18} {name} ({stage['cells']} cells, {stage['wall_s']:.1f} s)")
    ev, tr = report["evaluation_stages"], report["training_stages"]
    lines += [
        f"evaluations: {ev['equal']} of {sum(ev.values())} stages equal the committed rows"
        f" ({ev['differs']} differ, {ev['failed']} failed)",
        f"trainings (reported, not failed, until the pinned regeneration): {tr['equal']} of {sum(tr.values())} stages "
        f"equal ({report['training_runs']['equal']} of {sum(report['training_runs'].values())} runs)",
        f"first stage that differs: {report['first_differing_stage'] or 'none'}",
        f"{report['wall_s']:.0f} s on {report['cpu']['model']}, SRMPC_NUMERICS={report['numerics']}, commit "
        f"{(report['commit'] or '?')[:10]}{' (changed working tree)' if report['dirty'] else ''}",
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    args = parse_arguments(argv)
    main_thread = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(128 + signum)) if main_thread else None
    try:  # SIGTERM ends the check as Ctrl-C does: no new cells, the scratch folder removed
        report = run_check(args)
    except (BadInput, NumericsError) as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    finally:
        if main_thread:
            signal.signal(signal.SIGTERM, previous)
    print("\n".join(summary_lines(report)))
    path = args.json if args.json is not None else ROOT / DEFAULT_REPORT
    write_report(path, report)
    print(f"report: {path}")
    return 0 if report["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
