"""Golden hashes: under the pinned numeric environment (srmpc.numerics), a short training of every agent and a
short evaluation of every controller (pipelines/numerics_probe.py's cells) give these bytes on every x86-64 CPU
with AVX2 (tests/data/golden_hashes.json); tests/test_isa_caps.py runs them under instruction-set caps that stand
for other such CPUs.

CI runs on whatever machine it is given (an Intel Xeon, an AMD EPYC, ...), so every CI run is a cross-machine
check; ``benchmarks/reproducibility.py`` records the CPU models where it passed
(``results/benchmarks/reproducibility.json``). Until the pinned trainings agree across vendors, each CPU vendor has
its own set (tests/golden_sets.py); :func:`test_vendor_sets_agree` is a strict xfail that fails the suite once they
become equal, and then its marker goes. If :func:`test_golden_hashes` fails on a new CPU of a vendor that has a set,
find the path that differs and pin it in srmpc/numerics.py: never update the golden hashes to make a machine pass.
A vendor without a set fails with one line saying how to add it. The hashes change only in a commit that moves
results on purpose, and that commit says so. ``python -m pipelines.numerics_probe`` prints this machine's pinned
hashes.

Hashed: a training's ``policy.pt``, an evaluation's ``episodes.csv`` (every metric of every episode, full
precision); ``summary.json`` is derived from them and records the machine.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipelines.numerics_probe import CELLS, PINNED, run_cell
from srmpc.numerics import cpu_model
from tests.golden_sets import this_vendors_set, vendor_sets

SETS = vendor_sets()
"""Each CPU vendor's MD5 of every cell under ``SRMPC_NUMERICS=pinned`` (tests/data/golden_hashes.json)."""
REPRODUCIBILITY = Path(__file__).parents[1] / "results" / "benchmarks" / "reproducibility.json"


def test_every_set_covers_every_cell():
    assert SETS and all(set(cells) == set(CELLS) for cells in SETS.values())


def test_every_set_records_where_it_was_made():
    """results/benchmarks/reproducibility.json names the CPU model and commit that made each vendor's set."""
    made = json.loads(REPRODUCIBILITY.read_text())["golden_sets"]
    assert set(made) == set(SETS)
    assert all(entry["model"] and entry["commit"] for entry in made.values())


@pytest.mark.xfail(strict=True, reason="the pinned trainings still reach MKL, whose kernels differ per CPU vendor")
def test_vendor_sets_agree():
    """One golden set for every vendor. A strict xfail until the pin takes MKL off every float path: once the sets
    are equal it fails the suite, and the marker goes."""
    first, *others = SETS.values()
    assert all(cells == first for cells in others)


def test_evaluations_agree_across_vendors():
    """The evaluations (numpy with OpenBLAS's Haswell kernels, numba without fast-math) already give one set."""
    evaluations = [{cell: digest for cell, digest in cells.items() if cell.startswith("evaluate/")}
                   for cells in SETS.values()]
    assert all(cells == evaluations[0] for cells in evaluations)


def test_golden_hashes(tmp_path):
    """Pinned, every agent's short training and every controller's short evaluation give this vendor's bytes."""
    golden = this_vendors_set()
    digests = {cell: run_cell(cell, tmp_path, PINNED) for cell in CELLS}
    moved = {cell: (digest, golden[cell]) for cell, digest in digests.items() if digest != golden[cell]}
    assert not moved, (
        f"other bytes than this vendor's golden hashes on this CPU ({cpu_model()}): "
        + "; ".join(f"{cell} {got} (golden {want})" for cell, (got, want) in moved.items())
        + ". Find the library path that differs and pin it in srmpc/numerics.py; do not update the hashes for a "
        "machine.")


def test_evaluation_workers_inherit_the_pin(tmp_path):
    """Two worker processes (spawned interpreters) evaluate with the parent's pin: the same bytes as one process.
    Natively, a policy's actions in numpy follow the CPU's OpenBLAS core type (an AVX-512 CPU's: other bytes)."""
    assert run_cell("evaluate/ppo_lsi", tmp_path, PINNED, workers=2) == this_vendors_set()["evaluate/ppo_lsi"]


def test_a_vendor_without_a_set_gets_one_line(monkeypatch):
    """A CPU vendor with no golden set fails with one line naming the vendor and how to add its set."""
    import tests.golden_sets as golden_sets

    monkeypatch.setattr(golden_sets, "cpuinfo", lambda: {"vendor_id": "HygonGenuine", "model name": "Hygon C86"})
    with pytest.raises(pytest.fail.Exception) as failure:
        this_vendors_set()
    message = str(failure.value)
    assert "\n" not in message and "HygonGenuine" in message and "pipelines.numerics_probe" in message
