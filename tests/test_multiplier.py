"""The multiplier's published options (issue 9), its diagnostic, and the over-seeds training summary."""

from __future__ import annotations

import hashlib
import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModule

from srmpc.agents.hyperparameters import PPOHyperparameters, TrainTask
from srmpc.agents.multiplier_diagnostic import event_ahead
from srmpc.agents.networks import COST_VALUE_KEY
from srmpc.agents.ppo_lsi_loss import PPOLSILoss
from srmpc.agents.toy_env import ToyConstrainedEnv
from srmpc.agents.trainer import MULTIPLIER_JSON, MULTIPLIER_SAMPLES_CSV, Trainer, build_loss
from srmpc.confidence_intervals import t_interval

ROOT = Path(__file__).resolve().parents[1]
torch.set_num_threads(1)
LOW, HIGH = torch.tensor([-0.1, -5.0]), torch.tensor([0.1, 5.0])


def small(**overrides) -> PPOHyperparameters:
    settings = dict(num_envs=16, frames_per_batch=16 * 16, minibatch_size=64, total_frames=16 * 16 * 3,
                    epochs=2, checkpoint_every=100, task=TrainTask.toy)
    settings.update(overrides)
    return PPOHyperparameters(**settings)


def test_event_ahead_marks_the_window_before_an_event_and_stops_at_the_episode_end():
    # one scene, 8 steps: an episode ends without an event at t=2, the next one ends in a collision at t=6
    event_cost = torch.tensor([[0, 0, 0, 0, 0, 0, 1, 0]], dtype=torch.float32)
    done = torch.tensor([[0, 0, 1, 0, 0, 0, 1, 0]], dtype=torch.bool)
    ahead = event_ahead(event_cost, done, horizon_steps=4)
    # t=3..6 see the collision within 4 steps; t=0..2 are cut off by the done at t=2; t=7 sees nothing
    assert ahead.tolist() == [[False, False, False, True, True, True, True, False]]


class _FixedCostValue(torch.nn.Module):
    def __init__(self, values: torch.Tensor):
        super().__init__()
        self.values = values

    def forward(self, observation):
        return self.values.reshape(-1, 1)


def test_violation_normalization_divides_the_violation_by_its_std_before_the_clip():
    torch.manual_seed(0)
    hp = small()
    reference = build_loss(30, LOW, HIGH, hp)
    values = torch.tensor([-1.0, -1.0, -1.0, 0.05, 0.5, 2.0])
    critic = TensorDictModule(_FixedCostValue(values), in_keys=["observation"], out_keys=[COST_VALUE_KEY])
    env = ToyConstrainedEnv(6, seed=1)
    with torch.no_grad():
        batch = reference.compute_advantages(env.rollout(1, reference.actor_network,
                                                         break_when_any_done=False)).reshape(-1)
    for normalize in (False, True):
        loss = PPOLSILoss(reference.actor_network, reference.critic_network, critic, reference.multiplier_network,
                          cost_threshold=0.0, violation_clip=(0.3, 100.0), violation_normalization=normalize)
        lam = loss.multiplier_network(batch.select("observation")).get("lambda").flatten()
        violation = values / values.std() if normalize else values
        expected = -(lam * violation.clamp(-0.3, 100.0)).mean()
        assert torch.allclose(loss(batch)["loss_multiplier"], expected, rtol=1e-6, atol=1e-7)


def test_multiplier_takes_its_steps_and_its_learning_rate_decays_to_the_final_value(tmp_path):
    hp = small(multiplier_steps=3, multiplier_lr=1e-3, multiplier_lr_final=1e-4, multiplier_max_grad_norm=3.0)
    trainer = Trainer(ToyConstrainedEnv(hp.num_envs, seed=0), hp, tmp_path, progress=False)
    trainer.train(max_iterations=1)
    steps = {int(state["step"]) for state in trainer.optimizers["multiplier"].state.values()}
    actor_steps = {int(state["step"]) for state in trainer.optimizers["actor"].state.values()}
    assert steps == {3} and actor_steps == {hp.epochs * hp.frames_per_batch // hp.minibatch_size}
    trainer.train()
    trainer.close()
    assert math.isclose(trainer.optimizers["multiplier"].param_groups[0]["lr"], 1e-4)
    stats = json.loads((tmp_path / MULTIPLIER_JSON).read_text())  # strict JSON: no NaN literals
    # the last batch, 16 scenes x 16 steps; the states whose 10-step look-ahead fits in it: 16 x (16 - 10 + 1)
    assert (stats["states"], stats["horizon_steps"]) == (16 * 7, 10)
    header, *lines = (tmp_path / MULTIPLIER_SAMPLES_CSV).read_text().splitlines()
    assert header == "lambda,cost_value,event_ahead"
    # fewer states than the subsample's size: every state before an event first, then every state once
    rows = np.array([[float(v) for v in line.split(",")] for line in lines])
    before_event = round(stats["share_event_ahead"] * stats["states"])
    assert len(rows) == before_event + stats["states"] and np.all(rows[:before_event, 2] == 1.0)
    lam, cost_value, ahead = rows[before_event:].T  # the statistics recomputed from the states themselves
    assert lam.mean() == pytest.approx(stats["lambda_mean"], rel=1e-12)
    assert ahead.mean() == pytest.approx(stats["share_event_ahead"], rel=1e-12)
    # float64 both ways, summed in another order: the largest deviation measured 6.7e-16 (the means: equal)
    assert np.corrcoef(lam, cost_value)[0, 1] == pytest.approx(stats["corr_lambda_cost_value"], abs=1e-12)
    assert -1.0 <= stats["corr_lambda_cost_value"] <= 1.0


def test_multiplier_steps_are_capped_at_the_minibatches_of_an_iteration(tmp_path):
    with pytest.raises(ValueError, match="multiplier_steps"):
        small(multiplier_steps=0)
    hp = small(multiplier_steps=100)  # 2 epochs x 4 minibatches
    trainer = Trainer(ToyConstrainedEnv(hp.num_envs, seed=0), hp, tmp_path, progress=False)
    trainer.train(max_iterations=1)
    trainer.close()
    assert {int(state["step"]) for state in trainer.optimizers["multiplier"].state.values()} == {8}


def test_t_interval_over_seeds_matches_the_student_t_formula():
    low, high = t_interval([1.0, 2.0, 3.0])
    half = 4.302652729911275 * 1.0 / math.sqrt(3.0)  # t_{0.975, 2} * s / sqrt(n), s = 1
    assert math.isclose(low, 2.0 - half) and math.isclose(high, 2.0 + half)
    assert all(math.isnan(v) for v in t_interval([1.0]))


def _write_metrics(path: Path, cost_rate: float, episode_return: float) -> None:
    """100 iterations of 10000 env steps; the returns alternate +-1 around ``episode_return``."""
    path.parent.mkdir(parents=True)
    columns = "iteration,frames,wall_s,episodes,episode/return,episode/train_return,episode/cost_return," \
              "episode/si_cost_return,episode/steps,episode/vx,cost_rate,step/reward,env_steps_per_s"
    rows = [f"{i},{i * 10000},{i},10,{episode_return + (-1) ** i},1,0.1,-1,300,20,{cost_rate},0.5,1000"
            for i in range(1, 101)]
    path.write_text("\n".join([columns, *rows]) + "\n")


def test_training_summary_is_the_mean_over_seeds_with_t_intervals_and_the_claim_per_seed(tmp_path):
    # over the last 5% (5 iterations, 50000 steps): PPO 50 events per seed; PPO-L-SI 10, 45 and 20
    for seed, lsi_rate in enumerate([2e-4, 9e-4, 4e-4]):
        _write_metrics(tmp_path / "ppo" / f"seed_{seed}" / "metrics.csv", 1e-3, -100.0)
        _write_metrics(tmp_path / "ppo_lsi" / f"seed_{seed}" / "metrics.csv", lsi_rate, -90.0)
    subprocess.run([sys.executable, str(ROOT / "pipelines/training_figure.py"), "--training-dir", str(tmp_path),
                    "--figure-dir", str(tmp_path / "figures")], check=True, capture_output=True)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["ppo"]["seeds"] == [0, 1, 2]
    assert math.isclose(summary["ppo"]["cost_rate"], 1e-3) and math.isclose(summary["ppo_lsi"]["cost_rate"], 5e-4)
    low, high = summary["ppo_lsi"]["cost_rate_ci95"]
    assert low < 5e-4 < high
    claim = summary["paper_claim"]
    assert math.isclose(claim["cost_rate_ratio_lsi_over_ppo"], 0.5)
    per_seed = [claim["per_seed"][s] for s in ("0", "1", "2")]
    assert [s["events"] for s in per_seed] == [[10, 50], [45, 50], [20, 50]]
    # seed 0: ratio 0.2, CI below 0.5; seed 1: 0.9, CI above 0.5; seed 2: 0.4, CI across 0.5
    assert [s["verdict"] for s in per_seed] == ["holds", "fails", "not shown"]
    assert [s["holds"] for s in per_seed] == [True, False, False]
    assert all(s["return_difference_lsi_minus_ppo_ci95"][0] > 0 for s in per_seed)
    low, high = claim["cost_rate_ratio_lsi_over_ppo_ci95"]  # t over the seeds' log ratios: wide with 3 seeds
    assert low < 0.2 * 0.9 and high > 0.9
    assert claim["verdict"] == "not shown" and claim["holds"] is False
    assert (tmp_path / "figures" / "training.png").stat().st_size > 0


def test_designated_policy_is_a_copy_of_the_chosen_seed_with_its_hash(tmp_path):
    source = tmp_path / "ppo_lsi" / "seed_0" / "policy.pt"
    source.parent.mkdir(parents=True)
    source.write_bytes(b"policy bytes")
    subprocess.run([sys.executable, str(ROOT / "pipelines/designate_policy.py"), "--agent", "ppo_lsi", "--seed", "0",
                    "--training-dir", str(tmp_path)], check=True, capture_output=True)
    assert (tmp_path / "ppo_lsi" / "policy.pt").read_bytes() == b"policy bytes"
    designated = json.loads((tmp_path / "ppo_lsi" / "designated.json").read_text())
    assert designated["seed"] == 0 and designated["sha256"] == hashlib.sha256(b"policy bytes").hexdigest()
    missing = subprocess.run([sys.executable, str(ROOT / "pipelines/designate_policy.py"), "--agent", "ppo",
                              "--seed", "0", "--training-dir", str(tmp_path)], capture_output=True, text=True)
    assert missing.returncode != 0 and "seed_0/policy.pt" in missing.stderr and "Traceback" not in missing.stderr
