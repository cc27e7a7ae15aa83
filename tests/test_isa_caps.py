"""Instruction-set caps that stand for another x86-64 CPU: pinned, none changes a byte of the golden cells; natively,
some do (so the pinned test could fail). The golden hashes: tests/test_golden_hashes.py. Every cap's effect,
natively and pinned, on this machine: ``python -m pipelines.numerics_probe --caps`` (results/benchmarks/isa_caps.json).
"""

from __future__ import annotations

from pathlib import Path

import pytest

from pipelines.numerics_probe import CAP_CELLS, CAPS, NATIVE, NEEDS_AVX512, PINNED, run_cell
from srmpc.numerics import cpu_flags
from tests.golden_sets import this_vendors_set

DEFAULT_CAPS = ("numpy_no_avx512",)
"""Caps in the default suite: NumPy without its AVX-512 loops (NumPy now computes a pinned training's GEMMs and
vector math). MKL's settings, which the pin takes off the path: tests/test_mkl_off_the_path.py. The others are slow
(``NUMBA_CPU_NAME`` compiles every kernel again): ``make test-slow``."""


def _check_cap(name: str, out: Path) -> None:
    if name in NEEDS_AVX512 and "avx512f" not in cpu_flags():
        pytest.skip(f"{name}: this CPU has no AVX-512")
    golden = this_vendors_set()["cells"]
    for cell in CAP_CELLS:
        digest = run_cell(cell, out, {**PINNED, **CAPS[name]})
        assert digest == golden[cell], (f"pinned, cap {name} {CAPS[name]}: {cell} gives {digest}, not the golden "
                                        f"{golden[cell]}: that cap's library path is not pinned")


@pytest.mark.parametrize("name", DEFAULT_CAPS)
def test_caps_give_the_pinned_bytes(name, tmp_path):
    """An instruction-set cap standing for another AVX2 / AVX-512 CPU changes nothing when pinned."""
    _check_cap(name, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", [name for name in CAPS if name not in DEFAULT_CAPS])
def test_more_caps_give_the_pinned_bytes(name, tmp_path):
    _check_cap(name, tmp_path)


def test_without_the_pin_caps_change_the_bytes(tmp_path):
    """The caps are effective: natively, MKL's SSE2 branch or ATen without SIMD trains another PPO-L-SI policy, so
    the pinned tests could fail."""
    native = run_cell("train/ppo_lsi", tmp_path / "native", NATIVE)
    capped = {name: run_cell("train/ppo_lsi", tmp_path / name, {**NATIVE, **CAPS[name]})
              for name in ("mkl_cbwr_compatible", "aten_default")}
    assert any(digest != native for digest in capped.values()), f"native {native}, capped {capped}"
