"""The golden hashes, one set per CPU vendor (tests/data/golden_hashes.json), until the pinned trainings agree.

Under ``SRMPC_NUMERICS=pinned`` a training still reached MKL, whose kernels are not the same code on an Intel Xeon
and an AMD EPYC, so the four golden trainings gave other bytes per vendor (issue "Byte-identical on Intel and
AMD"); the evaluations agree. Each vendor (``/proc/cpuinfo``'s ``vendor_id``) therefore has its own set of
:data:`pipelines.numerics_probe.CELLS`, and ``tests/test_golden_hashes.py`` compares this machine's bytes with its
vendor's. Where and at which commit each set was made: ``results/benchmarks/reproducibility.json``
(``golden_sets``).

A set is added for a vendor that has none, in a commit that says so: that is the only edit of this file outside a
commit that moves results on purpose.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from srmpc.numerics import cpu_model, cpuinfo

GOLDEN_FILE = Path(__file__).parent / "data" / "golden_hashes.json"
"""``{"about": ..., "vendors": {vendor_id: {cell: MD5 (16 hex digits)}}}``."""


def vendor_sets() -> dict[str, dict[str, str]]:
    """Every vendor's golden set: vendor_id -> cell -> MD5."""
    return json.loads(GOLDEN_FILE.read_text())["vendors"]


def no_set_message(vendor: str, model: str) -> str:
    """The one line a CPU vendor without a golden set gets: what to do."""
    return (f"no golden set for CPU vendor {vendor!r} ({model}) in tests/data/golden_hashes.json: run `python -m "
            f"pipelines.numerics_probe` on this machine, add its hashes under vendors.{vendor} in a commit that says "
            f"so, and `python benchmarks/reproducibility.py --golden-set` to record where they were made")


def this_vendors_set() -> dict[str, str]:
    """This CPU vendor's golden set; a vendor without one fails the calling test with one line saying what to do."""
    vendor, sets = cpuinfo().get("vendor_id", "unknown"), vendor_sets()
    if vendor not in sets:
        pytest.fail(no_set_message(vendor, cpu_model()), pytrace=False)
    return sets[vendor]
