"""The peer PPO (srmpc.sb3_ppo): the SB3 VecEnv adapter, training with resume, the exported policy, the stage."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from srmpc.config.compose import compose_config, to_objects
from srmpc.controllers.policy import PolicyController
from srmpc.sb3_ppo.training import train_sb3_ppo
from srmpc.sb3_ppo.vec_env import TwinSb3VecEnv

ROOT = Path(__file__).resolve().parents[1]
LOW, HIGH = np.array([-0.1, -5.0]), np.array([0.1, 5.0])


def small_config(tmp: Path, total_frames: int, *extra: str):
    return to_objects(compose_config([
        "agent=ppo", "agent.name=ppo_sb3", "agent.num_envs=16", "agent.frames_per_batch=256", "agent.minibatch_size=64",
        f"agent.total_frames={total_frames}", "agent.checkpoint_every=2", f"agent.output_dir={tmp}", *extra]))


def test_actions_in_unit_box_map_onto_the_physical_box():
    env = TwinSb3VecEnv(small_config(Path("unused"), 256).scenario, 2, seed=0)
    corners = env.physical_actions(np.array([[-1.0, -1.0], [1.0, 1.0]]))
    # the bounds of the twin's float32 action space (0.1 rad is 0.1 + 1.5e-9 there; the twin clips to 0.1)
    assert np.array_equal(corners, np.array([LOW, HIGH]).astype(np.float32).astype(np.float64))
    assert np.abs(corners - np.array([LOW, HIGH])).max() < 2e-9
    assert np.array_equal(env.physical_actions(np.zeros((1, 2))), np.zeros((1, 2)))
    assert env.action_space.low.tolist() == [-1.0, -1.0] and env.action_space.high.tolist() == [1.0, 1.0]


def test_episode_ends_carry_terminal_observation_and_truncation_flag_as_sb3_expects():
    scenario = small_config(Path("unused"), 256, "scenario.episode_steps=6").scenario
    env = TwinSb3VecEnv(scenario, 8, seed=1)
    env.seed(1)
    env.reset()
    rng = np.random.default_rng(0)
    seen_truncated = seen_terminated = 0
    for _ in range(12):
        actions = rng.uniform(-1, 1, (8, 2)).astype(np.float32)
        observation, reward, dones, infos = env.step(actions)
        assert observation.shape == (8, 30) and reward.dtype == np.float32 and dones.dtype == bool
        for i, info in enumerate(infos):
            if not dones[i]:
                assert "terminal_observation" not in info
                continue
            assert info["terminal_observation"].shape == (30,)
            assert not np.array_equal(info["terminal_observation"], observation[i])  # the new episode's first
            truncated = info["TimeLimit.truncated"]
            assert truncated == (info["termination"] == "")  # ended by the time limit, not by a crash or road exit
            seen_truncated += truncated
            seen_terminated += not truncated
    assert seen_truncated > 0  # 6-step episodes: every scene that survives is truncated at steps 6 and 12
    finished = env.finished
    assert len(finished) == seen_truncated + seen_terminated
    assert all(1 <= e["steps"] <= 6 for e in finished)
    assert all(e["cost_return"] in (0.0, 1.0) for e in finished)


def test_training_resumes_bit_for_bit_and_exports_sb3s_deterministic_action(tmp_path):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    config = small_config(straight, 1024)
    train_sb3_ppo(config.scenario, config.agent, straight)
    half = small_config(resumed, 512)
    train_sb3_ppo(half.scenario, half.agent, resumed)  # stops after 2 iterations, checkpointed
    train_sb3_ppo(config.scenario, config.agent, resumed)  # resumes to 4
    rows = [list(csv.DictReader((d / "metrics.csv").open())) for d in (straight, resumed)]
    assert len(rows[0]) == len(rows[1]) == 4
    for a, b in zip(*rows, strict=True):
        for key in ("frames", "episodes", "episode/return", "episode/cost_return", "cost_rate", "step/reward"):
            assert a[key] == b[key], key
    policies = [torch.load(d / "policy.pt", weights_only=False) for d in (straight, resumed)]
    assert all(torch.equal(x, y) for x, y in zip(policies[0]["weights"], policies[1]["weights"], strict=True))
    assert policies[0]["action_head"] == "clipped_gaussian_mean" and policies[0]["frames"] == 1024

    from stable_baselines3 import PPO

    model = PPO.load(straight / "last.zip", device="cpu")
    env = TwinSb3VecEnv(config.scenario, 8, seed=3)
    env.seed(3)
    observation = env.reset()
    for _ in range(20):
        observation, *_ = env.step(np.random.default_rng(1).uniform(-1, 1, (8, 2)))
    sb3_action, _ = model.predict(observation, deterministic=True)
    expected = env.physical_actions(np.clip(sb3_action, -1.0, 1.0))
    policy = PolicyController.from_policy_file(straight / "policy.pt", LOW, HIGH).policy
    ours = np.clip(policy(observation), LOW, HIGH)
    # float32 (SB3) against float64 (the export): largest deviation measured 7.4e-8 (in m/s^2 and rad)
    assert np.abs(ours - expected).max() < 1e-6


def test_stage_refuses_the_constrained_agent_in_one_line(tmp_path):
    result = subprocess.run([sys.executable, "-m", "srmpc", "stage=train_sb3", "agent=ppo_lsi",
                             "tracking.enabled=false", f"agent.output_dir={tmp_path / 'run'}",
                             f"hydra.run.dir={tmp_path / 'hydra'}"],
                            cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "agent.constrained=True" in lines[0] and "train_sb3" in lines[0]
    assert not (tmp_path / "run").exists()


def test_stage_trains_into_its_directory_with_the_implementation_in_its_config(tmp_path):
    out = tmp_path / "run"
    overrides = ["stage=train_sb3", "agent=ppo", "agent.name=ppo_sb3", "agent.num_envs=16",
                 "agent.frames_per_batch=256", "agent.minibatch_size=64", "agent.total_frames=512",
                 "tracking.enabled=false",
                 f"agent.output_dir={out}", f"hydra.run.dir={tmp_path / 'hydra'}"]
    result = subprocess.run([sys.executable, "-m", "srmpc", *overrides], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "implementation: stable-baselines3==" in (out / "config.yaml").read_text()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 512 and summary["implementation"].startswith("stable-baselines3==")
    rows = [{k: float(v) for k, v in row.items() if v} for row in csv.DictReader((out / "metrics.csv").open())]
    assert [row["frames"] for row in rows] == [256.0, 512.0]
    for row in rows:  # an event ends its episode: a batch's events are the cost returns of the episodes it ended
        events = row["episodes"] * row["episode/cost_return"] if row["episodes"] else 0.0
        assert row["cost_rate"] * 256 == pytest.approx(events, abs=1e-9), row  # a mean times its count: equal here
    # the summary's window, the last 5% of the frames, is the last iteration
    assert (summary["cost_rate"], summary["episodes"]) == (rows[-1]["cost_rate"], rows[-1]["episodes"])
    again = subprocess.run([sys.executable, "-m", "srmpc", *overrides[:-2], "agent.seed=5", f"agent.output_dir={out}",
                            f"hydra.run.dir={tmp_path / 'hydra2'}"], cwd=ROOT, capture_output=True, text=True)
    assert again.returncode == 2 and "holds results of a different config" in again.stderr


@pytest.mark.parametrize(("overrides", "command"), [
    ("agent=ppo agent.seed=1", ["stage=train", "agent=ppo", "agent.seed=1"]),
    ("stage=train_sb3 agent=ppo agent.name=ppo_sb3", ["stage=train_sb3", "agent=ppo", "agent.name=ppo_sb3"]),
])
def test_train_runs_starts_the_stage_a_run_names(overrides, command):
    import importlib.util

    spec = importlib.util.spec_from_file_location("train_runs", ROOT / "pipelines" / "train_runs.py")
    train_runs = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("train_runs", train_runs)  # its dataclass looks its module up
    spec.loader.exec_module(train_runs)
    assert train_runs.training_command(overrides) == command
