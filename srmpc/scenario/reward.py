"""Reward terms, paper eq. (reward-function). See :class:`RewardParameters` for the scale."""

import numpy as np
from numba import njit


@njit(cache=True)
def reward_prime(vx: float, y: float, vx_ref: float, y_ref: float, speed_weight: float) -> float:
    """r' = -g (vx_ref - vx)^2 - (1 - g) (y_ref - y)^2, the paper's evaluation reward (J_r sums it)."""
    return -speed_weight * (vx_ref - vx) ** 2 - (1.0 - speed_weight) * (y_ref - y) ** 2


@njit(cache=True)
def training_reward(r_prime: float, scale: float) -> float:
    """r = exp(r' / scale) in (0, 1]: the exponentiated, normalized reward the agents train on."""
    return np.exp(r_prime / scale)
