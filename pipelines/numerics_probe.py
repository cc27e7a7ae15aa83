"""Short cells whose bytes stand for the pipeline's numerics, and the instruction-set caps that stand for other CPUs.

    python -m pipelines.numerics_probe                 # this machine's pinned MD5 of every cell
    python -m pipelines.numerics_probe --caps [--out results/benchmarks/isa_caps.json]

A cell is a short training of one agent (PPO, PPO-L-SI, PPO-L-RSS, Stable-Baselines3's PPO; :data:`ITERATIONS`
iterations, its ``policy.pt``) or a short evaluation of one controller (:data:`EPISODES` dense episodes of a
published experiment with the committed policies, its ``episodes.csv``), run through ``python -m srmpc`` as a user
would. ``tests/test_golden_hashes.py`` holds their golden MD5s under ``SRMPC_NUMERICS=pinned``.

``--caps`` runs :data:`CAP_CELLS` natively and pinned under every cap of :data:`CAPS` (each cap an environment
variable that makes a library take the kernels of another CPU: AVX2 on an AVX-512 CPU, no SIMD, another OpenBLAS
core type, another numba target) and writes, per mode, each cell's MD5 without a cap and under each cap, and which
caps changed which cells. Caps that this CPU cannot run (an AVX-512 kernel on an AVX2 CPU) are skipped and listed.
``threads``: the pinned PPO-L-SI training at ``agent.num_threads=1`` and ``=2``.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUTPUT = ROOT / "results" / "benchmarks" / "isa_caps.json"
FRAMES_PER_ITERATION = 32768

ITERATIONS = 3
"""Training iterations: ATen's kernels without SIMD moved a training's bytes only after 3-4 iterations (an Intel
Xeon), MKL's branch after 1."""

EPISODES = 2
"""Dense episodes per evaluation cell."""

TRAININGS = {
    "train/ppo": ["stage=train", "agent=ppo"],
    "train/ppo_lsi": ["stage=train", "agent=ppo_lsi"],
    "train/ppo_lsi_rss": ["stage=train", "+experiment=training/ppo_lsi_rss"],
    "train/ppo_sb3": ["stage=train_sb3", "agent=ppo", "agent.name=ppo_sb3"],
}
"""Each agent: PPO, PPO-L-SI, PPO-L-RSS, Stable-Baselines3's PPO (their ``python -m srmpc`` overrides)."""

EVALUATIONS = {
    "evaluate/lane_keeping": "table/lane_keeping",
    "evaluate/ppo_lsi": "table/ppo_lsi",
    "evaluate/ppo_sb3": "table/ppo_sb3",
    "evaluate/ltv_mpc": "table/ltv_mpc",
    "evaluate/srmpc": "table/srmpc",
    "evaluate/srmpc_best_of_two": "variants/best_of_two",
    "evaluate/srmpc_sqp": "variants/sqp",
    "evaluate/nmpc_rollout": "nmpc/rollout",
    "evaluate/highway_env_srmpc": "crosscheck/highway_env_srmpc",
}
"""Each controller (lane keeping, a policy of ours and SB3's, LTV-MPC, SRMPC and two variants, the NMPC), the last
on highway-env itself (numpy): the experiment each runs."""

CELLS = (*TRAININGS, *EVALUATIONS)

CAP_CELLS = ("train/ppo_lsi", "evaluate/ppo_lsi", "evaluate/srmpc")
"""What a cap reruns: the paths through MKL and ATen (training), OpenBLAS and NumPy (a policy in numpy), numba (the
rollout and the planner)."""

CAPS = {
    "mkl_avx2": {"MKL_ENABLE_INSTRUCTIONS": "AVX2"},
    "mkl_avx512": {"MKL_ENABLE_INSTRUCTIONS": "AVX512"},
    "mkl_cbwr_avx2": {"MKL_CBWR": "AVX2"},
    "mkl_cbwr_compatible": {"MKL_CBWR": "COMPATIBLE"},
    "aten_avx2": {"ATEN_CPU_CAPABILITY": "avx2"},
    "aten_avx512": {"ATEN_CPU_CAPABILITY": "avx512"},
    "aten_default": {"ATEN_CPU_CAPABILITY": "default"},
    "onednn_avx2": {"ONEDNN_MAX_CPU_ISA": "AVX2"},
    "numpy_no_avx512": {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"},
    "openblas_haswell": {"OPENBLAS_CORETYPE": "Haswell"},
    "openblas_skylakex": {"OPENBLAS_CORETYPE": "SkylakeX"},
    "numba_haswell": {"NUMBA_CPU_NAME": "haswell"},
    "numba_generic": {"NUMBA_CPU_NAME": "generic"},
}
"""Instruction-set caps, each standing for another x86-64 CPU (``aten_default``: one without AVX2)."""

NEEDS_AVX512 = ("mkl_avx512", "aten_avx512", "openblas_skylakex")
"""Caps that ask for AVX-512 kernels: skipped on a CPU without avx512f (OpenBLAS's would not run)."""

CAP_VARIABLES = ("MKL_ENABLE_INSTRUCTIONS", "MKL_CBWR", "ATEN_CPU_CAPABILITY", "ONEDNN_MAX_CPU_ISA",
                 "NPY_DISABLE_CPU_FEATURES", "NPY_ENABLE_CPU_FEATURES", "NUMBA_CPU_NAME", "NUMBA_CPU_FEATURES",
                 "SRMPC_NUMERICS", "SRMPC_NUMERICS_REPLACED")
"""Removed from a cell's environment before its own are set. The machine's OPENBLAS_CORETYPE stays (this workplace
sets it on some CPUs): a native run keeps the machine's choice, and the pin replaces it."""

PINNED = {"SRMPC_NUMERICS": "pinned"}
NATIVE = {"SRMPC_NUMERICS": "native"}


def run_cell(cell: str, out: Path, environment: dict[str, str], extra: tuple[str, ...] = (), workers: int = 1,
             iterations: int = ITERATIONS, count_ops: bool = False) -> str:
    """Run ``cell`` through ``python -m srmpc`` into ``out`` with ``environment`` added (and the ``extra``
    overrides; an evaluation in ``workers`` processes, a training for ``iterations``); its bytes' MD5 (16 digits).
    The run's stdout and stderr are kept in ``<folder>.log``; with ``count_ops`` it runs under :func:`count_aten_ops`,
    whose counts go to ``<folder>.ops.json``."""
    env = {k: v for k, v in os.environ.items() if k not in CAP_VARIABLES and k != "SRMPC_PARENT_RUN_ID"}
    env.update(environment)
    folder = out / cell.replace("/", "_")
    if cell in TRAININGS:
        overrides = [*TRAININGS[cell], f"agent.total_frames={iterations * FRAMES_PER_ITERATION}",
                     f"agent.output_dir={folder}"]
        result_file = folder / "policy.pt"
    else:
        overrides = [f"+experiment={EVALUATIONS[cell]}", "scenario=dense", f"evaluation.episodes={EPISODES}",
                     f"evaluation.workers={workers}", f"evaluation.output_dir={folder}"]
        result_file = folder / "episodes.csv"
    entry = ["-m", "pipelines.numerics_probe", "--count-ops", str(folder) + ".ops.json", "--"] if count_ops else \
        ["-m", "srmpc"]
    command = [sys.executable, *entry, *overrides, *extra, "tracking.enabled=false"]
    done = subprocess.run(command, cwd=ROOT, env=env, capture_output=True, text=True, timeout=900)
    folder.parent.mkdir(parents=True, exist_ok=True)
    Path(str(folder) + ".log").write_text(done.stdout + done.stderr)
    if done.returncode != 0:
        raise RuntimeError(f"{cell} {environment}: exit {done.returncode}: {done.stderr.strip()[-1500:]}")
    return hashlib.md5(result_file.read_bytes()).hexdigest()[:16]


def count_aten_ops(overrides: list[str], out: Path) -> None:
    """Run ``python -m srmpc overrides`` in this process under a ``TorchDispatchMode`` that counts every aten op it
    calls (forward and backward, below autograd), and write the counts to ``out`` (JSON: op name -> calls)."""
    import runpy  # noqa: I001  (srmpc before torch: the pin first)
    from collections import Counter

    import srmpc  # noqa: F401  (the pin first: it may start this process again)
    from torch.utils._python_dispatch import TorchDispatchMode

    counts: Counter[str] = Counter()

    class CountOps(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            counts[func._schema.name.split("::")[-1]] += 1
            return func(*args, **(kwargs or {}))

    sys.argv = ["srmpc", *overrides]
    try:
        with CountOps():
            runpy.run_module("srmpc", run_name="__main__")
    except SystemExit as exit_:
        if exit_.code not in (None, 0):
            raise
    out.write_text(json.dumps(dict(sorted(counts.items())), indent=0) + "\n")


def cap_matrix(folder: Path) -> dict:
    """Per mode: :data:`CAP_CELLS`' MD5 without a cap and under each cap this CPU runs; the caps that moved a cell."""
    from srmpc.numerics import cpu_flags

    runnable = {name: cap for name, cap in CAPS.items() if name not in NEEDS_AVX512 or "avx512f" in cpu_flags()}
    report: dict = {"skipped": sorted(set(CAPS) - set(runnable)), "modes": {}}
    for mode, base in (("native", NATIVE), ("pinned", PINNED)):
        plain = {cell: run_cell(cell, folder / mode, base) for cell in CAP_CELLS}
        capped = {name: {cell: run_cell(cell, folder / f"{mode}_{name}", {**base, **cap}) for cell in CAP_CELLS}
                  for name, cap in runnable.items()}
        moved = {name: [cell for cell in CAP_CELLS if digests[cell] != plain[cell]] for name, digests in capped.items()}
        report["modes"][mode] = {"no_cap": plain, "caps": capped,
                                 "moved": {name: cells for name, cells in moved.items() if cells}}
        print(f"{mode}: caps that moved a cell: {report['modes'][mode]['moved'] or 'none'}", flush=True)
    two = run_cell("train/ppo_lsi", folder / "threads_2", PINNED, ("agent.num_threads=2",))
    one = report["modes"]["pinned"]["no_cap"]["train/ppo_lsi"]
    report["threads"] = {"cell": "train/ppo_lsi", "pinned_1_thread": one, "pinned_2_threads": two}
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--caps", action="store_true", help="the native and pinned cap matrix, written to --out")
    parser.add_argument("--out", type=Path, default=OUTPUT)
    parser.add_argument("--count-ops", type=Path, metavar="JSON",
                        help="run `python -m srmpc OVERRIDES` (after --) counting its aten ops into JSON")
    parser.add_argument("overrides", nargs="*", help="with --count-ops: the run's overrides")
    args = parser.parse_args()
    if args.count_ops:
        count_aten_ops(args.overrides, args.count_ops)
        return
    with tempfile.TemporaryDirectory() as folder:
        if not args.caps:
            for cell in CELLS:
                print(f'    "{cell}": "{run_cell(cell, Path(folder), PINNED)}",', flush=True)
            return
        report = cap_matrix(Path(folder))
    from srmpc.numerics import PINNED_VARIABLES, cpu_summary

    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    report = {"cpu": cpu_summary(), "commit": commit, "iterations": ITERATIONS, "episodes": EPISODES,
              "pin": PINNED_VARIABLES, "caps": CAPS, **report}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
