"""Closed-loop controllers for the scenario.

A controller has ``reset()`` (episode start), ``act(observation, scene) -> action`` with the
normalized observation and the scene measurement (``srmpc.scenario.highway.SceneMeasurement``:
ego and other vehicles' states, observation slots), returning the physical action
(delta [rad], a [m/s^2]), and ``episode_outcomes() -> dict[str, int]``: how many steps of the
episode each outcome produced (a planner's solved / fallback counts; empty for policies).
"""

from typing import Protocol

import numpy as np


class Controller(Protocol):
    def reset(self) -> None: ...

    def act(self, observation: np.ndarray, scene) -> np.ndarray: ...

    def episode_outcomes(self) -> dict[str, int]: ...
