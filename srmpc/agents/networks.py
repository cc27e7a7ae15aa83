"""Networks of PPO / PPO-L-SI, as TensorDict modules over the 30-float observation.

- Actor pi(a|s): an MLP gives the mean ``loc`` of a Gaussian in pre-squash space; its standard
  deviation ``scale = exp(log_std)`` is one learned parameter per action dimension, independent of
  the state (as in CleanRL's continuous PPO). The sample u ~ N(loc, scale) is squashed by
  ``TanhNormal`` into the action box: a = low + (high - low) (tanh(u) + 1) / 2, with the
  change-of-variables term in the log-probability. So every action respects the physical bounds
  (steering [-0.1, 0.1] rad, acceleration [-5, 5] m/s^2) and no clipping of samples is needed.
- Reward critic v(s) -> ``state_value``; cost critic v_c(s) -> ``cost_value``.
- Multiplier lambda(s) -> ``lambda``: min(softplus(MLP(s)), lambda_max) >= 0; lambda_max is the
  paper's numerical "infinite" multiplier (Table tab:lambda).

All MLPs have tanh hidden activations and orthogonal init (CleanRL): hidden gain sqrt(2), policy
head gain 0.01 (initial actions near the box centre), value heads gain 1.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import ProbabilisticActor, TanhNormal

OBSERVATION_KEY = "observation"
ACTION_KEY = "action"
LOG_PROB_KEY = "action_log_prob"
VALUE_KEY = "state_value"
COST_VALUE_KEY = "cost_value"
LAMBDA_KEY = "lambda"


def mlp(in_features: int, hidden_sizes: Sequence[int], out_features: int, head_gain: float) -> nn.Sequential:
    """tanh MLP with orthogonal init: hidden layers gain sqrt(2), output layer ``head_gain``, zero biases."""
    layers: list[nn.Module] = []
    width = in_features
    for size in hidden_sizes:
        linear = nn.Linear(width, size)
        nn.init.orthogonal_(linear.weight, math.sqrt(2.0))
        nn.init.zeros_(linear.bias)
        layers += [linear, nn.Tanh()]
        width = size
    head = nn.Linear(width, out_features)
    nn.init.orthogonal_(head.weight, head_gain)
    nn.init.zeros_(head.bias)
    layers.append(head)
    return nn.Sequential(*layers)


class GaussianHead(nn.Module):
    """obs -> (loc, scale): MLP mean and a state-independent scale exp(log_std)."""

    def __init__(self, observation_dim: int, action_dim: int, hidden_sizes: Sequence[int], initial_std: float):
        super().__init__()
        self.loc_net = mlp(observation_dim, hidden_sizes, action_dim, head_gain=0.01)
        self.log_std = nn.Parameter(torch.full((action_dim,), math.log(initial_std)))

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self.loc_net(observation)
        return loc, self.log_std.exp().expand_as(loc)


class Multiplier(nn.Module):
    """lambda(s) = min(softplus(MLP(s)), lambda_max); the output bias starts at ``initial_bias``."""

    def __init__(self, observation_dim: int, hidden_sizes: Sequence[int], lambda_max: float, initial_bias: float):
        super().__init__()
        self.net = mlp(observation_dim, hidden_sizes, 1, head_gain=0.01)
        nn.init.constant_(self.net[-1].bias, initial_bias)
        self.lambda_max = lambda_max

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return nn.functional.softplus(self.net(observation)).clamp(max=self.lambda_max)

    def logit(self, observation: torch.Tensor) -> torch.Tensor:
        """The pre-softplus output z(s), lambda(s) = min(softplus(z(s)), lambda_max)."""
        return self.net(observation)


def make_actor(
    observation_dim: int,
    action_low: torch.Tensor,
    action_high: torch.Tensor,
    hidden_sizes: Sequence[int],
    initial_std: float = 1.0,
) -> ProbabilisticActor:
    """Stochastic policy writing ``action`` and ``action_log_prob``; actions lie in [low, high]."""
    head = TensorDictModule(
        GaussianHead(observation_dim, action_low.numel(), hidden_sizes, initial_std),
        in_keys=[OBSERVATION_KEY], out_keys=["loc", "scale"],
    )
    return ProbabilisticActor(
        head,
        in_keys=["loc", "scale"],
        out_keys=[ACTION_KEY],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": action_low.clone(), "high": action_high.clone()},
        return_log_prob=True,
        log_prob_key=LOG_PROB_KEY,
    )


def make_value(observation_dim: int, hidden_sizes: Sequence[int], out_key: str) -> TensorDictModule:
    """State-value network obs -> ``out_key`` (shape [..., 1])."""
    return TensorDictModule(mlp(observation_dim, hidden_sizes, 1, head_gain=1.0),
                            in_keys=[OBSERVATION_KEY], out_keys=[out_key])


def make_multiplier(
    observation_dim: int, hidden_sizes: Sequence[int], lambda_max: float, initial_lambda: float
) -> TensorDictModule:
    """Multiplier network obs -> ``lambda`` in [0, lambda_max], starting near ``initial_lambda`` everywhere."""
    initial_bias = math.log(math.expm1(initial_lambda))  # softplus^-1
    return TensorDictModule(Multiplier(observation_dim, hidden_sizes, lambda_max, initial_bias),
                            in_keys=[OBSERVATION_KEY], out_keys=[LAMBDA_KEY])
