"""Faults at run time end in one line naming the path, without a traceback: a truncated or corrupted
policy.pt, a missing policy file, an output directory that cannot be created."""

from __future__ import annotations

import pickle
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from srmpc.agents.checkpoint import CheckpointError, load_actor, load_actor_mean_layers, load_checkpoint, save_policy
from srmpc.agents.networks import make_actor

ROOT = Path(__file__).resolve().parents[1]


def _policy_bytes(tmp_path: Path) -> bytes:
    """A policy.pt as training writes it (2x8 actor)."""
    low, high = torch.tensor([-0.1, -5.0]), torch.tensor([0.1, 5.0])
    actor = make_actor(30, low, high, [8, 8])
    path = tmp_path / "whole_policy.pt"
    save_policy(actor.state_dict(), {"observation_dim": 30, "action_low": low, "action_high": high,
                                     "hidden_sizes": [8, 8]}, path)
    loaded = load_actor(path).state_dict()  # whole, it loads: the damage below is what fails
    assert all(torch.equal(value, loaded[key]) for key, value in actor.state_dict().items())
    return path.read_bytes()


def _damaged(tmp_path: Path) -> dict[str, Path]:
    whole = _policy_bytes(tmp_path)
    files = {
        "truncated": whole[: len(whole) // 2],
        "end_cut_off": whole[: len(whole) - 200],  # torch's zip reader fails with OSError EINVAL here
        "empty": b"",
        "garbage": b"\x00\x01 not a torch file " * 50,
        "not_a_policy": pickle.dumps({"observation_dim": 30}),
    }
    paths = {}
    for name, content in files.items():
        paths[name] = tmp_path / f"{name}.pt"
        paths[name].write_bytes(content)
    torch.save([1, 2, 3], tmp_path / "a_list.pt")
    paths["a_list"] = tmp_path / "a_list.pt"
    return paths


def test_a_damaged_policy_or_checkpoint_is_one_line_naming_the_file(tmp_path):
    for name, path in _damaged(tmp_path).items():
        for load in (load_actor, load_actor_mean_layers):
            with pytest.raises(CheckpointError) as caught:
                load(path)
            message = str(caught.value)
            assert message.startswith(f"{path}: not a") and "\n" not in message, (name, load.__name__, message)
    checkpoint_dir = tmp_path / "run"
    checkpoint_dir.mkdir()
    (checkpoint_dir / "last.pt").write_bytes(b"PK\x03\x04 torn")
    with pytest.raises(CheckpointError, match=r"last.pt: not a readable training checkpoint"):
        load_checkpoint(checkpoint_dir)


def _cli(tmp_path: Path, *overrides: str) -> subprocess.CompletedProcess:
    command = [sys.executable, "-m", "srmpc", "+experiment=smoke", "evaluation.episodes=1", "tracking.enabled=false",
               f"hydra.run.dir={tmp_path / 'hydra'}", *overrides]
    return subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=600)


def _one_line(result: subprocess.CompletedProcess) -> str:
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr[-3000:]
    return lines[0]


@pytest.mark.parametrize(
    ("case", "code", "expected"),
    [
        ("truncated policy", 1, "srmpc: error: {policy}: not a readable policy file (truncated or corrupted?"),
        ("missing policy", 2, "srmpc: config error: controller.policy_path='{missing}': no such policy file"),
        ("unwritable output", 2, "srmpc: config error: evaluation.output_dir={blocked}/eval: cannot write there"),
    ],
)
def test_cli_runtime_fault_is_one_line_naming_the_path(tmp_path, case, code, expected):
    policy = tmp_path / "policy.pt"
    whole = _policy_bytes(tmp_path)
    policy.write_bytes(whole[: len(whole) - 200])
    blocked = tmp_path / "a_file"
    blocked.write_text("not a directory\n")
    missing = tmp_path / "results" / "training" / "ppo_lsi" / "policy.pt"
    overrides = {
        "truncated policy": ["controller=policy", f"controller.policy_path={policy}",
                             f"evaluation.output_dir={tmp_path / 'eval'}"],
        "missing policy": ["controller=policy", f"controller.policy_path={missing}",
                           f"evaluation.output_dir={tmp_path / 'eval'}"],
        "unwritable output": ["controller=lane_keeping", f"evaluation.output_dir={blocked / 'eval'}"],
    }[case]
    result = _cli(tmp_path, *overrides)
    assert result.returncode == code, result.stderr[-3000:]
    assert _one_line(result).startswith(expected.format(policy=policy, missing=missing, blocked=blocked))
    assert not (tmp_path / "eval").exists()
