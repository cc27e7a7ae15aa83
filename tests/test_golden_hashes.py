"""Golden hashes: under the pinned numeric environment (srmpc.numerics), a short training of every agent and a
short evaluation of every controller (pipelines/numerics_probe.py's cells) give these bytes on every x86-64 CPU
with AVX2 and FMA (tests/data/golden_hashes.json, tests/golden_sets.py); tests/test_mkl_off_the_path.py shows that
MKL's dispatch cannot move them, tests/test_isa_caps.py that other instruction-set caps cannot, and
tests/test_numerics_fingerprint.py names the building block that differs when they move.

CI runs on whatever machine it is given (an Intel Xeon, an AMD EPYC, ...), so every CI run is a cross-machine
check; ``benchmarks/reproducibility.py`` records the CPU models where it passed
(``results/benchmarks/reproducibility.json``). If :func:`test_golden_hashes` fails on a new CPU, find the path
that differs (the fingerprint names it) and take it off the vendor-dependent path in srmpc/numerics.py or
srmpc/pinned_kernels.py: never update the golden hashes to make a machine pass. If a CPU vendor cannot be made to
agree at once, give it a set of its own (tests/golden_sets.py says how), so that CI stays green. The hashes change
only in a commit that moves results on purpose, and that commit says so. ``python -m pipelines.numerics_probe``
prints this machine's pinned hashes.

Hashed: a training's ``policy.pt``, an evaluation's ``episodes.csv`` (every metric of every episode, full
precision); ``summary.json`` is derived from them and records the machine.
"""

from __future__ import annotations

import json
from pathlib import Path

from pipelines.numerics_fingerprint import BLOCKS
from pipelines.numerics_probe import CELLS, PINNED, run_cell
from srmpc.numerics import cpu_model
from tests.golden_sets import SHARED, set_name, shared_set, this_vendors_set, vendor_sets

REPRODUCIBILITY = Path(__file__).parents[1] / "results" / "benchmarks" / "reproducibility.json"


def test_every_set_covers_every_cell_and_block():
    for golden in (shared_set(), *vendor_sets().values()):
        assert set(golden["cells"]) == set(CELLS) and set(golden["fingerprint"]) == set(BLOCKS)


def test_one_set_for_every_vendor():
    """With MKL off every float path, no CPU vendor has a set of its own. If one must get one (its bytes differ),
    mark this test ``xfail(strict=True)`` in the same commit: it then fails the suite once the sets agree again."""
    assert not vendor_sets(), f"vendors with a set of their own: {sorted(vendor_sets())}"


def test_every_set_records_where_it_was_made():
    """results/benchmarks/reproducibility.json names the CPU model and commit that made each set."""
    made = json.loads(REPRODUCIBILITY.read_text())["golden_sets"]
    assert set(made) == {SHARED, *vendor_sets()}
    assert all(entry["model"] and entry["vendor"] and entry["commit"] for entry in made.values())


def test_golden_hashes(tmp_path):
    """Pinned, every agent's short training and every controller's short evaluation give the golden bytes."""
    golden = this_vendors_set()["cells"]
    digests = {cell: run_cell(cell, tmp_path, PINNED) for cell in CELLS}
    moved = {cell: (digest, golden[cell]) for cell, digest in digests.items() if digest != golden[cell]}
    assert not moved, (
        f"other bytes than the golden set ({set_name()}) on this CPU ({cpu_model()}): "
        + "; ".join(f"{cell} {got} (golden {want})" for cell, (got, want) in moved.items())
        + ". tests/test_numerics_fingerprint.py names the first building block that differs; take it off the "
        "vendor-dependent path (srmpc/pinned_kernels.py); do not update the hashes for a machine.")


def test_evaluation_workers_inherit_the_pin(tmp_path):
    """Two worker processes (spawned interpreters) evaluate with the parent's pin: the same bytes as one process.
    Natively, a policy's actions in numpy follow the CPU's OpenBLAS core type (an AVX-512 CPU's: other bytes)."""
    assert run_cell("evaluate/ppo_lsi", tmp_path, PINNED, workers=2) == this_vendors_set()["cells"]["evaluate/ppo_lsi"]


def test_training_bytes_do_not_depend_on_the_thread_count(tmp_path):
    """Pinned, PPO-L-SI trained on 2 torch threads gives the golden (1-thread) bytes (natively it does not: MKL's
    kernels follow the thread count): OpenBLAS runs on one thread, and no ATen reduction on a training's path is
    split by thread."""
    assert run_cell("train/ppo_lsi", tmp_path, PINNED, ("agent.num_threads=2",)) == \
        this_vendors_set()["cells"]["train/ppo_lsi"]
