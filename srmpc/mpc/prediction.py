"""Predicted motion of the other vehicles over the MPC horizon.

A predictor maps the observed vehicles ``(V, 4) [x, y, heading, speed]`` to their poses at the
horizon's stages k = 0..N, shape ``(N + 1, V, 4)``.  The default is constant velocity along the
current heading::

    x_k = x_0 + v cos(phi) k dt,   y_k = y_0 + v sin(phi) k dt,   phi_k = phi,   v_k = v.

Hook for the batched simulator: any callable with the ``TrafficPredictor`` signature can be
passed to the planner/controller, e.g. an IDM rollout of the simulator's own traffic model
(``IdmRolloutPredictor`` below adapts a function that returns the rollout).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol

import numpy as np


class TrafficPredictor(Protocol):
    """Predicts other vehicles' states at stages 0..horizon."""

    def __call__(self, others: np.ndarray, horizon: int, control_period_s: float) -> np.ndarray:
        """Return (horizon + 1, V, 4) predicted [x, y, heading, speed]; stage 0 = ``others``."""
        ...


def predict_constant_velocity(
    others: np.ndarray, horizon: int, control_period_s: float
) -> np.ndarray:
    """Constant-velocity, constant-heading prediction (see module doc); (N + 1, V, 4)."""
    others = np.asarray(others, dtype=np.float64).reshape(-1, 4)
    times_s = np.arange(horizon + 1)[:, None] * control_period_s
    predicted = np.broadcast_to(others, (horizon + 1, *others.shape)).copy()
    speed = others[:, 3]
    predicted[:, :, 0] += times_s * (speed * np.cos(others[:, 2]))[None, :]
    predicted[:, :, 1] += times_s * (speed * np.sin(others[:, 2]))[None, :]
    return predicted


class IdmRolloutPredictor:
    """Adapter for a simulator-supplied rollout (e.g. IDM with lane keeping).

    Args:
        rollout: ``rollout(others, horizon, control_period_s) -> (horizon + 1, V, 4)``, the
            simulator's prediction of the same vehicles in the same order.  The batched
            simulator is expected to provide it; until then use ``predict_constant_velocity``.
    """

    def __init__(self, rollout: Callable[[np.ndarray, int, float], np.ndarray]) -> None:
        self._rollout = rollout

    def __call__(self, others: np.ndarray, horizon: int, control_period_s: float) -> np.ndarray:
        others = np.asarray(others, dtype=np.float64).reshape(-1, 4)
        predicted = np.asarray(self._rollout(others, horizon, control_period_s), dtype=np.float64)
        expected = (horizon + 1, others.shape[0], 4)
        if predicted.shape != expected:
            raise ValueError(f"rollout returned shape {predicted.shape}, expected {expected}")
        return predicted
