"""Fill numba's on-disk cache once, before many processes need the kernels.

    python -m srmpc.precompile [--jobs N]

Numba compiles a kernel on its first call and caches it next to its source (``__pycache__``,
kept consistent by :mod:`srmpc.sim.jit_cache`). A fresh clone has no cache: a short SRMPC, NMPC
or LTV-MPC run then spends nearly all its time compiling, minutes of CPU in all. Processes started at
once on a cold cache (pytest-xdist workers, the test suite's CLI runs, evaluation workers, SLURM
shards on a shared file system) each compile the same kernels, on cores that could run something
else. This module runs one short closed loop of each planner and one iteration of twin training,
``--jobs`` at a time (default: every core this process may use), each in its own process; from
then on every process loads the kernels from the cache. With a warm cache it does nothing.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

PACKAGE_ROOT = Path(__file__).resolve().parent
LARGEST_KERNEL_INDEX = "mpc/__pycache__/compiled_step.srmpc_step-*.nbi"
"""numba's index file of SRMPC's compiled step: the kernel that takes longest to compile and calls most of
the others (twin, rollout, QP, interior point); present once a process has compiled and cached them."""

SHORT_RUN = ("evaluation.episodes=1", "scenario.episode_steps=5", "evaluation.workers=1", "tracking.enabled=false")
"""A 5-step episode: every kernel of a planner's closed loop is called at least once."""
TRAINING_RUN = ("stage=train", "agent=ppo_lsi", "agent.num_envs=8", "agent.frames_per_batch=64",
                "agent.minibatch_size=32", "agent.epochs=1", "agent.total_frames=64", "tracking.enabled=false")
"""One iteration of PPO-L-SI on the batched twin (its vectorized step and reset kernels)."""
RUNS = (
    ("controller=srmpc",) + SHORT_RUN,
    ("controller=nmpc", "controller.initial_guess=rollout") + SHORT_RUN,
    ("controller=ltv_mpc",) + SHORT_RUN,
    TRAINING_RUN,
)
"""Longest first, so that ``--jobs`` processes finish together."""


def cache_is_warm() -> bool:
    """Whether numba's cache holds SRMPC's compiled step for the current sources."""
    from srmpc.sim.jit_cache import drop_stale_numba_cache

    drop_stale_numba_cache()
    return any(PACKAGE_ROOT.glob(LARGEST_KERNEL_INDEX))


def run_once(overrides: tuple[str, ...], output_dir: Path) -> None:
    """``python -m srmpc <overrides>`` writing into ``output_dir``; raise with its last output lines if it fails."""
    where = "agent.output_dir" if "stage=train" in overrides else "evaluation.output_dir"
    command = [sys.executable, "-m", "srmpc", *overrides, f"{where}={output_dir}"]
    result = subprocess.run(command, capture_output=True, text=True)
    if result.returncode != 0:
        tail = "\n".join((result.stdout + result.stderr).strip().splitlines()[-5:])
        raise RuntimeError(f"{' '.join(command[1:])} exited with {result.returncode}:\n{tail}")


def precompile(jobs: int) -> bool:
    """Compile every kernel into the cache unless it is warm; return whether it compiled."""
    if cache_is_warm():
        return False
    with tempfile.TemporaryDirectory(prefix="srmpc-precompile-") as directory, ThreadPoolExecutor(jobs) as pool:
        list(pool.map(run_once, RUNS, [Path(directory) / str(i) for i in range(len(RUNS))]))
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--jobs", type=int, default=len(os.sched_getaffinity(0)),
                        help="processes at once (default: every core this process may use)")
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs={args.jobs}: must be >= 1")
    try:
        compiled = precompile(args.jobs)
    except RuntimeError as error:
        print(f"srmpc.precompile: error: {error}", file=sys.stderr)
        return 1
    print("numba cache: compiled" if compiled else "numba cache: already warm")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
