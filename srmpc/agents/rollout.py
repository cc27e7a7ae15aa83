"""Collection of the (B, T) training batch: TorchRL's ``Collector`` loop without what we do not use.

Per step t (T = frames_per_batch / B), exactly as ``torchrl.collectors.Collector`` with
``ExplorationType.RANDOM`` under ``no_grad``:

  1. the actor's random pass on the current observations s_t (B, obs_dim):
     (loc, scale) = head(s_t), a_t ~ TanhNormal(loc, scale) by ``rsample``, log pi(a_t | s_t)
     (:func:`sample_actions`: the arithmetic of ``ProbabilisticActor``'s calls, without the
     distribution objects, so the same draws from torch's generator and the same floats);
  2. one env step, and a partial reset of the scenes that ended (``step_and_maybe_reset``): the
     "next" entries of step t are the step's own, the observation s_{t+1} is the new episode's
     where a scene ended.

What the Collector does and training does not need is dropped: TensorDicts built per step, the
trajectory ids, the stored ``loc`` / ``scale`` and root copies of the info keys, and the final
``torch.stack`` of T TensorDicts. The batch is written in place into tensors allocated once per
iteration. An env with ``step_and_reset_into`` (:class:`srmpc.sim.torchrl_env.TwinHighwayEnv`)
writes its outputs straight into those tensors; any other ``EnvBase`` goes through its public
``step_and_maybe_reset``.

Batch keys (all (B, T, ...)): "observation", "action", "action_log_prob" (B, T), and in "next":
"observation", "reward", "done", "terminated", "truncated" and the env's other observation keys
("cost", "reward_prime", "event_cost", "vx").
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import ProbabilisticActor
from torchrl.modules.distributions.utils import sample_and_log_prob

from srmpc.agents import tanh_normal
from srmpc.agents.networks import ACTION_KEY, LOG_PROB_KEY, OBSERVATION_KEY


def sample_actions(actor: ProbabilisticActor, observation: torch.Tensor,
                   box: tuple[torch.Tensor, torch.Tensor] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """(a, log pi(a|s)) of ``actor``'s random pass on ``observation``, without TensorDicts.

    ``ProbabilisticActor.forward`` (its ``SafeProbabilisticModule``) under ``ExplorationType.RANDOM``
    does exactly these calls: ``head(s) -> (loc, scale)``,
    ``dist = distribution_class(loc=loc, scale=scale, **distribution_kwargs)`` and TorchRL's
    ``sample_and_log_prob(dist, (), reparameterize=True)`` (``TanhNormal.rsample_and_log_prob``:
    the log-probability of the draw's own pre-image). Call it under ``torch.no_grad()``.
    With ``box`` = :func:`srmpc.agents.tanh_normal.actor_box` (``TanhNormal`` actors), the
    distribution's arithmetic runs without its objects (:mod:`srmpc.agents.tanh_normal`).
    """
    head, probabilistic = actor.module[0], actor.module[-1]
    loc, scale = head.module(observation)
    if box is not None:
        return tanh_normal.rsample_and_log_prob(loc, scale, *box)
    dist = probabilistic.distribution_class(loc=loc, scale=scale, **probabilistic.distribution_kwargs)
    return sample_and_log_prob(dist, torch.Size(()), reparameterize=dist.has_rsample)


class RolloutCollector:
    """Collects ``frames_per_batch`` steps of ``env`` with ``actor`` per :meth:`collect` call.

    The first observations come from ``env.reset()`` at construction (as the Collector's). The
    current observations live in ``observation`` (B, obs_dim); :meth:`state` / :meth:`load_state`
    give and take them as a TensorDict ``{"observation": ...}`` (the checkpoint's "carrier").
    """

    def __init__(self, env: EnvBase, actor: ProbabilisticActor, frames_per_batch: int) -> None:
        (self.num_envs,) = env.batch_size
        if frames_per_batch % self.num_envs:
            raise ValueError(f"frames_per_batch={frames_per_batch} is not a multiple of num_envs={self.num_envs}")
        self.env, self.actor = env, actor
        self.steps = frames_per_batch // self.num_envs
        with torch.no_grad():
            self.observation = env.reset().get(OBSERVATION_KEY).clone()
        self.action_shape = env.full_action_spec[ACTION_KEY].shape[1:]
        self.next_specs = {key: (spec.shape[1:], spec.dtype) for key, spec in (
            *env.full_observation_spec.items(True, True), *env.full_reward_spec.items(True, True),
            *env.full_done_spec.items(True, True))}
        self._fast = hasattr(env, "step_and_reset_into")
        self._box = tanh_normal.actor_box(actor)

    def state(self) -> TensorDict:
        return TensorDict({OBSERVATION_KEY: self.observation.clone()}, batch_size=[self.num_envs])

    def load_state(self, carrier: TensorDictBase) -> None:
        """Take the current observations from a carrier (ours, or an old checkpoint's Collector carrier)."""
        self.observation.copy_(carrier.get(OBSERVATION_KEY))

    def _allocate(self) -> TensorDict:
        b, t = self.num_envs, self.steps
        nxt = {key: torch.empty((b, t, *shape), dtype=dtype) for key, (shape, dtype) in self.next_specs.items()}
        return TensorDict({
            OBSERVATION_KEY: torch.empty((b, t, *self.observation.shape[1:]), dtype=self.observation.dtype),
            ACTION_KEY: torch.empty((b, t, *self.action_shape)),
            LOG_PROB_KEY: torch.empty((b, t)),
            "next": TensorDict(nxt, batch_size=[b, t]),
        }, batch_size=[b, t])

    @torch.no_grad()
    def collect(self) -> TensorDict:
        """A fresh (B, T) batch (see the module docstring)."""
        batch = self._allocate()
        observations, actions, log_probs = batch[OBSERVATION_KEY], batch[ACTION_KEY], batch[LOG_PROB_KEY]
        nxt = {key: batch["next"][key] for key in self.next_specs}
        with set_exploration_type(ExplorationType.RANDOM):
            for t in range(self.steps):
                observations[:, t] = self.observation
                action, log_prob = sample_actions(self.actor, self.observation, self._box)
                actions[:, t] = action
                log_probs[:, t] = log_prob
                step_out = {key: value[:, t] for key, value in nxt.items()}
                if self._fast:
                    self.env.step_and_reset_into(action, step_out, self.observation)
                else:
                    self._generic_step(action, step_out)
        return batch

    def _generic_step(self, action: torch.Tensor, step_out: dict[str, torch.Tensor]) -> None:
        carrier = TensorDict({OBSERVATION_KEY: self.observation, ACTION_KEY: action}, batch_size=[self.num_envs])
        stepped, following = self.env.step_and_maybe_reset(carrier)
        stepped_next = stepped.get("next")
        for key, out in step_out.items():
            out.copy_(stepped_next.get(key))
        self.observation = following.get(OBSERVATION_KEY).clone()
