"""Under ``SRMPC_NUMERICS=pinned`` no float op of a training reaches MKL, so MKL's dispatch cannot matter on any CPU.

MKL's kernels differ per CPU vendor even in its ``COMPATIBLE`` branch (issue "Byte-identical on Intel and AMD"), so
the pin takes MKL off the path (srmpc.pinned_kernels) instead of pinning it. Shown here on whatever CPU runs the
suite, with a one-iteration PPO-L-SI training (MKL's branch moved a training's bytes after one iteration):

- ``MKL_VERBOSE=1`` prints no BLAS or LAPACK call pinned, and does natively (so the check can fail);
- MKL's own settings (``MKL_ENABLE_INSTRUCTIONS``, ``MKL_CBWR``) leave the pinned bytes as they are. On an Intel
  Xeon these settings changed a training's bytes through MKL's BLAS and vector math (``MKL_VERBOSE`` does not
  print the vector math);
- every aten op that PPO-L-SI's and Stable-Baselines3's trainings call, counted below autograd, is either one that
  srmpc.pinned_kernels reroutes or one whose CPU kernel never calls MKL (:data:`UNROUTED_MKL_OPS` lists those that
  may, and none may appear): this covers the vector math that ``MKL_VERBOSE`` cannot see.
"""

from __future__ import annotations

import json

import pytest

from pipelines.numerics_probe import NATIVE, PINNED, run_cell
from srmpc.pinned_kernels import MATRIX_OPS, UNARY_FUNCTIONS, UNROUTED_MKL_OPS

MKL_SETTINGS = {
    "sse4_2": {"MKL_ENABLE_INSTRUCTIONS": "SSE4_2"},
    "avx512": {"MKL_ENABLE_INSTRUCTIONS": "AVX512"},
    "cbwr_auto": {"MKL_CBWR": "AUTO"},
    "cbwr_avx2": {"MKL_CBWR": "AVX2"},
}
"""MKL's dispatch settings: each made an Intel Xeon's training take another MKL code path."""


@pytest.fixture(scope="module")
def pinned_run(tmp_path_factory):
    """The one-iteration pinned PPO-L-SI training with MKL_VERBOSE=1, its aten ops counted: (MD5, log, ops)."""
    out = tmp_path_factory.mktemp("pinned")
    digest = run_cell("train/ppo_lsi", out, {**PINNED, "MKL_VERBOSE": "1"}, iterations=1, count_ops=True)
    return digest, (out / "train_ppo_lsi.log").read_text(), json.loads((out / "train_ppo_lsi.ops.json").read_text())


def test_pinned_training_makes_no_mkl_call(pinned_run, tmp_path):
    _, log, ops = pinned_run
    assert "MKL_VERBOSE" not in log, [line for line in log.splitlines() if "MKL_VERBOSE" in line][:5]
    assert {"addmm", "mm", "tanh", "exp", "log", "linalg_qr"} <= set(ops), "the training did not run its layers"
    run_cell("train/ppo_lsi", tmp_path, {**NATIVE, "MKL_VERBOSE": "1"}, iterations=1)
    native_log = (tmp_path / "train_ppo_lsi.log").read_text()
    assert "SGEMM" in native_log, "natively MKL_VERBOSE shows the GEMMs: the check above can fail"


@pytest.mark.parametrize("setting", sorted(MKL_SETTINGS))
def test_mkl_settings_leave_the_pinned_bytes(setting, pinned_run, tmp_path):
    digest = run_cell("train/ppo_lsi", tmp_path, {**PINNED, **MKL_SETTINGS[setting]}, iterations=1)
    assert digest == pinned_run[0], f"pinned, {MKL_SETTINGS[setting]} changed the training's bytes: MKL is on its path"


def test_every_op_of_a_training_is_rerouted_or_never_reaches_mkl(pinned_run, tmp_path):
    run_cell("train/ppo_sb3", tmp_path, PINNED, iterations=1, count_ops=True)
    sb3_ops = json.loads((tmp_path / "train_ppo_sb3.ops.json").read_text())
    for agent, ops in (("PPO-L-SI", pinned_run[2]), ("Stable-Baselines3's PPO", sb3_ops)):
        assert not set(ops) & UNROUTED_MKL_OPS, f"{agent} calls {sorted(set(ops) & UNROUTED_MKL_OPS)}: reroute them"
        routed = set(UNARY_FUNCTIONS) | set(MATRIX_OPS) | {"_foreach_sqrt"}
        assert {"addmm", "tanh", "exp"} <= set(ops) & routed
