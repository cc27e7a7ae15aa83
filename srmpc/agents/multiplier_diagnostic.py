"""Does lambda(s) track the constraint? lambda(s) against v_c(s) and the realized danger, on policy states.

Computed at the end of a PPO-L-SI training run on its last collected batch (B scenes x T steps of the
final stochastic policy) with the final networks, and written to ``multiplier.json`` (statistics) and
``multiplier_samples.csv`` (a subsample for the scatter figure) in the run's output directory.

Statistics (all over the states whose ``horizon_steps`` look-ahead fits in the batch):
- ``corr_lambda_cost_value``: Pearson r of lambda(s) and the cost critic v_c(s);
- ``spearman_lambda_cost_value``: the same on ranks (lambda is often bimodal, r then understates it);
- ``corr_lambda_event_ahead``: point-biserial r of lambda(s) and "a collision or road exit within the
  next ``horizon_steps`` steps" (the danger v_c is meant to measure, independent of the critic);
- ``corr_cost_value_event_ahead``: the critic's own r with that event (how well v_c knows the danger);
- ``lambda_mean_violated`` / ``lambda_mean_satisfied``: mean lambda where v_c(s) > d and where not;
- ``lambda_mean_event_ahead`` / ``lambda_mean_no_event_ahead``: mean lambda before an event and elsewhere;
- ``share_violated``, ``share_event_ahead``, ``share_at_max``, ``states``.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDict, TensorDictBase

from srmpc.agents.networks import COST_VALUE_KEY, LAMBDA_KEY, OBSERVATION_KEY
from srmpc.agents.ppo_lsi_loss import PPOLSILoss, pearson

HORIZON_STEPS = 10
"""Look-ahead of the realized-danger label [steps] (2 s at the 5 Hz policy rate)."""
SAMPLES = 4000
"""States kept in multiplier_samples.csv for the scatter figure."""


def event_ahead(event_cost: torch.Tensor, done: torch.Tensor, horizon_steps: int) -> torch.Tensor:
    """(B, T) bool: an event cost occurs at one of steps t..t+horizon-1 of the same episode.

    ``event_cost`` and ``done`` are (B, T) of the transitions s_t -> s_{t+1}; an episode ends at the
    first done, so the window stops there (a done with an event counts, a done without ends the window).
    Only t <= T - horizon_steps have their whole window in the batch.
    """
    steps = event_cost.shape[1]
    ahead = torch.zeros_like(done, dtype=torch.bool)
    open_window = torch.ones_like(done, dtype=torch.bool)
    for offset in range(horizon_steps):
        valid = steps - offset
        ahead[:, :valid] |= open_window[:, :valid] & (event_cost[:, offset:] > 0)
        open_window[:, :valid] &= ~done[:, offset:]
    return ahead


def _spearman(x: torch.Tensor, y: torch.Tensor) -> float:
    rank = lambda v: torch.argsort(torch.argsort(v)).double()  # noqa: E731 (ties broken by order)
    return float(pearson(rank(x), rank(y)))


@torch.no_grad()
def multiplier_diagnostic(loss: PPOLSILoss, batch: TensorDictBase, horizon_steps: int = HORIZON_STEPS,
                          samples: int = SAMPLES, seed: int = 0) -> tuple[dict[str, float], dict[str, list[float]]]:
    """Statistics of lambda(s) vs v_c(s) and the realized danger on a (B, T) batch, and a subsample."""
    if not loss.constrained:
        raise ValueError("the multiplier diagnostic needs a constrained (PPO-L-SI) loss")
    steps = batch.shape[1]
    if steps < horizon_steps:
        raise ValueError(f"batch has {steps} steps per scene, fewer than horizon_steps={horizon_steps}")
    nxt = batch.get("next")
    event = event_ahead(nxt.get("event_cost").squeeze(-1), nxt.get("done").squeeze(-1), horizon_steps)
    keep = slice(0, steps - horizon_steps + 1)
    observation = batch.get(OBSERVATION_KEY)[:, keep].reshape(-1, batch.get(OBSERVATION_KEY).shape[-1])
    states = TensorDict({OBSERVATION_KEY: observation}, batch_size=[observation.shape[0]])
    lam = loss.multiplier_network(states.clone()).get(LAMBDA_KEY).flatten().double()
    cost_value = loss.cost_critic_network(states.clone()).get(COST_VALUE_KEY).flatten().double()
    event = event[:, keep].reshape(-1)
    violated = cost_value > loss.cost_threshold

    def mean_where(mask: torch.Tensor) -> float:
        return float(lam[mask].mean()) if bool(mask.any()) else math.nan

    stats = {
        "states": int(lam.numel()),
        "horizon_steps": horizon_steps,
        "corr_lambda_cost_value": float(pearson(lam, cost_value)),
        "spearman_lambda_cost_value": _spearman(lam, cost_value),
        "corr_lambda_event_ahead": float(pearson(lam, event.double())),
        "corr_cost_value_event_ahead": float(pearson(cost_value, event.double())),
        "lambda_mean": float(lam.mean()),
        "lambda_mean_violated": mean_where(violated),
        "lambda_mean_satisfied": mean_where(~violated),
        "lambda_mean_event_ahead": mean_where(event),
        "lambda_mean_no_event_ahead": mean_where(~event),
        "share_violated": float(violated.double().mean()),
        "share_event_ahead": float(event.double().mean()),
        "share_at_max": float((lam >= loss.lambda_max * (1.0 - 1e-6)).double().mean()),
    }
    # Subsample for the scatter: every state before an event (rare) plus a uniform draw of the rest.
    generator = torch.Generator().manual_seed(seed)
    rare = event.nonzero().flatten()[:samples // 4]
    rest = torch.randperm(lam.numel(), generator=generator)[:samples - rare.numel()]
    index = torch.cat([rare, rest])
    subsample = {"lambda": lam[index].tolist(), "cost_value": cost_value[index].tolist(),
                 "event_ahead": event[index].double().tolist()}
    return stats, subsample
