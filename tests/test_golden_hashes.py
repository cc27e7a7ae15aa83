"""Golden hashes: under the pinned numeric environment (srmpc.numerics), a short training of every agent and a
short evaluation of every controller (pipelines/numerics_probe.py's cells) give these bytes on every x86-64 CPU
with AVX2 (tests/data/golden_hashes.json); tests/test_isa_caps.py runs them under instruction-set caps that stand
for other such CPUs.

CI runs on whatever machine it is given (an Intel Xeon, an AMD EPYC, ...), so every CI run is a cross-machine
check; ``benchmarks/reproducibility.py`` records the CPU models where it passed
(``results/benchmarks/reproducibility.json``). If :func:`test_golden_hashes` fails on a new CPU, find the path
that differs and pin it in srmpc/numerics.py: never update the golden hashes to make a machine pass. The hashes
change only in a commit that moves results on purpose, and that commit says so. ``python -m
pipelines.numerics_probe`` prints this machine's pinned hashes.

Hashed: a training's ``policy.pt``, an evaluation's ``episodes.csv`` (every metric of every episode, full
precision); ``summary.json`` is derived from them and records the machine.
"""

from __future__ import annotations

import json
from pathlib import Path

from pipelines.numerics_probe import CELLS, PINNED, run_cell
from srmpc.numerics import cpu_model

GOLDEN = json.loads((Path(__file__).parent / "data" / "golden_hashes.json").read_text())["cells"]
"""MD5 of each cell's bytes under ``SRMPC_NUMERICS=pinned`` (first 16 hex digits): tests/data/golden_hashes.json."""


def test_golden_hashes(tmp_path):
    """Pinned, every agent's short training and every controller's short evaluation give the committed bytes."""
    assert set(GOLDEN) == set(CELLS)
    digests = {cell: run_cell(cell, tmp_path, PINNED) for cell in CELLS}
    moved = {cell: (digest, GOLDEN[cell]) for cell, digest in digests.items() if digest != GOLDEN[cell]}
    assert not moved, (
        f"other bytes than the golden hashes on this CPU ({cpu_model()}): "
        + "; ".join(f"{cell} {got} (golden {want})" for cell, (got, want) in moved.items())
        + ". Find the library path that differs and pin it in srmpc/numerics.py; do not update the hashes for a "
        "machine.")


def test_evaluation_workers_inherit_the_pin(tmp_path):
    """Two worker processes (spawned interpreters) evaluate with the parent's pin: the same bytes as one process.
    Natively, a policy's actions in numpy follow the CPU's OpenBLAS core type (an AVX-512 CPU's: other bytes)."""
    assert run_cell("evaluate/ppo_lsi", tmp_path, PINNED, workers=2) == GOLDEN["evaluate/ppo_lsi"]
