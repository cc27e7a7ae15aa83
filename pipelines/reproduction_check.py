"""Your ``dvc repro`` against the committed results: which outputs equal them, whether the table's verdicts agree,
and the first stage that differs.

    python -m pipelines.reproduction_check [--revision REV] [--after DIR] [--json PATH]

Run it in your clone after ``dvc repro`` (``make reproduce FORCE=1``). "Committed" is the git revision ``--revision``
(default HEAD): its ``dvc.lock`` and its files (``git show``; every output is committed to git, ``cache: false``).
"Yours" is this checkout's working tree, or that of ``--after DIR`` (another checkout).

1. Outputs. Every out and metric of every stage of the revision's ``dvc.lock``, byte for byte: a file out equals
   when its MD5 is the one the lock records; a directory out when its ``.dir`` hash is (DVC's: the MD5 of its files'
   sorted list, ``.dvcignore``'d files such as a training's ``last.pt`` left out). Where a hash differs, each file
   is compared with the revision's blob. A JSON or CSV file that equals the committed one once the machine's
   fields (:data:`MACHINE_FIELDS`) are left out counts as equal, and the count says so: the record of the machine,
   ``environment`` (``srmpc.numerics.SUMMARY_KEY``: CPU model, numeric pin, library versions; in a run's
   ``summary.json`` and in the copies of it, a training's ``designated.json`` for one), and the wall-clock
   measurements :data:`WALL_CLOCK` (a training's ``wall_s``, ``env_steps_per_s``): JSON keys at any depth, CSV
   columns. Everything else of such a file is compared exactly (a CSV's fields as text); a policy (``.pt``), an
   ``episodes.csv`` and every other file stay compared byte for byte. A differing file says what differs: a JSON's
   top-level keys, a CSV's columns and rows (the machine's fields left out).
2. Verdicts, paired on the seeds. Every evaluation of the lock (the table's cells, each method of
   ``pipelines/reporting.py`` in each traffic level, and every other one): your episodes against the committed
   episodes of the same seeds (``pipelines/revision_pairing.py``, as ``benchmarks/table_vs_revision.py`` pairs them:
   paired differences with bootstrap CIs, ``agrees``); byte-identical episodes agree without a bootstrap. And the
   table's claims: ``pipelines/paper_table.claims`` regenerated from each side's ``results/table.json``, each claim
   line with its numbers masked (its verdict words: "holds", "lower", "not distinguishable", ...), yours against
   the committed.
3. The first stage that differs, in the order of the pipeline's graph (the lock's deps, params files and outs: a
   stage follows every stage whose outputs it depends on; ties in ``dvc.yaml``'s order): an upstream difference
   explains the ones downstream of it, which are counted. ``differences_start_in``: the differing stages none of
   whose upstream stages differs (their inputs are the committed ones, their outputs are not).

Prints a short summary; ``--json PATH`` writes the full report. Exit status 0 when every output equals the committed
one, 1 when some differ, 2 with one line on bad input (a bad ``--revision``, not a git repository, no ``dvc.lock``
at the revision, a missing ``--after``).
"""

from __future__ import annotations

import argparse
import bisect
import csv
import hashlib
import heapq
import io
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pathspec
import yaml

from pipelines.paper_table import claims
from pipelines.reporting import EXPERIMENTS
from pipelines.revision_pairing import TRAFFIC, compare_cells, evaluation_of
from srmpc.numerics import SUMMARY_KEY

ROOT = Path(__file__).resolve().parents[1]
PROGRAM = "reproduction_check"
WALL_CLOCK = ("wall_s", "env_steps_per_s")
"""JSON keys and CSV columns of the committed results that measure the wall clock of the machine that ran a stage,
not its result (a rerun on the same machine gives other values):

- ``wall_s``: the seconds since a training started (``srmpc.agents.trainer``, ``time.perf_counter``): a column of
  its ``metrics.csv`` (one row per iteration) and, its last value, a key of its ``summary.json``
  (``srmpc.agents.report``); copied from there into ``designated.json``'s ``training_summary``
  (``designate_policy``), ``results/training/summary.json`` (per agent the mean over seeds and ``per_seed``,
  ``training_figure``), ``results/training/ablation/summary.json`` (each variant's ``training``,
  ``multiplier_ablation``) and ``results/figures/training.csv`` (a column);
- ``env_steps_per_s``: an iteration's environment steps over its wall time (a column of ``metrics.csv``).

Not timings, though their names look alike: ``response_time_ego_s`` and ``response_time_others_s`` (RSS settings,
``results/rss.json`` and the RSS trainings' ``config.yaml``), ``return_per_step`` and ``mean_return_per_step``
(returns), ``per_seed`` and ``per_step`` (groupings), and ``results/nmpc.json``'s ``time_median_ms``,
``time_p99_ms``, ``ipopt_time_median_ms`` and ``qp_time_median_ms``: solve times measured by
``benchmarks/nmpc_initial_guess.py``, which the ``nmpc`` stage copies from its committed input
``results/benchmarks/nmpc_initial_guess.json`` (a dep, not an out): they differ only where that input does."""
MACHINE_FIELDS = (SUMMARY_KEY, *WALL_CLOCK)
"""What is left out of a JSON (keys, at any depth) or CSV (columns) whose hash differs before it is compared: the
machine's record (``environment``) and its wall-clock times (:data:`WALL_CLOCK`)."""
BYTE_COMPARED = ("episodes.csv",)
"""Names of files compared byte for byte even though they are CSV: an evaluation's episodes (it has no machine's
fields; the verdicts pair it on the seeds)."""
SHOWN = 10
"""Differing outputs the summary names; the JSON report lists all."""
NUMBER = re.compile(r"(?<![\w.])[+-]?\d+(?:[.,]\d+)*(?:e[+-]?\d+)?")
"""A number in a claim line (not digits inside a word): masked, so that only the verdict's words are compared."""


class BadInput(Exception):
    """One line for the user, exit status 2."""


# ---------------------------------------------------------------------------------------------------
# the revision


def _git(root: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["git", *args], cwd=root, capture_output=True)


def resolve_revision(root: Path, revision: str) -> str:
    """``revision``'s commit in the repository at ``root`` (BadInput when there is no repository or no such commit)."""
    if _git(root, "rev-parse", "--git-dir").returncode != 0:
        raise BadInput(f"{root}: not a git repository")
    commit = _git(root, "rev-parse", "--verify", "--quiet", f"{revision}^{{commit}}")
    if commit.returncode != 0:
        raise BadInput(f"--revision {revision}: not a git revision")
    return commit.stdout.decode().strip()


def committed_lock(root: Path, commit: str, revision: str) -> dict:
    """The revision's ``dvc.lock`` (BadInput when it has none, or none DVC could read)."""
    shown = _git(root, "show", f"{commit}:dvc.lock")
    if shown.returncode != 0:
        raise BadInput(f"--revision {revision}: no dvc.lock there")
    try:
        lock = yaml.load(shown.stdout, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except yaml.YAMLError as error:
        raise BadInput(f"--revision {revision}: dvc.lock is not YAML ({str(error).splitlines()[0]})") from None
    if not isinstance(lock, dict) or not isinstance(lock.get("stages"), dict):
        raise BadInput(f"--revision {revision}: dvc.lock has no stages")
    return lock


def committed_blobs(root: Path, commit: str) -> dict[str, str]:
    """Every file of the revision: path -> its blob's id."""
    listed = _git(root, "ls-tree", "-r", "-z", commit).stdout.decode()
    blobs = {}
    for entry in filter(None, listed.split("\0")):
        info, path = entry.split("\t", 1)
        _, kind, blob = info.split()
        if kind == "blob":
            blobs[path] = blob
    return blobs


def blob_bytes(root: Path, blob: str) -> bytes:
    return _git(root, "cat-file", "blob", blob).stdout


def stage_order(root: Path, commit: str) -> dict[str, int]:
    """Each stage's place in the revision's ``dvc.yaml`` (a ``foreach``/``matrix`` stage: its name before ``@``)."""
    shown = _git(root, "show", f"{commit}:dvc.yaml")
    try:
        stages = yaml.safe_load(shown.stdout).get("stages", {}) if shown.returncode == 0 else {}
    except (yaml.YAMLError, AttributeError):
        stages = {}
    return {name: i for i, name in enumerate(stages)}


# ---------------------------------------------------------------------------------------------------
# hashes


def git_blob_id(data: bytes) -> str:
    """The id git gives a file of these bytes."""
    return hashlib.sha1(b"blob %d\0" % len(data) + data).hexdigest()


def directory_files(directory: Path, root: Path, ignore: pathspec.PathSpec) -> list[str]:
    """The files of a directory out, relative to it, sorted; those ``.dvcignore`` names left out."""
    files = []
    for path in directory.rglob("*"):
        if path.is_file() and not ignore.match_file(path.relative_to(root).as_posix()):
            files.append(path.relative_to(directory).as_posix())
    return sorted(files)


def directory_md5(directory: Path, files: list[str]) -> str:
    """DVC's hash of a directory out: the MD5 of its files' sorted (md5, relpath) list, as JSON, and ``.dir``."""
    entries = [{"md5": hashlib.md5((directory / f).read_bytes()).hexdigest(), "relpath": f} for f in files]
    return hashlib.md5(json.dumps(entries, sort_keys=True).encode()).hexdigest() + ".dir"


def dvcignore(after: Path) -> pathspec.PathSpec:
    path = after / ".dvcignore"
    return pathspec.GitIgnoreSpec.from_lines(path.read_text().splitlines() if path.is_file() else [])


# ---------------------------------------------------------------------------------------------------
# outputs


def _canonical(document) -> str:
    return json.dumps(document, sort_keys=True)


def _without(value, found: dict, where: str = ""):
    """A parsed JSON ``value`` without the keys :data:`MACHINE_FIELDS` at any depth; each value left out goes into
    ``found`` under its place (``/key/0/wall_s``)."""
    if isinstance(value, dict):
        kept = {}
        for key, item in value.items():
            if key in MACHINE_FIELDS:
                found[f"{where}/{key}"] = item
            else:
                kept[key] = _without(item, found, f"{where}/{key}")
        return kept
    if isinstance(value, list):
        return [_without(item, found, f"{where}/{i}") for i, item in enumerate(value)]
    return value


def _machine_field_order(names: set[str]) -> list[str]:
    return [field for field in MACHINE_FIELDS if field in names]


def _json_machine_fields(committed: bytes, yours: bytes) -> list[str] | None:
    a_found: dict = {}
    b_found: dict = {}
    a, b = _without(json.loads(committed), a_found), _without(json.loads(yours), b_found)
    if _canonical(a) != _canonical(b):
        return None
    return _machine_field_order({place.rsplit("/", 1)[-1] for place in a_found.keys() | b_found.keys()
                                 if (place in a_found) != (place in b_found)
                                 or _canonical(a_found[place]) != _canonical(b_found[place])})


def _csv_machine_fields(committed: bytes, yours: bytes) -> list[str] | None:
    a, b = (list(csv.reader(io.StringIO(data.decode()))) for data in (committed, yours))
    if not a or not b or any(len(row) != len(rows[0]) for rows in (a, b) for row in rows):  # no header, ragged
        return None

    def without(rows: list[list[str]]) -> list[list[str]]:
        kept = [i for i, name in enumerate(rows[0]) if name not in WALL_CLOCK]
        return [[row[i] for i in kept] for row in rows]

    def column(rows: list[list[str]], name: str) -> list[str] | None:
        return [row[rows[0].index(name)] for row in rows[1:]] if name in rows[0] else None

    if without(a) != without(b):
        return None
    return _machine_field_order({name for name in WALL_CLOCK if column(a, name) != column(b, name)})


def machine_fields_differing(path: str, committed: bytes, yours: bytes) -> list[str] | None:
    """The machine's fields (:data:`MACHINE_FIELDS`) in which ``yours`` differs from ``committed``, where it equals
    it without them: JSON (the keys at any depth left out, the rest compared as parsed JSON) or CSV (the columns left
    out, the rest compared field by field as text); else None: other files (:data:`BYTE_COMPARED`, not JSON or
    CSV), a difference elsewhere, or none in the machine's fields (formatting)."""
    if Path(path).name in BYTE_COMPARED:
        return None
    try:
        if path.endswith(".json"):
            fields = _json_machine_fields(committed, yours)
        elif path.endswith(".csv"):
            fields = _csv_machine_fields(committed, yours)
        else:
            return None
    except (ValueError, csv.Error):  # not JSON, not UTF-8, not CSV
        return None
    return fields or None


def _names(names: list[str], shown: int) -> str:
    """The first ``shown`` names, then how many more."""
    return ", ".join(names[:shown]) + (f" and {len(names) - shown} more" if len(names) > shown else "")


def what_differs(path: str, committed: bytes, yours: bytes) -> str:
    """A JSON object's differing top-level keys; a CSV's differing columns and rows; else "bytes". The machine's
    fields (:data:`MACHINE_FIELDS`) left out."""
    try:
        if path.endswith(".json"):
            a, b = _without(json.loads(committed), {}), _without(json.loads(yours), {})
            if isinstance(a, dict) and isinstance(b, dict):
                keys = sorted(k for k in a.keys() | b.keys() if _canonical(a.get(k)) != _canonical(b.get(k)))
                return f"keys {_names(keys, 6)}" if keys else "formatting"
        if path.endswith(".csv"):
            a, b = pd.read_csv(io.BytesIO(committed)), pd.read_csv(io.BytesIO(yours))
            a, b = (frame.drop(columns=[c for c in WALL_CLOCK if c in frame.columns]) for frame in (a, b))
            if list(a.columns) != list(b.columns) or len(a) != len(b):
                return f"shape: {len(a)} rows of {len(a.columns)} columns committed, yours {len(b)} of {len(b.columns)}"
            unequal = (a != b) & ~(a.isna() & b.isna())
            columns = [c for c in a.columns if unequal[c].any()]
            rows = int(unequal.any(axis=1).sum())
            return f"columns {_names(columns, 4)} in {rows} of {len(a)} rows" if columns else "formatting"
    except (ValueError, TypeError, pd.errors.ParserError):  # unreadable, or not comparable column by column
        pass
    return "bytes"


def compare_file(path: str, yours: Path, blobs: dict[str, str], root: Path) -> dict:
    """One file against the revision's blob: ``equal``, ``equal_apart_from_machine`` (with ``left_out``: the
    machine's fields that differ), ``differs`` (with ``what``), ``missing`` (not in your tree) or ``extra`` (not in
    the revision's)."""
    blob = blobs.get(path)
    if not yours.is_file():
        return {"status": "missing"}
    if blob is None:
        return {"status": "extra"}
    data = yours.read_bytes()
    if git_blob_id(data) == blob:
        return {"status": "equal"}
    committed = blob_bytes(root, blob)
    fields = machine_fields_differing(path, committed, data)
    if fields:
        return {"status": "equal_apart_from_machine", "left_out": fields}
    return {"status": "differs", "what": what_differs(path, committed, data)}


def compare_out(out: dict, after: Path, blobs: dict[str, str], root: Path, ignore: pathspec.PathSpec) -> dict:
    """One out of the lock: equal when its hash is the locked one, else file by file against the revision."""
    path, locked = out["path"], str(out.get("md5", ""))
    target = after / path
    if locked.endswith(".dir"):
        if not target.is_dir():
            return {"status": "missing"}
        files = directory_files(target, after, ignore)
        if directory_md5(target, files) == locked:
            return {"status": "equal"}
        committed = [p[len(path) + 1:] for p in blobs if p.startswith(path + "/") and not ignore.match_file(p)]
        compared = {f: compare_file(f"{path}/{f}", target / f, blobs, root) for f in sorted({*files, *committed})}
        unequal = {f: c for f, c in compared.items() if not c["status"].startswith("equal")}
        if not unequal and compared:
            left_out = {field for c in compared.values() for field in c.get("left_out", [])}
            return {"status": "equal_apart_from_machine", "left_out": _machine_field_order(left_out)} if left_out \
                else {"status": "equal"}
        return {"status": "differs", "files": unequal or {"": {"status": "differs", "what": "no files"}}}
    if not target.is_file():
        return {"status": "missing"}
    if hashlib.md5(target.read_bytes()).hexdigest() == locked:
        return {"status": "equal"}
    return compare_file(path, target, blobs, root)


def out_summary(result: dict) -> str:
    """What differs in one out, in a few words."""
    if "files" in result:
        files = result["files"]
        shown = [f"{f} ({c.get('what', c['status'])})" for f, c in list(files.items())[:3]]
        return "; ".join(shown) + (f"; {len(files) - 3} more files" if len(files) > 3 else "")
    return result.get("what", result["status"])


# ---------------------------------------------------------------------------------------------------
# the graph


def upstream_stages(lock: dict) -> dict[str, set[str]]:
    """Each stage of the lock: the stages whose outs its deps or params files are, contain or lie in."""
    owners = {out["path"]: name for name, stage in lock["stages"].items() for out in stage.get("outs", [])}
    paths = sorted(owners)

    def producers(dep: str) -> set[str]:
        parts = dep.split("/")
        found = {owners[p] for p in ("/".join(parts[:i]) for i in range(1, len(parts) + 1)) if p in owners}
        i = bisect.bisect_left(paths, dep + "/")
        while i < len(paths) and paths[i].startswith(dep + "/"):
            found.add(owners[paths[i]])
            i += 1
        return found

    upstream = {}
    for name, stage in lock["stages"].items():
        deps = [dep["path"] for dep in stage.get("deps", [])] + list(stage.get("params", {}) or {})
        upstream[name] = {owner for dep in deps for owner in producers(dep)} - {name}
    return upstream


def topological_order(upstream: dict[str, set[str]], order: dict[str, int]) -> list[str]:
    """Every stage after those it depends on; of those ready, the first in ``dvc.yaml`` (then by name)."""
    def key(name: str) -> tuple[int, str]:
        return order.get(name.split("@", 1)[0], len(order)), name

    waiting = {name: set(ups) for name, ups in upstream.items()}
    downstream: dict[str, list[str]] = {name: [] for name in upstream}
    for name, ups in upstream.items():
        for up in ups:
            downstream[up].append(name)
    ready = [key(name) for name, ups in waiting.items() if not ups]
    heapq.heapify(ready)
    ordered = []
    while ready:
        _, name = heapq.heappop(ready)
        ordered.append(name)
        for child in downstream[name]:
            waiting[child].discard(name)
            if not waiting[child]:
                heapq.heappush(ready, key(child))
    return ordered + sorted(set(upstream) - set(ordered), key=key)  # a cycle (DVC refuses one): at the end


def descendants(upstream: dict[str, set[str]], stage: str) -> set[str]:
    found, frontier = set(), [stage]
    while frontier:
        current = frontier.pop()
        for name, ups in upstream.items():
            if current in ups and name not in found:
                found.add(name)
                frontier.append(name)
    return found


# ---------------------------------------------------------------------------------------------------
# verdicts


def pair_evaluations(lock: dict, outputs: dict[str, dict], after: Path, blobs: dict[str, str], root: Path) -> dict:
    """Every evaluation's episodes in the lock, yours against the revision's on the same seeds (module doc, 2.)."""
    table_cells = {(experiment, traffic): method for method, experiment in EXPERIMENTS.items() for traffic in TRAFFIC}
    result: dict = {"traffic": {}, "experiments": {}, "moved": [], "missing": []}
    for path in sorted(p for stage in lock["stages"].values() for p in (o["path"] for o in stage.get("outs", []))):
        cell = evaluation_of(path)
        if cell is None or not path.endswith("/episodes.csv"):
            continue
        experiment, traffic = cell
        status = outputs[path]["status"]
        if status == "missing" or path not in blobs:
            result["missing"].append(f"{experiment} {traffic}")
            comparison = {"agrees": False, "missing": "yours" if status == "missing" else "committed"}
        elif status == "equal":
            episodes = (after / path).read_bytes().count(b"\n") - 1  # rows under the header
            comparison = {"episodes_paired": episodes, "identical_episodes": episodes, "byte_identical": True,
                          "agrees": True}
        else:
            try:
                yours = pd.read_csv(after / path)
                comparison = compare_cells(pd.read_csv(io.BytesIO(blob_bytes(root, blobs[path]))), yours)
            except (ValueError, KeyError, pd.errors.ParserError) as error:
                comparison = {"agrees": False, "error": f"{type(error).__name__}: {error}"}
            comparison["byte_identical"] = False
            moved = [f"{experiment} {traffic} {m}" for m, c in comparison.get("cells", {}).items() if not c["agrees"]]
            if "error" in comparison:
                moved = [f"{experiment} {traffic} (unreadable: {comparison['error']})"]
            comparison["agrees"] = not moved
            result["moved"] += moved
        result["experiments"].setdefault(experiment, {})[traffic] = comparison
        if (experiment, traffic) in table_cells:
            result["traffic"].setdefault(traffic, {})[table_cells[experiment, traffic]] = comparison
    table = [c for level in result["traffic"].values() for c in level.values()]
    every = [c for level in result["experiments"].values() for c in level.values()]
    result["all_agree"] = all(c["agrees"] for c in table)
    result["experiments_all_agree"] = all(c["agrees"] for c in every)
    result["counts"] = {
        "table_cells": len(table), "table_cells_agree": sum(c["agrees"] for c in table),
        "table_cells_identical": sum(c.get("byte_identical", False) for c in table),
        "evaluations": len(every), "evaluations_agree": sum(c["agrees"] for c in every),
        "evaluations_identical": sum(c.get("byte_identical", False) for c in every),
    }
    return result


def claim_lines(table: dict) -> list[tuple[str, str]]:
    """(traffic, claim line) of ``paper_table.claims`` for each traffic level of a ``table.json`` with SRMPC."""
    return [(level, line) for level, rows in table.items() if "srmpc" in rows for line in claims(rows, level)]


def verdict(line: str) -> str:
    """A claim line with its numbers masked: the words that state the verdict, and what it is about."""
    return NUMBER.sub("#", line)


def compare_verdicts(root: Path, commit: str, blobs: dict[str, str], after: Path) -> dict:
    """The table's claims from each side's ``results/table.json``: which verdicts moved (module doc, 2.)."""
    path = "results/table.json"
    if path not in blobs:
        return {"compared": False, "reason": f"no {path} at the revision"}
    if not (after / path).is_file():
        return {"compared": False, "reason": f"no {path} in yours"}
    try:
        committed = claim_lines(json.loads(blob_bytes(root, blobs[path])))
        yours = claim_lines(json.loads((after / path).read_text()))
    except (ValueError, KeyError, TypeError, IndexError, AttributeError) as error:
        return {"compared": False, "reason": f"{path}: {type(error).__name__}: {error}"}
    moved = []
    for i in range(max(len(committed), len(yours))):
        level, ours = committed[i] if i < len(committed) else (yours[i][0], None)
        theirs = yours[i][1] if i < len(yours) else None
        if ours is None or theirs is None or verdict(ours) != verdict(theirs):
            moved.append({"traffic": level, "committed": ours, "yours": theirs})
    return {"compared": True, "claims": len(committed), "all_agree": not moved, "moved": moved,
            "committed": [line for _, line in committed], "yours": [line for _, line in yours]}


def _moved_verdict(entry: dict) -> str:
    def words(line: str | None) -> str:
        return "(none)" if line is None else verdict(line).rstrip(":. ").rsplit(": ", 1)[-1]

    about = (entry["committed"] or entry["yours"]).lstrip(" -").split(":", 1)[0]
    return f"{entry['traffic']} {about}: committed \"{words(entry['committed'])}\", yours \"{words(entry['yours'])}\""


# ---------------------------------------------------------------------------------------------------
# the check


def check(root: Path, revision: str, after: Path) -> dict:
    """The full report (module doc)."""
    started = time.perf_counter()
    if not after.is_dir():
        raise BadInput(f"--after {after}: no such directory")
    commit = resolve_revision(root, revision)
    lock = committed_lock(root, commit, revision)
    blobs = committed_blobs(root, commit)
    ignore = dvcignore(after)
    outputs, stages = {}, {}
    for name, stage in lock["stages"].items():
        for out in stage.get("outs", []):
            outputs[out["path"]] = {"stage": name, **compare_out(out, after, blobs, root, ignore)}
        stages[name] = all(outputs[o["path"]]["status"].startswith("equal") for o in stage.get("outs", []))
    upstream = upstream_stages(lock)
    ordered = topological_order(upstream, stage_order(root, commit))
    differing = [name for name in ordered if not stages[name]]
    first = differing[0] if differing else None
    below_first = descendants(upstream, first) if first else set()
    statuses = [o["status"] for o in outputs.values()]
    after_commit = _git(after, "rev-parse", "HEAD")
    return {
        "revision": commit, "revision_name": revision,
        "after": {"path": "." if after == root else str(after),
                  "commit": after_commit.stdout.decode().strip() if after_commit.returncode == 0 else None},
        "all_equal": not differing,
        "outputs": {"total": len(statuses), "equal": sum(s.startswith("equal") for s in statuses),
                    "equal_apart_from_machine": statuses.count("equal_apart_from_machine"),
                    "left_out": _machine_field_order({field for out in outputs.values()
                                                      for field in out.get("left_out", [])}),
                    "differing": statuses.count("differs"), "missing": statuses.count("missing")},
        "stages": {"total": len(stages), "equal": sum(stages.values()), "differing": differing},
        "first_differing_stage": first,
        "downstream_of_first": sorted(set(differing) & below_first),
        "not_downstream_of_first": [s for s in differing[1:] if s not in below_first],
        "differences_start_in": [s for s in differing if not upstream[s] & set(differing)],
        "pairing": pair_evaluations(lock, outputs, after, blobs, root),
        "verdicts": compare_verdicts(root, commit, blobs, after),
        "outs": outputs,
        "wall_s": time.perf_counter() - started,
    }


def summary(report: dict) -> list[str]:
    """The short human summary (stdout)."""
    o, s, p, v = report["outputs"], report["stages"], report["pairing"], report["verdicts"]
    lines = [f"reproduction check: {report['after']['path']} against {report['revision'][:10]} "
             f"(--revision {report['revision_name']})"]
    machine = ""
    if o["equal_apart_from_machine"]:
        left_out = [what for what, fields in (("wall-clock times", WALL_CLOCK), ("the machine record", (SUMMARY_KEY,)))
                    if set(fields) & set(o["left_out"])]
        machine = (f" ({o['equal_apart_from_machine']} only after leaving out {' and '.join(left_out)}: "
                   f"{', '.join(o['left_out'])})")
    lines.append(f"outputs: {o['equal']} of {o['total']} equal the committed ones{machine}"
                 + (f"; {o['total'] - o['equal']} differ:" if o["equal"] < o["total"] else ""))
    rank = {stage: i for i, stage in enumerate(s["differing"])}  # the first stage's outputs first
    unequal = sorted(((path, out) for path, out in report["outs"].items() if not out["status"].startswith("equal")),
                     key=lambda item: rank[item[1]["stage"]])
    lines += [f"  {path} [{out['stage']}]: {out_summary(out)}" for path, out in unequal[:SHOWN]]
    if len(unequal) > SHOWN:
        lines.append(f"  ... and {len(unequal) - SHOWN} more (--json)")
    lines.append(f"stages: {s['equal']} of {s['total']} equal")
    c = p["counts"]
    for what, n, agree, identical in (("table cells", c["table_cells"], c["table_cells_agree"],
                                       c["table_cells_identical"]),
                                      ("every evaluation", c["evaluations"], c["evaluations_agree"],
                                       c["evaluations_identical"])):
        lines.append(f"{what}, paired on the seeds: {agree} of {n} agree ({identical} byte-identical)")
    if p["moved"] or p["missing"]:
        lines.append(f"  moved: {_names(p['moved'] + [f'{m} (missing)' for m in p['missing']], SHOWN)}")
    if not v["compared"]:
        lines.append(f"table verdicts: not compared ({v['reason']})")
    elif v["all_agree"]:
        lines.append(f"table verdicts: all agree ({v['claims']} claims)")
    else:
        lines.append(f"table verdicts: {len(v['moved'])} of {v['claims']} moved")
        lines += [f"  {_moved_verdict(entry)}" for entry in v["moved"]]
    first = report["first_differing_stage"]
    if first is None:
        lines.append("first stage that differs: none")
    else:
        others = len(s["differing"]) - 1
        lines.append(f"first stage that differs: {first}" + (
            f" ({others} other {'stage differs' if others == 1 else 'stages differ'}: "
            f"{len(report['downstream_of_first'])} downstream of it, {len(report['not_downstream_of_first'])} not)"
            if others else " (the only one)"))
        if report["differences_start_in"] != [first]:
            lines.append(f"differences start in: {_names(report['differences_start_in'], 5)} "
                         "(no stage upstream of them differs)")
    return lines


def main(argv: list[str] | None = None, root: Path = ROOT) -> int:
    parser = argparse.ArgumentParser(prog=f"python -m pipelines.{PROGRAM}", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--revision", default="HEAD", help="the git revision whose results are committed (HEAD)")
    parser.add_argument("--after", type=Path, default=None,
                        help="the checkout whose working tree holds your outputs (default: this one)")
    parser.add_argument("--json", type=Path, default=None, help="write the full report here")
    args = parser.parse_args(argv)
    root = root.resolve()
    try:
        report = check(root, args.revision, (args.after or root).resolve())
        if args.json is not None:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            temporary = args.json.with_name(args.json.name + ".tmp")
            temporary.write_text(json.dumps(report, indent=1) + "\n")
            os.replace(temporary, args.json)
    except BadInput as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    except OSError as error:
        print(f"{PROGRAM}: {error}", file=sys.stderr)
        return 2
    print("\n".join(summary(report)))
    return 0 if report["all_equal"] else 1


if __name__ == "__main__":
    sys.exit(main())
