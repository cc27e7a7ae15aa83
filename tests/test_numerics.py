"""The pinned numeric environment reaches every process: srmpc.numerics."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from srmpc.numerics import MODE_VARIABLE, PINNED_VARIABLES, REPLACED_VARIABLE, requested_mode

ROOT = Path(__file__).resolve().parents[1]

PROBE = """
import json, os, sys
VARIABLES = sys.argv[1:]
import numpy, torch          # loaded before srmpc, as a benchmark script does
import srmpc
from numpy._core._multiarray_umath import __cpu_features__
print(json.dumps({"aten": torch.backends.cpu.get_cpu_capability(), "numpy_avx512": __cpu_features__["X86_V4"],
                  "variables": {k: os.environ.get(k) for k in VARIABLES}}))
"""


def _environment(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in PINNED_VARIABLES and not k.startswith(MODE_VARIABLE)}
    return {**env, **extra}


def _probe(env: dict[str, str]) -> dict:
    done = subprocess.run([sys.executable, "-c", PROBE, *PINNED_VARIABLES], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_pinned_process_that_loaded_numpy_first_starts_again_pinned():
    """numpy and torch loaded before srmpc: the process starts again with the pin, and the libraries follow it."""
    seen = _probe(_environment(**{MODE_VARIABLE: "pinned", "OPENBLAS_CORETYPE": "Zen"}))
    assert seen["variables"] == PINNED_VARIABLES
    assert seen["aten"] == "AVX2"
    assert seen["numpy_avx512"] is False


def test_native_leaves_the_environment_alone():
    seen = _probe(_environment(**{MODE_VARIABLE: "native"}))
    assert all(value is None for value in seen["variables"].values())


@pytest.mark.parametrize("value", ["pinnd", ""])
def test_bad_mode_is_one_line(value):
    done = subprocess.run([sys.executable, "-m", "srmpc", "--cfg", "job"], cwd=ROOT, capture_output=True, text=True,
                          env=_environment(**{MODE_VARIABLE: value}), timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip().splitlines() == [
        f"srmpc: config error: {MODE_VARIABLE}={value!r}: must be one of pinned, native"]


def test_requested_mode_defaults_to_native_until_the_regeneration():
    assert requested_mode({}) == "native"
    assert requested_mode({MODE_VARIABLE: " Pinned "}) == "pinned"


def test_run_records_its_environment_outside_its_identity(tmp_path):
    """summary.json gets the pin, the CPU and the libraries under ``environment``; config.yaml (the identity that a
    resume compares) does not, so the same run resumes on another machine or with another pin."""
    out = tmp_path / "smoke"
    env = _environment(**{MODE_VARIABLE: "pinned", "OPENBLAS_CORETYPE": "Zen"})
    done = subprocess.run([sys.executable, "-m", "srmpc", "+experiment=smoke", f"evaluation.output_dir={out}",
                           "tracking.enabled=false"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    record = json.loads((out / "summary.json").read_text())["environment"]
    assert record["numerics"] == "pinned"
    assert record["pinned"] == PINNED_VARIABLES
    assert record["replaced"] == {"OPENBLAS_CORETYPE": "Zen"}
    assert record["cpu"]["model"] and record["cpu"]["avx2"] is True
    assert {"torch", "numpy", "numba", "mkl", "numpy_blas"} <= set(record["libraries"])
    config = (out / "config.yaml").read_text()
    assert "numerics" not in config and REPLACED_VARIABLE not in config and "environment" not in config
