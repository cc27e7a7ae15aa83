"""What the spot check recomputes: one cell per evaluation and per training that ``dvc.lock`` records, the command
that recomputes its first rows, and the comparison of those rows with the committed ones.

- An evaluation cell is a stage of the lock with an out ``results/evaluation/<...>/episodes.csv`` and a
  ``python -m srmpc <overrides>`` command (every ``evaluate@<question>/<name>-<traffic>``). Its first rows are
  recomputed by the stage's own command with ``evaluation.episodes=K`` and a temporary ``evaluation.output_dir``
  (``evaluation.workers=1``, ``tracking.enabled=false``: neither changes an episode, srmpc.stages.evaluate's
  ``NOT_IDENTITY``). Episode i runs from seed ``evaluation.seed + i`` whatever the episode count, and
  ``episodes.csv`` holds one row per episode in episode order, so the first K rows are the committed file's
  first K rows: compared byte for byte, header included.
- A training cell is one run of a ``python -m pipelines.train_runs ...`` stage (the runs it expands to, e.g.
  ``agent=ppo_lsi agent.seed=0``). Its first iterations are recomputed by the run's own command
  (``python -m srmpc stage=train ...``) with ``agent.total_frames`` = N batches and a temporary
  ``agent.output_dir``; the first N rows of ``metrics.csv`` are compared field by field as text, leaving out the
  wall-clock columns (``wall_s``, ``env_steps_per_s``: pipelines.reproduction_check's ``WALL_CLOCK``). A run whose
  multiplier learning rate anneals over the whole training (``agent.multiplier_lr_final`` set) computes its second
  iteration's rate from ``total_frames``, so only its first row is comparable.
"""

from __future__ import annotations

import csv
import io
import shlex
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from pipelines.reproduction_check import WALL_CLOCK

EVALUATION_ROOT = "results/evaluation/"
EPISODES_NAME = "episodes.csv"
METRICS_NAME = "metrics.csv"
SRMPC_COMMAND = ("python", "-m", "srmpc")
TRAIN_RUNS_COMMAND = ("python", "-m", "pipelines.train_runs")
EVALUATION_OVERRIDES = ("evaluation.workers=1", "tracking.enabled=false")
"""Added to an evaluation's command besides the episode count and the output folder: one process per cell (the
spot check runs cells side by side) and no MLflow run; neither changes an episode."""
TRAINING_OVERRIDES = ("tracking.enabled=false",)
"""Added to a training's command besides its length and output folder: no MLflow run."""


class BadInput(Exception):
    """One line for the user (exit status 2): a missing dvc.lock or committed file, a command not understood."""


@dataclass
class Cell:
    """One evaluation or training to recompute: ``stage`` (the lock's), ``name`` (what the report calls it),
    ``committed`` (the committed file, relative to the root), ``arguments`` (``python -m srmpc``'s, without the
    spot check's own overrides), ``rows`` (how many rows to compare; set once the committed file is read)."""

    kind: str  # "evaluation" or "training"
    stage: str
    name: str
    committed: str
    arguments: list[str]
    rows: int = 0
    frames_per_batch: int = 0
    note: str = ""
    controller: str = ""
    """An evaluation's controller and simulator, from the lock's params (what it composed to)."""
    simulator: str = ""

    def overrides(self, output_dir: Path) -> list[str]:
        """``python -m srmpc``'s overrides that recompute the cell's first :attr:`rows` rows into ``output_dir``:
        the stage's own, then the spot check's."""
        if self.kind == "evaluation":
            extra = [f"evaluation.episodes={self.rows}", f"evaluation.output_dir={output_dir}", *EVALUATION_OVERRIDES]
        else:
            extra = [f"agent.total_frames={self.rows * self.frames_per_batch}", f"agent.output_dir={output_dir}",
                     *TRAINING_OVERRIDES]
        return [*self.arguments, *extra]

    def command(self, python: str, output_dir: Path) -> list[str]:
        """The command line that does it (Hydra's own run folder beside ``output_dir``)."""
        return [python, "-m", "srmpc", *self.overrides(output_dir), f"hydra.run.dir={output_dir}.hydra"]

    @property
    def recomputed_name(self) -> str:
        return EPISODES_NAME if self.kind == "evaluation" else METRICS_NAME


def read_lock(root: Path) -> dict:
    """``root/dvc.lock``'s stages (BadInput when it is missing or not a lock)."""
    path = root / "dvc.lock"
    try:
        lock = yaml.load(path.read_text(), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    except FileNotFoundError:
        raise BadInput(f"{path}: no dvc.lock (--root names the checkout whose committed results are checked)") from None
    except (OSError, yaml.YAMLError) as error:
        raise BadInput(f"{path}: cannot be read as YAML ({str(error).splitlines()[0]})") from None
    if not isinstance(lock, dict) or not isinstance(lock.get("stages"), dict):
        raise BadInput(f"{path}: has no stages")
    return lock["stages"]


def evaluation_cells(stages: dict) -> list[Cell]:
    """Every stage of the lock that writes ``results/evaluation/<...>/episodes.csv``, in the lock's order."""
    cells = []
    for name, stage in stages.items():
        outs = [out["path"] for out in stage.get("outs", []) if isinstance(out, dict) and "path" in out]
        episodes = [p for p in outs if p.startswith(EVALUATION_ROOT) and p.endswith("/" + EPISODES_NAME)]
        if not episodes:
            continue
        tokens = shlex.split(str(stage.get("cmd", "")))
        if tuple(tokens[:3]) != SRMPC_COMMAND or len(episodes) != 1:
            raise BadInput(f"dvc.lock: stage {name}: cmd {stage.get('cmd')!r} is not one 'python -m srmpc ...' "
                           "evaluation; the spot check cannot recompute it")
        composed = next(iter((stage.get("params") or {}).values()), {})
        composed = composed if isinstance(composed, dict) else {}
        cells.append(Cell("evaluation", name, name, episodes[0], tokens[3:],
                          controller=str((composed.get("controller") or {}).get("name", "")),
                          simulator=str((composed.get("evaluation") or {}).get("simulator", ""))))
    return cells


def training_cells(stages: dict) -> list[Cell]:
    """One cell per run of every ``python -m pipelines.train_runs ...`` stage of the lock, in the stage's run order.
    The runs are composed (conf/) to find each one's output folder and batch size."""
    from pipelines.train_runs import parse_arguments, training_command
    from srmpc.config.compose import ConfigError, compose_config, to_objects
    from srmpc.stages.train import training_dir

    cells = []
    for name, stage in stages.items():
        tokens = shlex.split(str(stage.get("cmd", "")))
        if tuple(tokens[:3]) != TRAIN_RUNS_COMMAND:
            continue
        try:
            runs, _ = parse_arguments(tokens[3:])  # the stage's own expansion of its runs
        except SystemExit:
            raise BadInput(f"dvc.lock: stage {name}: cmd {stage.get('cmd')!r}: train_runs refuses its arguments"
                           ) from None
        for run in runs:
            arguments = training_command(run)
            try:
                config = to_objects(compose_config(arguments))
            except ConfigError as error:
                raise BadInput(f"dvc.lock: stage {name}: run '{run}' does not compose today: {error}") from None
            output_dir = training_dir(config).as_posix()
            note = ("agent.multiplier_lr_final anneals over total_frames: only the first iteration is comparable"
                    if getattr(config.agent, "multiplier_lr_final", None) is not None else "")
            cells.append(Cell("training", name, f"{name}: {output_dir}", f"{output_dir}/{METRICS_NAME}", arguments,
                              frames_per_batch=config.agent.frames_per_batch, note=note))
    return cells


# ---------------------------------------------------------------------------------------------------
# the rows


def committed_lines(root: Path, cell: Cell) -> list[bytes]:
    """The committed file's lines (header first; BadInput, one line, when the file is missing)."""
    path = root / cell.committed
    try:
        return path.read_bytes().splitlines(keepends=True)
    except FileNotFoundError:
        raise BadInput(f"{cell.committed}: committed file missing (dvc.lock's stage {cell.stage} records it); "
                       "restore it (git checkout -- results) or leave the stage out (--stages)") from None


@dataclass
class Comparison:
    """``equal``; otherwise the first differing row (1 = the first after the header; 0: the header) and what
    differs there."""

    equal: bool
    rows: int
    row: int = 0
    detail: str = ""
    columns: list[str] = field(default_factory=list)
    """Every column that differs in some compared row."""
    max_relative: float | None = None
    """The largest |recomputed - committed| / max(|committed|, |recomputed|) over the differing floating-point
    fields (a difference in the last bits is about 1e-15; a different episode far more); counts are not scaled."""


def _fields(line: bytes) -> list[str]:
    return next(csv.reader(io.StringIO(line.decode("utf-8", "replace"))), [])


def _first_difference(header: list[str], committed: list[str], yours: list[str], left_out: tuple = ()) -> str:
    for column, (a, b) in enumerate(zip(committed, yours, strict=False)):
        name = header[column] if column < len(header) else f"column {column + 1}"
        if a != b and name not in left_out:
            return f"{name}: committed {a}, recomputed {b}"
    return f"{len(committed)} fields committed, {len(yours)} recomputed"


def _extent(header: list[str], committed: list[list[str]], recomputed: list[list[str]], left_out: tuple = ()
            ) -> tuple[list[str], float | None]:
    """The columns that differ in any of the rows, and the largest relative difference of a numeric field."""
    columns: list[str] = []
    largest = None
    for a_row, b_row in zip(committed, recomputed, strict=False):
        for column, (a, b) in enumerate(zip(a_row, b_row, strict=False)):
            name = header[column] if column < len(header) else f"column {column + 1}"
            if a == b or name in left_out:
                continue
            if name not in columns:
                columns.append(name)
            if not any(mark in a + b for mark in ".eE"):  # a count (steps_solved, n_steps): listed, not scaled
                continue
            try:
                x, y = float(a), float(b)
            except ValueError:
                continue
            scale = max(abs(x), abs(y))
            relative = abs(y - x) / scale if scale else 0.0
            largest = relative if largest is None else max(largest, relative)
    return columns, largest


def compare_episodes(committed: list[bytes], recomputed: list[bytes], rows: int) -> Comparison:
    """The header and the first ``rows`` rows of an ``episodes.csv``, byte for byte."""
    if len(recomputed) < rows + 1:
        return Comparison(False, rows, len(recomputed), f"{len(recomputed) - 1} rows recomputed, {rows} expected")
    for i in range(rows + 1):
        if committed[i] != recomputed[i]:
            header = _fields(committed[0])
            if i == 0:
                return Comparison(False, rows, 0, "header differs")
            a = [_fields(line) for line in committed[1:rows + 1]]
            b = [_fields(line) for line in recomputed[1:rows + 1]]
            return Comparison(False, rows, i, _first_difference(header, a[i - 1], b[i - 1]), *_extent(header, a, b))
    return Comparison(True, rows)


def compare_metrics(committed: list[bytes], recomputed: list[bytes], rows: int) -> Comparison:
    """The header and the first ``rows`` rows of a ``metrics.csv``, field by field as text, without the wall-clock
    columns (:data:`WALL_CLOCK`)."""
    if len(recomputed) < rows + 1:
        return Comparison(False, rows, len(recomputed), f"{len(recomputed) - 1} rows recomputed, {rows} expected")
    header = _fields(committed[0])
    if _fields(recomputed[0]) != header:
        return Comparison(False, rows, 0, "header differs")
    kept = [i for i, name in enumerate(header) if name not in WALL_CLOCK]
    all_a = [_fields(line) for line in committed[1:rows + 1]]
    all_b = [_fields(line) for line in recomputed[1:rows + 1]]
    for i, (a, b) in enumerate(zip(all_a, all_b, strict=True), start=1):
        if [a[k] for k in kept if k < len(a)] != [b[k] for k in kept if k < len(b)]:
            return Comparison(False, rows, i, _first_difference(header, a, b, WALL_CLOCK),
                              *_extent(header, all_a, all_b, WALL_CLOCK))
    return Comparison(True, rows)
