"""Golden hashes: under the pinned numeric environment (srmpc.numerics), a short training of every agent and a
short evaluation of every controller (pipelines/numerics_probe.py's cells) give these bytes on every x86-64 CPU
with AVX2, and under every instruction-set cap that stands for another such CPU.

CI runs on whatever machine it is given (an Intel Xeon, an AMD EPYC, ...), so every CI run is a cross-machine
check; ``benchmarks/reproducibility.py`` records the CPU models where it passed
(``results/benchmarks/reproducibility.json``). If :func:`test_golden_hashes` fails on a new CPU, find the path
that differs and pin it in srmpc/numerics.py: never update :data:`GOLDEN` to make a machine pass. The hashes
change only in a commit that moves results on purpose, and that commit says so. ``python -m
pipelines.numerics_probe`` prints this machine's pinned hashes.

Hashed: a training's ``policy.pt``, an evaluation's ``episodes.csv`` (every metric of every episode, full
precision); ``summary.json`` is derived from them and records the machine.
"""

from __future__ import annotations

import pytest

from pipelines.numerics_probe import CAP_CELLS, CAPS, CELLS, NATIVE, NEEDS_AVX512, PINNED, run_cell
from srmpc.numerics import cpu_flags, cpu_model

GOLDEN = {
    "train/ppo": "c34127bdd359cab7",
    "train/ppo_lsi": "8973ff23279e14b0",
    "train/ppo_lsi_rss": "580578a564a77c5e",
    "train/ppo_sb3": "d7e03dc3d5970cfb",
    "evaluate/lane_keeping": "427e92daba5f894f",
    "evaluate/ppo_lsi": "da8c008abd1a66b1",
    "evaluate/ppo_sb3": "51cce7dc7d06c8f1",
    "evaluate/ltv_mpc": "205e6dbe62be3b38",
    "evaluate/srmpc": "5b6274825424bc64",
    "evaluate/srmpc_best_of_two": "22d2b76c1ff624e8",
    "evaluate/srmpc_sqp": "9c4aa363448d9f42",
    "evaluate/nmpc_rollout": "d019a22b55387cf6",
    "evaluate/highway_env_srmpc": "72bdca6180132386",
}
"""MD5 of each cell's bytes under ``SRMPC_NUMERICS=pinned`` (first 16 hex digits)."""

DEFAULT_CAPS = ("mkl_avx2", "aten_avx512", "onednn_avx2", "numpy_no_avx512")
"""Caps in the default suite; the others (``NUMBA_CPU_NAME`` compiles every kernel again) are slow."""


@pytest.fixture(scope="module")
def pinned_hashes(tmp_path_factory) -> dict[str, str]:
    out = tmp_path_factory.mktemp("pinned")
    return {cell: run_cell(cell, out, PINNED) for cell in CELLS}


def test_golden_hashes(pinned_hashes):
    """Pinned, every agent's short training and every controller's short evaluation give the committed bytes."""
    moved = {cell: (digest, GOLDEN.get(cell)) for cell, digest in pinned_hashes.items() if digest != GOLDEN.get(cell)}
    assert not moved, (
        f"other bytes than the golden hashes on this CPU ({cpu_model()}): "
        + "; ".join(f"{cell} {got} (golden {want})" for cell, (got, want) in moved.items())
        + ". Find the library path that differs and pin it in srmpc/numerics.py; do not update GOLDEN for a machine.")


def _check_cap(name: str, pinned_hashes: dict[str, str], out) -> None:
    if name in NEEDS_AVX512 and "avx512f" not in cpu_flags():
        pytest.skip(f"{name}: this CPU has no AVX-512")
    for cell in CAP_CELLS:
        digest = run_cell(cell, out, {**PINNED, **CAPS[name]})
        assert digest == pinned_hashes[cell], (f"pinned, cap {name} {CAPS[name]}: {cell} gives {digest}, not "
                                               f"{pinned_hashes[cell]}: that cap's library path is not pinned")


@pytest.mark.parametrize("name", DEFAULT_CAPS)
def test_caps_give_the_pinned_bytes(name, pinned_hashes, tmp_path):
    """An instruction-set cap standing for another AVX2 / AVX-512 CPU changes nothing when pinned."""
    _check_cap(name, pinned_hashes, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", [name for name in CAPS if name not in DEFAULT_CAPS and name != "aten_default"])
def test_more_caps_give_the_pinned_bytes(name, pinned_hashes, tmp_path):
    _check_cap(name, pinned_hashes, tmp_path)


def test_evaluation_workers_inherit_the_pin(pinned_hashes, tmp_path):
    """Two worker processes (spawned interpreters) evaluate with the parent's pin: the same bytes as one process.
    Natively, a policy's actions in numpy follow the CPU's OpenBLAS core type (an AVX-512 CPU's: other bytes)."""
    from pipelines import numerics_probe

    folder = tmp_path / "workers"
    overrides = ["+experiment=table/ppo_lsi", "scenario=dense", f"evaluation.episodes={numerics_probe.EPISODES}",
                 "evaluation.workers=2", f"evaluation.output_dir={folder}", "tracking.enabled=false"]
    import hashlib
    import os
    import subprocess
    import sys

    env = {k: v for k, v in os.environ.items() if k not in numerics_probe.CAP_VARIABLES} | PINNED
    done = subprocess.run([sys.executable, "-m", "srmpc", *overrides], cwd=numerics_probe.ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    digest = hashlib.md5((folder / "episodes.csv").read_bytes()).hexdigest()[:16]
    assert digest == pinned_hashes["evaluate/ppo_lsi"]


def test_without_the_pin_caps_change_the_bytes(tmp_path):
    """The caps are effective: natively, MKL's SSE2 branch or ATen without SIMD trains another PPO-L-SI policy, so
    the pinned tests above could fail."""
    native = run_cell("train/ppo_lsi", tmp_path / "native", NATIVE)
    capped = {name: run_cell("train/ppo_lsi", tmp_path / name, {**NATIVE, **CAPS[name]})
              for name in ("mkl_cbwr_compatible", "aten_default")}
    assert any(digest != native for digest in capped.values()), f"native {native}, capped {capped}"
