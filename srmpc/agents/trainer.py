"""Training loop of PPO / PPO-L-SI over a batched TorchRL env (CleanRL layout, TorchRL parts).

Per iteration:
  1. collect ``frames_per_batch`` steps from the B envs (T = frames / B steps per env; episodes
     continue across iterations, partial resets of the scenes that ended), with
     :class:`srmpc.agents.rollout.RolloutCollector`: TorchRL's ``Collector`` loop, same floats,
     without its per-step TensorDicts;
  2. episode bookkeeping: per-env running sums of r', event cost, SI cost, steps, vx; finished
     episodes give the logged episode metrics;
  3. two GAEs (reward and, if constrained, cost) under no_grad;
  4. ``epochs`` passes of shuffled minibatches (the loss's tensors gathered once per minibatch,
     no TensorDict): actor + critics step on every minibatch; lambda(s)
     steps on the first ``multiplier_steps`` minibatches of every ``multiplier_update_every``-th
     iteration (slow timescale), its learning rate decaying linearly if ``multiplier_lr_final`` is set;
  5. NaN/Inf check of every loss term and parameter; metrics to MLflow; checkpoint every K iterations.

``Trainer.profile`` holds the last iteration's wall time per section (:data:`PROFILE_SECTIONS`).

The env must provide "observation" (B, obs_dim), a Bounded "action" spec, and in "next": "reward",
"cost", "reward_prime", "event_cost", "vx", "done", "terminated", "truncated" (all (B, 1)).
"""

from __future__ import annotations

import copy
import csv
import json
import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.envs import EnvBase

from srmpc.agents.checkpoint import POLICY_NAME, load_checkpoint, save_checkpoint, save_policy
from srmpc.agents.hyperparameters import PPOHyperparameters
from srmpc.agents.networks import COST_VALUE_KEY, VALUE_KEY, make_actor, make_multiplier, make_value
from srmpc.agents.ppo_lsi_loss import ROW_BLOCK, PPOLSILoss
from srmpc.agents.rollout import RolloutCollector

METRICS_CSV = "metrics.csv"
MULTIPLIER_JSON = "multiplier.json"
MULTIPLIER_SAMPLES_CSV = "multiplier_samples.csv"


def write_json(path: Path, data: dict) -> None:
    """Write ``data`` as indented JSON via a temporary file and rename."""
    temporary = path.with_name(path.name + ".tmp")
    finite = {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in data.items()}
    temporary.write_text(json.dumps(finite, indent=2) + "\n")
    os.replace(temporary, path)


CSV_COLUMNS = ("iteration", "frames", "wall_s", "episodes", "episode/return", "episode/train_return",
               "episode/cost_return", "episode/si_cost_return", "episode/steps", "episode/vx", "cost_rate",
               "step/reward", "env_steps_per_s", "train/lambda_mean", "train/lambda_share_at_max",
               "train/violation_share", "train/lambda_cost_value_corr")
"""The columns of ``metrics.csv``, one row per iteration (``srmpc.agents.report`` reads them)."""


def truncate_metrics_csv(path: Path, last_iteration: int) -> None:
    """Keep the rows up to ``last_iteration`` (a crash may have left later ones), replacing the file
    atomically (temporary file + rename), so a crash here never leaves it empty."""
    rows = []
    if path.exists():
        with path.open(newline="") as handle:
            rows = [r for r in csv.DictReader(handle) if r.get("iteration") and
                    float(r["iteration"]) <= last_iteration]
    temporary = path.with_name(path.name + ".tmp")
    with temporary.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    os.replace(temporary, path)


def append_metrics_row(path: Path, metrics: dict[str, float]) -> None:
    """One iteration's row of ``metrics.csv`` (columns it lacks stay empty)."""
    with path.open("a", newline="") as handle:
        csv.DictWriter(handle, fieldnames=CSV_COLUMNS).writerow({k: metrics.get(k, "") for k in CSV_COLUMNS})


PROFILE_SECTIONS = ("collect", "episodes", "advantage", "data", "forward", "backward", "optimizer", "multiplier",
                    "diagnostics")
"""Sections of an iteration in ``Trainer.profile`` [s]: collection; episode bookkeeping; the GAEs
(critics on s_t and s_{t+1}, recursion); data movement (the loss's tensors flattened, one gather
per minibatch); the loss's forward pass (every network and term); backward; the gradient clips
and the actor's and critics' Adam steps; lambda(s) outside the forward pass (its clip and Adam
step, and z(s) of the whole batch once it is fixed for the iteration); the NaN checks and the
loss terms' read-out."""


class NonFiniteError(RuntimeError):
    """A loss term or a parameter became NaN/Inf; the last good checkpoint is kept untouched."""


def build_loss(observation_dim: int, action_low: torch.Tensor, action_high: torch.Tensor,
               hp: PPOHyperparameters) -> PPOLSILoss:
    """Actor, critics, multiplier and the loss module that owns them."""
    actor = make_actor(observation_dim, action_low, action_high, hp.hidden_sizes, hp.initial_std)
    critic = make_value(observation_dim, hp.hidden_sizes, VALUE_KEY)
    cost_critic = multiplier = None
    if hp.constrained:
        cost_critic = make_value(observation_dim, hp.hidden_sizes, COST_VALUE_KEY)
        multiplier = make_multiplier(observation_dim, hp.hidden_sizes, hp.lambda_max, hp.initial_lambda)
    return PPOLSILoss(
        actor, critic, cost_critic, multiplier, constrained=hp.constrained, clip_epsilon=hp.clip_epsilon,
        entropy_coeff=hp.entropy_coef, gamma=hp.gamma, gae_lambda=hp.gae_lambda, cost_gamma=hp.cost_gamma,
        cost_threshold=hp.cost_threshold, violation_clip=(hp.violation_clip_low, hp.violation_clip_high),
        lambda_max=hp.lambda_max, multiplier_loss_on_logit=hp.multiplier_loss_on_logit,
        violation_normalization=hp.violation_normalization,
    )


def parameter_groups(loss: PPOLSILoss) -> dict[str, list[torch.nn.Parameter]]:
    """Parameters per optimizer: actor, critics (v and v_c), multiplier."""
    groups = {
        "actor": list(loss.actor_network_params.values(True, True)),
        "critic": list(loss.critic_network_params.values(True, True)),
        "multiplier": [],
    }
    if loss.constrained:
        groups["critic"] += list(loss.cost_critic_network.parameters())
        groups["multiplier"] = list(loss.multiplier_network.parameters())
    return groups


@dataclass
class EpisodeTracker:
    """Per-env running sums over the current episode; finished episodes are appended to ``finished``."""

    num_envs: int
    sums: dict[str, torch.Tensor] = field(default_factory=dict)
    finished: list[dict[str, float]] = field(default_factory=list)
    total_event_cost: float = 0.0
    total_steps: int = 0

    KEYS = ("return", "train_return", "cost_return", "si_cost_return", "steps", "vx_sum")
    """return: sum of r' (the paper's J_r); train_return: sum of the training reward r; cost_return: sum
    of event costs (the paper's J_c); si_cost_return: sum of the SI cost c; steps; vx_sum -> mean vx."""

    def __post_init__(self) -> None:
        self._stacked = torch.zeros(len(self.KEYS), self.num_envs, dtype=torch.float64)
        for row, k in zip(self._stacked, self.KEYS, strict=True):
            if k in self.sums:
                row.copy_(self.sums[k])
        self.sums = dict(zip(self.KEYS, self._stacked, strict=True))  # views of the rows of _stacked

    def update(self, batch: TensorDictBase) -> list[dict[str, float]]:
        """Consume a (B, T) batch; return the episodes that ended in it (ordered by step, then env).

        All KEYS advance together as the rows of one (6, B) float64 tensor, step by step, so every
        sum adds the same float64 values in the same order as one per key would.
        """
        nxt = batch.get("next")
        reward_prime = nxt.get("reward_prime").reshape(self.num_envs, -1)
        columns = torch.stack([
            reward_prime, nxt.get("reward").reshape(self.num_envs, -1),
            nxt.get("event_cost").reshape(self.num_envs, -1),
            nxt.get("cost").reshape(self.num_envs, -1), torch.ones_like(reward_prime),
            nxt.get("vx").reshape(self.num_envs, -1),
        ]).double()  # (6, B, T) in KEYS order
        done = nxt.get("done").reshape(self.num_envs, -1)
        self.total_event_cost += float(columns[self.KEYS.index("cost_return")].sum())
        self.total_steps += done.numel()
        ended: list[dict[str, float]] = []
        for t in range(done.shape[1]):
            self._stacked += columns[:, :, t]
            finished = done[:, t].nonzero().flatten()
            if finished.numel():
                for values in self._stacked[:, finished].T.tolist():
                    episode = dict(zip(self.KEYS, values, strict=True))
                    episode["vx"] = episode.pop("vx_sum") / max(episode["steps"], 1.0)
                    ended.append(episode)
                self._stacked[:, finished] = 0.0
        self.finished.extend(ended)
        return ended

    def state(self) -> dict[str, Any]:
        return {"sums": {k: v.clone() for k, v in self.sums.items()}, "total_event_cost": self.total_event_cost,
                "total_steps": self.total_steps}

    def load(self, state: dict[str, Any]) -> None:
        for k in self.KEYS:
            self.sums[k].copy_(state["sums"][k])
        self.total_event_cost = state["total_event_cost"]
        self.total_steps = state["total_steps"]

    def clear(self) -> None:
        """Zero the running sums (episodes restart)."""
        self._stacked.zero_()


def env_runtime_state(env: EnvBase) -> Any:
    """The env's full simulation state, or None when it cannot give one.

    Envs may implement ``runtime_state()`` / ``load_runtime_state(state)``; for
    ``srmpc.sim.torchrl_env.TwinHighwayEnv`` the simulator's public ``snapshot()`` (every scene and
    its random stream) plus the env's per-scene done flags are used.
    """
    if hasattr(env, "runtime_state"):
        return env.runtime_state()
    simulator = getattr(env, "simulator", None)
    if simulator is not None and hasattr(simulator, "snapshot"):
        done = getattr(env, "_done", None)
        return {"simulator": simulator.snapshot(), "done": None if done is None else done.copy()}
    return None


def load_env_runtime_state(env: EnvBase, state: Any) -> bool:
    """Put a state from :func:`env_runtime_state` back; False when the env cannot take it."""
    if state is None:
        return False
    if hasattr(env, "load_runtime_state"):
        env.load_runtime_state(state)
        return True
    simulator = getattr(env, "simulator", None)
    if simulator is not None and hasattr(simulator, "restore") and "simulator" in state:
        simulator.restore(state["simulator"])
        if state["done"] is not None:
            env._done[...] = state["done"]
        return True
    return False


class Trainer:
    """PPO / PPO-L-SI trainer. ``run`` is an :class:`srmpc.tracking.Run` (or anything with
    ``log_metrics(dict, step)``); ``output_dir`` receives ``last.pt``, ``policy.pt`` and ``metrics.csv``.
    A ``last.pt`` already in ``output_dir`` is resumed from."""

    def __init__(self, env: EnvBase, hp: PPOHyperparameters, output_dir: Path, run: Any = None,
                 progress: bool = True) -> None:
        if env.batch_size != torch.Size([hp.num_envs]):
            raise ValueError(f"env batch_size {tuple(env.batch_size)} != num_envs={hp.num_envs}")
        torch.set_num_threads(hp.num_threads)
        torch.manual_seed(hp.seed)
        self.env, self.hp, self.output_dir, self.run, self.progress = env, hp, Path(output_dir), run, progress
        self.output_dir.mkdir(parents=True, exist_ok=True)
        env.set_seed(hp.seed)
        action_spec = env.full_action_spec["action"]
        self.observation_dim = env.full_observation_spec["observation"].shape[-1]
        self.action_low = action_spec.space.low.reshape(-1, action_spec.shape[-1])[0].clone()
        self.action_high = action_spec.space.high.reshape(-1, action_spec.shape[-1])[0].clone()
        self.loss = build_loss(self.observation_dim, self.action_low, self.action_high, hp)
        groups = parameter_groups(self.loss)
        self.optimizers = {
            "actor": torch.optim.Adam(groups["actor"], lr=hp.actor_lr, eps=1e-5, foreach=True),
            "critic": torch.optim.Adam(groups["critic"], lr=hp.critic_lr, eps=1e-5, foreach=True),
        }
        if hp.constrained:
            self.optimizers["multiplier"] = torch.optim.Adam(groups["multiplier"], lr=hp.multiplier_lr, eps=1e-5,
                                                             foreach=True)
        self.groups = groups
        self.shuffle = torch.Generator().manual_seed(hp.seed)
        self.episodes = EpisodeTracker(hp.num_envs)
        self.iteration = 0
        self.frames = 0
        self.wall_s = 0.0
        self.collector = RolloutCollector(env, self.loss.actor_network, hp.frames_per_batch)
        self.profile: dict[str, float] = dict.fromkeys(PROFILE_SECTIONS, 0.0)
        self.resumed_from: int | None = None
        checkpoint = load_checkpoint(self.output_dir)
        if checkpoint is not None:
            self.load_state(checkpoint)
            self.resumed_from = self.iteration
        else:
            torch.manual_seed(hp.seed)  # as before the collector's construction (TorchRL's could draw numbers)
        self._snapshot = self.state()

    # ----------------------------------------------------------------------------------------- state
    def state(self) -> dict[str, Any]:
        """Everything a resume needs (see srmpc.agents.checkpoint)."""
        env_state = env_runtime_state(self.env)
        return copy.deepcopy({
            "iteration": self.iteration, "frames": self.frames, "wall_s": self.wall_s,
            "loss": self.loss.state_dict(),
            "optimizers": {k: o.state_dict() for k, o in self.optimizers.items()},
            "torch_rng": torch.get_rng_state(), "shuffle_rng": self.shuffle.get_state(),
            "carrier": self.collector.state(),  # the current observations
            "env": env_state, "episodes": self.episodes.state(),
            "hyperparameters": asdict(self.hp),
        })

    def load_state(self, state: dict[str, Any]) -> None:
        self.iteration, self.frames, self.wall_s = state["iteration"], state["frames"], state["wall_s"]
        self.loss.load_state_dict(state["loss"])
        for k, optimizer in self.optimizers.items():
            optimizer.load_state_dict(state["optimizers"][k])
        torch.set_rng_state(state["torch_rng"])
        self.shuffle.set_state(state["shuffle_rng"])
        if load_env_runtime_state(self.env, state["env"]):
            self.collector.load_state(state["carrier"])
            self.episodes.load(state["episodes"])
        else:  # the env cannot restore its state: episodes restart from fresh resets
            self.episodes.load(state["episodes"])
            self.episodes.clear()

    def save(self, state: dict[str, Any] | None = None) -> Path:
        state = self._snapshot if state is None else state
        path = save_checkpoint(state, self.output_dir)
        prefix = "actor_network_params."
        actor_state = {k[len(prefix):]: v for k, v in state["loss"].items() if k.startswith(prefix)}
        save_policy(actor_state, {"observation_dim": self.observation_dim, "action_low": self.action_low,
                                  "action_high": self.action_high, "hidden_sizes": list(self.hp.hidden_sizes),
                                  "iteration": state["iteration"], "frames": state["frames"],
                                  "name": self.hp.name}, self.output_dir / POLICY_NAME)
        return path

    # ----------------------------------------------------------------------------------------- update
    def _check_finite(self, named: dict[str, torch.Tensor], what: str) -> None:
        for name, value in named.items():
            if not torch.isfinite(value).all():
                raise NonFiniteError(
                    f"{what} '{name}' is NaN/Inf at iteration {self.iteration + 1}; training stopped. "
                    f"The last good checkpoint ({self.output_dir / 'last.pt'}, iteration "
                    f"{self._snapshot['iteration']}) is kept."
                )

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        """Advantages, then ``epochs`` passes of minibatch SGD; returns minibatch-averaged loss terms.

        Each minibatch gathers only the loss's own tensors (``PPOLSILoss.training_keys``) with one
        ``index_select`` each and calls ``PPOLSILoss.loss_terms`` on them; lambda(s) builds its
        graph only on the minibatches where it takes a step.
        """
        hp, profile, clock = self.hp, self.profile, time.perf_counter
        started = clock()
        self.loss.compute_advantages(batch)
        lap = clock()
        profile["advantage"] = lap - started
        for k in ("data", "forward", "backward", "optimizer", "multiplier", "diagnostics"):
            profile[k] = 0.0
        samples = batch.numel()
        data = [batch.get(key).reshape(samples, *batch.get(key).shape[batch.ndim:]) for key in self.loss.training_keys]
        profile["data"] += clock() - lap
        update_multiplier = hp.constrained and (self.iteration + 1) % hp.multiplier_update_every == 0
        if update_multiplier and hp.multiplier_lr_final is not None:
            progress = self.iteration / max(hp.iterations - 1, 1)
            for group in self.optimizers["multiplier"].param_groups:
                group["lr"] = hp.multiplier_lr + progress * (hp.multiplier_lr_final - hp.multiplier_lr)
        # After lambda(s)'s last step of the iteration z(s) is fixed: computed once for the whole
        # batch, then gathered per minibatch (same floats when minibatches are whole row blocks)
        share_logits = hp.constrained and hp.minibatch_size % ROW_BLOCK == 0
        logits: torch.Tensor | None = None
        names: list[str] = []
        totals: list[float] = []
        count = 0
        for _ in range(hp.epochs):
            order = torch.randperm(samples, generator=self.shuffle)
            for start in range(0, samples, hp.minibatch_size):
                lap = clock()
                index = order[start:start + hp.minibatch_size]
                minibatch = [tensor.index_select(0, index) for tensor in data]
                step_multiplier = update_multiplier and count < hp.multiplier_steps
                now = clock()
                profile["data"] += now - lap
                if share_logits and not step_multiplier and logits is None:
                    logits = self.loss.multiplier_logits(data[0])
                    lap, now = now, clock()
                    profile["multiplier"] += now - lap
                logit = None if logits is None else logits.index_select(0, index)
                terms = self.loss.loss_terms(*minibatch, multiplier_grad=step_multiplier, multiplier_logit=logit)
                losses = {k: v for k, v in terms.items() if k.startswith("loss_")}
                total = sum(losses.values())
                lap, now = now, clock()
                profile["forward"] += now - lap
                self._check_finite_all(losses, "loss term")
                lap, now = now, clock()
                profile["diagnostics"] += now - lap
                for optimizer in self.optimizers.values():
                    optimizer.zero_grad(set_to_none=True)
                total.backward()
                lap, now = now, clock()
                profile["backward"] += now - lap
                torch.nn.utils.clip_grad_norm_(self.groups["actor"], hp.max_grad_norm)
                torch.nn.utils.clip_grad_norm_(self.groups["critic"], hp.max_grad_norm)
                self.optimizers["actor"].step()
                self.optimizers["critic"].step()
                lap, now = now, clock()
                profile["optimizer"] += now - lap
                if step_multiplier:
                    if hp.multiplier_max_grad_norm is not None:
                        torch.nn.utils.clip_grad_norm_(self.groups["multiplier"], hp.multiplier_max_grad_norm)
                    self.optimizers["multiplier"].step()
                lap, now = now, clock()
                profile["multiplier"] += now - lap
                values = torch.stack([v.detach() for v in terms.values()]).tolist()
                if not names:
                    names, totals = list(terms), [0.0] * len(terms)
                totals = [a + b for a, b in zip(totals, values, strict=True)]
                profile["diagnostics"] += clock() - now
                count += 1
        lap = clock()
        self._check_finite({k: v for k, v in self.loss.named_parameters()}, "parameter")
        profile["diagnostics"] += clock() - lap
        return {k: v / count for k, v in zip(names, totals, strict=True)}

    def _check_finite_all(self, named: dict[str, torch.Tensor], what: str) -> None:
        """:meth:`_check_finite` with one op when everything is finite (the usual case)."""
        if not bool(torch.isfinite(torch.stack(list(named.values()))).all()):
            self._check_finite(named, what)

    # ----------------------------------------------------------------------------------------- loop
    def train(self, max_iterations: int | None = None, on_iteration: Callable[[dict], None] | None = None) -> dict:
        """Train until ``hp.iterations`` (or ``max_iterations`` more iterations); return the last metrics."""
        hp = self.hp
        stop = hp.iterations if max_iterations is None else min(hp.iterations, self.iteration + max_iterations)
        csv_path = self.output_dir / METRICS_CSV
        self._truncate_csv(csv_path)
        bar = None
        if self.progress:
            from tqdm import tqdm

            bar = tqdm(total=hp.iterations * hp.frames_per_batch, initial=self.frames, unit="step",
                       desc=f"train {hp.name}", unit_scale=True)
        metrics: dict[str, float] = {}
        batch = None
        try:
            while self.iteration < stop:
                started = time.perf_counter()
                batch = self.collector.collect()
                collect_s = time.perf_counter() - started
                ended = self.episodes.update(batch)
                self.profile["collect"] = collect_s
                self.profile["episodes"] = time.perf_counter() - started - collect_s
                losses = self.update(batch)
                self.iteration += 1
                self.frames += batch.numel()
                elapsed = time.perf_counter() - started
                self.wall_s += elapsed
                metrics = self._metrics(batch, ended, losses, collect_s, elapsed)
                self._snapshot = self.state()
                self._append_csv(csv_path, metrics)
                if self.run is not None:
                    self.run.log_metrics(metrics, step=self.frames)
                if self.iteration % hp.checkpoint_every == 0 or self.iteration == stop:
                    self.save()
                if on_iteration is not None:
                    on_iteration(metrics)
                if bar is not None:
                    bar.update(batch.numel())
                    bar.set_postfix(ret=f"{metrics.get('episode/return', math.nan):.1f}",
                                    cost_rate=f"{metrics['cost_rate']:.4f}")
        except (KeyboardInterrupt, SystemExit):
            self.save()  # the last completed iteration; the run is then marked FAILED by the caller
            raise
        finally:
            if bar is not None:
                bar.close()
        if hp.constrained and batch is not None and self.iteration == hp.iterations:
            self.write_multiplier_diagnostic(batch)
        return metrics

    def write_multiplier_diagnostic(self, batch: TensorDictBase) -> None:
        """``multiplier.json`` and ``multiplier_samples.csv`` from the last batch (see multiplier_diagnostic)."""
        from srmpc.agents.multiplier_diagnostic import multiplier_diagnostic

        steps = batch.shape[1]
        stats, samples = multiplier_diagnostic(self.loss, batch, horizon_steps=min(10, steps), seed=self.hp.seed)
        write_json(self.output_dir / MULTIPLIER_JSON, stats)
        temporary = self.output_dir / (MULTIPLIER_SAMPLES_CSV + ".tmp")
        with temporary.open("w", newline="") as handle:
            writer = csv.writer(handle)
            writer.writerow(list(samples))
            writer.writerows(zip(*samples.values(), strict=True))
        os.replace(temporary, self.output_dir / MULTIPLIER_SAMPLES_CSV)

    def close(self) -> None:
        """Nothing to release (kept for callers of TorchRL's collector API)."""

    def _metrics(self, batch: TensorDictBase, ended: list[dict], losses: dict[str, float], collect_s: float,
                 elapsed_s: float) -> dict[str, float]:
        nxt = batch.get("next")
        metrics = {
            "iteration": float(self.iteration), "frames": float(self.frames), "wall_s": self.wall_s,
            "env_steps_per_s": batch.numel() / elapsed_s, "collect_s": collect_s,
            "cost_rate": float(nxt.get("event_cost").sum()) / batch.numel(),
            "cost_rate_cumulative": self.episodes.total_event_cost / max(self.episodes.total_steps, 1),
            "step/reward": float(nxt.get("reward").mean()), "step/si_cost": float(nxt.get("cost").mean()),
            "step/vx": float(nxt.get("vx").mean()), "episodes": float(len(ended)),
        }
        if ended:
            for key in ("return", "train_return", "cost_return", "si_cost_return", "steps", "vx"):
                metrics[f"episode/{key}"] = sum(e[key] for e in ended) / len(ended)
        metrics.update({f"train/{k}": v for k, v in losses.items()})
        return metrics

    CSV_COLUMNS = CSV_COLUMNS

    def _truncate_csv(self, path: Path) -> None:
        """Keep the rows up to the resumed iteration (see :func:`truncate_metrics_csv`)."""
        truncate_metrics_csv(path, self.iteration)

    def _append_csv(self, path: Path, metrics: dict[str, float]) -> None:
        append_metrics_row(path, metrics)
