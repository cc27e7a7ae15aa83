"""The numerics fingerprint (pipelines/numerics_fingerprint.py): each building block of a training, pinned, gives
the golden MD5. When a CPU trains other bytes than the golden set, this names the first primitive that differs."""

from __future__ import annotations

from pipelines.numerics_fingerprint import BLOCKS, run_fingerprint
from pipelines.numerics_probe import NATIVE, PINNED
from srmpc.numerics import cpu_model
from tests.golden_sets import set_name, this_vendors_set


def test_fingerprint_names_the_first_block_that_differs():
    golden = this_vendors_set()["fingerprint"]
    got = run_fingerprint(PINNED)
    differing = [block for block in BLOCKS if got[block] != golden[block]]
    assert not differing, (f"pinned, on {cpu_model()}, the first building block that differs from the golden set "
                           f"({set_name()}) is {differing[0]!r} ({got[differing[0]]}, golden {golden[differing[0]]});"
                           f" all that differ: {differing}")


def test_the_fingerprint_sees_the_pin():
    """Natively the rerouted blocks take MKL's kernels: at least the GEMMs give other bytes, so the fingerprint can
    tell a path that is not pinned."""
    native, pinned = run_fingerprint(NATIVE), this_vendors_set()["fingerprint"]
    assert native["gemm"] != pinned["gemm"]
