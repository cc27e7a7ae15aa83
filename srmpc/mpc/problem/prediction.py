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

import numba
import numpy as np


class TrafficPredictor(Protocol):
    """Predicts other vehicles' states at stages 0..horizon."""

    def __call__(self, others: np.ndarray, horizon: int, control_period_s: float) -> np.ndarray:
        """Return (horizon + 1, V, 4) predicted [x, y, heading, speed]; stage 0 = ``others``."""
        ...


@numba.njit(cache=True)
def constant_velocity_rollout(others, horizon, control_period_s, predicted):
    """``predict_constant_velocity`` of ``others`` (V, 4) into ``predicted`` (N + 1, V, 4) (module doc)."""
    for j in range(others.shape[0]):
        x, y, heading, speed = others[j, 0], others[j, 1], others[j, 2], others[j, 3]
        velocity_x = speed * np.cos(heading)
        velocity_y = speed * np.sin(heading)
        for k in range(horizon + 1):
            time_s = k * control_period_s
            predicted[k, j, 0] = x + velocity_x * time_s
            predicted[k, j, 1] = y + velocity_y * time_s
            predicted[k, j, 2] = heading
            predicted[k, j, 3] = speed


def predict_constant_velocity(
    others: np.ndarray, horizon: int, control_period_s: float
) -> np.ndarray:
    """Constant-velocity, constant-heading prediction (see module doc); (N + 1, V, 4)."""
    others = np.ascontiguousarray(others, dtype=np.float64).reshape(-1, 4)
    predicted = np.empty((horizon + 1, others.shape[0], 4))
    constant_velocity_rollout(others, int(horizon), float(control_period_s), predicted)
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
