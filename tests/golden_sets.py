"""The golden hashes (tests/data/golden_hashes.json): one set for every CPU vendor, and a set of its own for a vendor
whose pinned bytes differ.

A set holds the MD5 of each cell of :data:`pipelines.numerics_probe.CELLS` (``cells``: short trainings and
evaluations) and of each block of :data:`pipelines.numerics_fingerprint.BLOCKS` (``fingerprint``), under
``SRMPC_NUMERICS=pinned``. With MKL off every float path (srmpc.pinned_kernels), ``vendors`` is empty: every x86-64
CPU with AVX2 and FMA is expected to give the one set. If a CPU of another vendor (``/proc/cpuinfo``'s
``vendor_id``) gives other bytes, issue "Byte-identical on Intel and AMD" item 0's rule applies again: add that
vendor's set under ``vendors`` in a commit that says so, mark ``test_one_set_for_every_vendor`` as a strict xfail
again, and take the primitive that the fingerprint names off the vendor-dependent path. Where and at which commit
each set was made: ``results/benchmarks/reproducibility.json`` (``golden_sets``: ``shared``, and each vendor's).

Adding a vendor's first set is the only edit of this file outside a commit that moves results on purpose.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from srmpc.numerics import cpuinfo

GOLDEN_FILE = Path(__file__).parent / "data" / "golden_hashes.json"
"""``{"about": ..., "cells": {cell: MD5}, "fingerprint": {block: MD5}, "vendors": {vendor_id: {"cells": ...,
"fingerprint": ...}}}`` (MD5: the first 16 hex digits)."""

SHARED = "shared"
"""The key of the set for every vendor without one of its own (``golden_sets`` in reproducibility.json)."""


def golden_file() -> dict:
    return json.loads(GOLDEN_FILE.read_text())


def vendor_sets() -> dict[str, dict[str, dict[str, str]]]:
    """The vendors with a set of their own: vendor_id -> {"cells": ..., "fingerprint": ...}."""
    return golden_file()["vendors"]


def shared_set() -> dict[str, dict[str, str]]:
    """The set for every vendor without one of its own: {"cells": ..., "fingerprint": ...}."""
    golden = golden_file()
    return {"cells": golden["cells"], "fingerprint": golden["fingerprint"]}


def set_name(vendor: str | None = None) -> str:
    """Which set a vendor (this CPU's by default) is compared with: its own vendor_id, or :data:`SHARED`."""
    vendor = cpuinfo().get("vendor_id", "unknown") if vendor is None else vendor
    return vendor if vendor in vendor_sets() else SHARED


def this_vendors_set() -> dict[str, dict[str, str]]:
    """The set this CPU's bytes are compared with: {"cells": ..., "fingerprint": ...}."""
    name = set_name()
    return shared_set() if name == SHARED else vendor_sets()[name]


def set_digest(golden: dict[str, dict[str, str]]) -> str:
    """An MD5 (16 hex digits) of a whole set: which set a machine passed (reproducibility.json)."""
    return hashlib.md5(json.dumps(golden, sort_keys=True).encode()).hexdigest()[:16]
