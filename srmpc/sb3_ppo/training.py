"""Stable-Baselines3's PPO on the twin, with our agent's hyperparameters: the peer of ``srmpc.agents``' PPO.

:func:`make_ppo` maps :class:`~srmpc.agents.hyperparameters.PPOHyperparameters` onto SB3 wherever SB3 has
the same knob:

=========================  ====================================  ==========================================
ours                       SB3                                   value (``conf/agent/ppo.yaml``)
=========================  ====================================  ==========================================
num_envs, frames_per_batch n_envs, n_steps = frames / num_envs   1024 envs x 32 steps = 32,768 per iteration
minibatch_size, epochs     batch_size, n_epochs                  8192, 4
gamma, gae_lambda          gamma, gae_lambda                     0.99, 0.95
clip_epsilon               clip_range                            0.2
entropy_coef               ent_coef                              0
actor_lr                   learning_rate (one optimizer)         3e-4
max_grad_norm              max_grad_norm                         0.5
hidden_sizes               net_arch pi / vf, tanh                2x64 each, separate networks
initial_std                log_std_init = ln(initial_std)        0.5 (in [-1, 1] action units)
seed                       seed (torch, numpy, env)              0, 1, 2
=========================  ====================================  ==========================================

What remains different (SB3's own defaults, kept as SB3 ships them):

- actions: an unsquashed Gaussian, clipped to [-1, 1] before the env, and the log-probability of the
  unclipped sample (ours: tanh-squashed Gaussian with the change-of-variables term); the deterministic
  action is the clipped mean (ours: the squashed mean);
- one Adam optimizer (lr 3e-4, eps 1e-5) over actor and critic, loss = policy + 0.5 value loss
  (``vf_coef``), one gradient-norm clip over both (ours: two optimizers, critic lr 1e-3, a clip each);
- value loss: MSE against the GAE returns, no value clipping (``clip_range_vf=None``), as ours;
- advantages normalized per minibatch, as ours;
- observations as the twin gives them (no ``VecNormalize``), as ours;
- initialisation: orthogonal, gains sqrt(2) hidden, 0.01 policy head, 1 value head, as ours;
- truncation: SB3 adds gamma V(terminal observation) to the truncated step's reward; ours (TorchRL's GAE)
  bootstraps from V of the same observation;
- minibatch shuffling from numpy's global generator (ours: a torch generator).

:class:`TrainingLog` writes ``metrics.csv`` with the columns of ``srmpc.agents.trainer.Trainer`` (r', J_c,
rho_c per iteration, in the paper's units), so ``srmpc.agents.report`` summarizes both PPOs alike, and
checkpoints every ``checkpoint_every`` iterations into ``last.zip`` + ``last_state.pt``, from which a rerun
resumes (the model, its optimizer, the simulator's scenes and streams, the torch and numpy RNG states).
"""

from __future__ import annotations

import math
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from srmpc.agents.checkpoint import POLICY_NAME, atomic_torch_save
from srmpc.agents.hyperparameters import PPOHyperparameters
from srmpc.agents.trainer import METRICS_CSV, append_metrics_row, truncate_metrics_csv
from srmpc.sb3_ppo.vec_env import TwinSb3VecEnv
from srmpc.scenario.parameters import ScenarioParameters

MODEL_NAME = "last.zip"
STATE_NAME = "last_state.pt"
IMPLEMENTATION = f"stable-baselines3=={stable_baselines3.__version__}"
CLIPPED_MEAN = "clipped_gaussian_mean"
"""``policy.pt``'s ``action_head``: the deterministic action is the mean, clipped to the box."""


def make_ppo(env: TwinSb3VecEnv, hp: PPOHyperparameters) -> PPO:
    """SB3's PPO over ``env`` with ``hp``'s settings (module table)."""
    if hp.constrained:
        raise ValueError(f"agent.constrained={hp.constrained}: Stable-Baselines3's PPO has no constraint (agent=ppo)")
    policy_kwargs = {
        "net_arch": {"pi": list(hp.hidden_sizes), "vf": list(hp.hidden_sizes)},
        "activation_fn": torch.nn.Tanh,
        "log_std_init": math.log(hp.initial_std),
        "ortho_init": True,
    }
    return PPO(
        "MlpPolicy", env, learning_rate=hp.actor_lr, n_steps=hp.frames_per_batch // hp.num_envs,
        batch_size=hp.minibatch_size, n_epochs=hp.epochs, gamma=hp.gamma, gae_lambda=hp.gae_lambda,
        clip_range=hp.clip_epsilon, clip_range_vf=None, normalize_advantage=True, ent_coef=hp.entropy_coef,
        max_grad_norm=hp.max_grad_norm, policy_kwargs=policy_kwargs, seed=hp.seed, device="cpu", verbose=0,
    )


def policy_layers(model: PPO, env: TwinSb3VecEnv) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The actor's mean network with the [-1, 1] -> box map folded into its last layer (float64)."""
    linears = [m for m in model.policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
    linears.append(model.policy.action_net)
    weights = [m.weight.detach().double().numpy().copy() for m in linears]
    biases = [m.bias.detach().double().numpy().copy() for m in linears]
    weights[-1] = env.action_half_range[:, None] * weights[-1]
    biases[-1] = env.action_half_range * biases[-1] + env.action_center
    return weights, biases


def save_policy(model: PPO, env: TwinSb3VecEnv, hp: PPOHyperparameters, path: Path) -> None:
    """``policy.pt`` for the evaluation (``srmpc.controllers.policy``): the clipped mean as an MLP."""
    weights, biases = policy_layers(model, env)
    box = env.twin.single_action_space
    atomic_torch_save({
        "action_head": CLIPPED_MEAN, "weights": [torch.from_numpy(w) for w in weights],
        "biases": [torch.from_numpy(b) for b in biases], "observation_dim": int(weights[0].shape[1]),
        "action_low": torch.tensor(box.low, dtype=torch.float64),
        "action_high": torch.tensor(box.high, dtype=torch.float64), "hidden_sizes": list(hp.hidden_sizes),
        "frames": int(model.num_timesteps), "iteration": int(model.num_timesteps // hp.frames_per_batch),
        "name": hp.name, "implementation": IMPLEMENTATION,
    }, path)


class TrainingLog(BaseCallback):
    """One ``metrics.csv`` row per iteration (after its collection), checkpoints, MLflow metrics."""

    def __init__(self, env: TwinSb3VecEnv, hp: PPOHyperparameters, output_dir: Path, run: Any,
                 wall_s: float = 0.0) -> None:
        super().__init__()
        self.env, self.hp, self.output_dir, self.run = env, hp, output_dir, run
        self.wall_s = wall_s
        self._clock = time.perf_counter()
        self._collect_started = self._clock
        self.last_totals = (0.0, 0.0)
        """The env's total event cost and training reward at the last row (per-iteration differences)."""

    def _tick(self) -> float:
        now = time.perf_counter()
        self.wall_s += now - self._clock
        self._clock = now
        return now

    def _on_rollout_start(self) -> None:
        iteration = self.model.num_timesteps // self.hp.frames_per_batch
        if iteration > 0 and iteration % self.hp.checkpoint_every == 0:
            self.save_checkpoint()
        self._collect_started = time.perf_counter()

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        previous_wall = self.wall_s
        self._tick()
        frames = self.model.num_timesteps
        ended, self.env.finished = self.env.finished, []
        batch_cost = self.env.total_event_cost - self.last_totals[0]
        batch_reward = self.env.total_reward - self.last_totals[1]
        self.last_totals = (self.env.total_event_cost, self.env.total_reward)
        metrics = {
            "iteration": float(frames // self.hp.frames_per_batch), "frames": float(frames), "wall_s": self.wall_s,
            "episodes": float(len(ended)), "cost_rate": batch_cost / self.hp.frames_per_batch,
            "step/reward": batch_reward / self.hp.frames_per_batch,
            "env_steps_per_s": self.hp.frames_per_batch / max(self.wall_s - previous_wall, 1e-9),
            "collect_s": time.perf_counter() - self._collect_started,
        }
        for key in ("return", "train_return", "cost_return", "si_cost_return", "steps", "vx"):
            if ended:
                metrics[f"episode/{key}"] = sum(e[key] for e in ended) / len(ended)
        append_metrics_row(self.output_dir / METRICS_CSV, metrics)
        if self.run is not None:
            self.run.log_metrics(metrics, step=frames)

    def save_checkpoint(self) -> None:
        """``last.zip`` (model and optimizer) and ``last_state.pt`` (everything else a resume needs)."""
        self._tick()
        temporary = self.output_dir / (MODEL_NAME + ".tmp.zip")
        self.model.save(temporary)
        state = {
            "frames": int(self.model.num_timesteps), "wall_s": self.wall_s, "env": self.env.runtime_state(),
            "last_obs": np.array(self.model._last_obs),
            "last_episode_starts": np.array(self.model._last_episode_starts), "last_totals": self.last_totals,
            # SB3 shuffles minibatches with numpy's global generator: its state is part of the run's
            "torch_rng": torch.get_rng_state(), "numpy_rng": np.random.get_state(),  # noqa: NPY002
        }
        atomic_torch_save(state, self.output_dir / (STATE_NAME + ".next"))
        os.replace(temporary, self.output_dir / MODEL_NAME)  # the pair changes together: state last
        os.replace(self.output_dir / (STATE_NAME + ".next"), self.output_dir / STATE_NAME)


def train_sb3_ppo(scenario: ScenarioParameters, hp: PPOHyperparameters, output_dir: Path, run: Any = None) -> Path:
    """Train (or resume from ``last.zip``) into ``output_dir``; returns the metrics.csv path."""
    torch.set_num_threads(hp.num_threads)
    output_dir.mkdir(parents=True, exist_ok=True)
    env = TwinSb3VecEnv(scenario, hp.num_envs, seed=hp.seed)
    total = hp.iterations * hp.frames_per_batch
    model_path, state_path = output_dir / MODEL_NAME, output_dir / STATE_NAME
    if model_path.exists() and state_path.exists():
        state = torch.load(state_path, weights_only=False)
        model = PPO.load(model_path, env=env, device="cpu")
        env.load_runtime_state(state["env"])
        model._last_obs = state["last_obs"]
        model._last_episode_starts = state["last_episode_starts"]
        torch.set_rng_state(state["torch_rng"])
        np.random.set_state(state["numpy_rng"])  # noqa: NPY002 (SB3's minibatch shuffling draws from it)
        log = TrainingLog(env, hp, output_dir, run, wall_s=state["wall_s"])
        log.last_totals = state["last_totals"]
        truncate_metrics_csv(output_dir / METRICS_CSV, state["frames"] // hp.frames_per_batch)
        remaining, reset = total - state["frames"], False
    else:
        model = make_ppo(env, hp)
        log = TrainingLog(env, hp, output_dir, run)
        truncate_metrics_csv(output_dir / METRICS_CSV, -1)
        remaining, reset = total, True
    if remaining > 0:
        model.learn(total_timesteps=remaining, callback=log, reset_num_timesteps=reset)
        log.save_checkpoint()
    save_policy(model, env, hp, output_dir / POLICY_NAME)
    env.close()
    return output_dir / METRICS_CSV
