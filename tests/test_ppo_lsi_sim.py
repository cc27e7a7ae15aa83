"""PPO-L-SI on the batched highway simulator: a short training raises return; resume is exact."""

from __future__ import annotations

import time

import pytest
import torch

from srmpc.agents.hyperparameters import PPOHyperparameters
from srmpc.agents.trainer import Trainer
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.sim.torchrl_env import TwinHighwayEnv
from tests.policy_returns import first_episode_returns

PARAMS = ScenarioParameters()
torch.set_num_threads(1)  # as the trainer does: small MLPs, and spinning threads stall a shared machine


@pytest.mark.timeout(600)
def test_short_training_on_the_simulator_raises_return(tmp_path):
    hp = PPOHyperparameters(num_envs=256, frames_per_batch=256 * 32, minibatch_size=2048, epochs=4,
                            total_frames=256 * 32 * 8, checkpoint_every=100)
    env = TwinHighwayEnv(PARAMS, hp.num_envs, seed=hp.seed, threads=1)
    probe = TwinHighwayEnv(PARAMS, 128, seed=1, threads=1)
    trainer = Trainer(env, hp, tmp_path, progress=False)
    before = first_episode_returns(probe, trainer.loss.actor_network, 200, seed=11)
    started = time.monotonic()
    trainer.train()
    trainer.close()
    elapsed = time.monotonic() - started
    after = first_episode_returns(probe, trainer.loss.actor_network, 200, seed=11)
    print(f"training {hp.total_frames} frames in {elapsed:.0f} s: before {before}, after {after}")
    # 65k frames: about 20 s on an idle 2-core machine (numba compilation aside); no wall-time
    # assertion, the machine is shared and timings are noisy
    # sum of the training reward r over each env's first episode (identical resets for both policies)
    assert after["train_return"] > 1.3 * before["train_return"], (before, after)
    assert after["steps"] > before["steps"] and after["cost_return"] < before["cost_return"]


def test_resume_on_the_simulator_reproduces_the_next_iterate(tmp_path):
    hp = PPOHyperparameters(num_envs=32, frames_per_batch=32 * 16, minibatch_size=256, epochs=2,
                            total_frames=32 * 16 * 10, checkpoint_every=1)
    straight = Trainer(TwinHighwayEnv(PARAMS, 32, seed=0, threads=1), hp, tmp_path / "a", progress=False)
    straight.train(max_iterations=3)
    Trainer(TwinHighwayEnv(PARAMS, 32, seed=0, threads=1), hp, tmp_path / "b", progress=False).train(max_iterations=2)
    resumed = Trainer(TwinHighwayEnv(PARAMS, 32, seed=99, threads=1), hp, tmp_path / "b", progress=False)
    assert resumed.resumed_from == 2
    resumed.train(max_iterations=1)
    expected, got = straight.loss.state_dict(), resumed.loss.state_dict()
    assert all(torch.equal(expected[k], got[k]) for k in expected)
