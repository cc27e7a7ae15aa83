"""The OCP's per-step data: what changes from one planner step to the next (``ocp.OcpConfig`` holds the rest).

At each step the planner measures the ego, chooses a linearization reference, predicts the other vehicles and
hands the QP (``qp_builder.LtvMpcQp.update``) one ``OcpStepData``; its shapes are checked once, here.
Shapes use N, the horizon, and V_obs, the observed vehicles. States are (x [m], y [m], psi [rad], v [m/s]),
inputs (delta [rad], a [m/s^2]), the other vehicles' poses (x [m], y [m], heading [rad], v [m/s]).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from srmpc.mpc.problem.vehicle_model import INPUT_DIM, STATE_DIM


@dataclass(frozen=True)
class OcpStepData:
    """One step's data of the OCP (module doc for the units), as contiguous float64 arrays.

    Attributes:
        measured_state: x_hat (4,), the measured ego state [m, m, rad, m/s].
        linearization_states: x^r (N + 1, 4) [m, m, rad, m/s], the states the dynamics and the collision rows
            are linearized about; row 0 should be x_hat (the planner sets it).
        linearization_inputs: u^r (N, 2) [rad, m/s^2], the inputs the dynamics are linearized about.
        tracking_reference: x^ref (N + 1, 4) [m, m, rad, m/s], the tracked states (row 0 unused).
        last_input: u_hat (2,) [rad, m/s^2], the input applied at the previous step (the rate cost's u_{-1}).
        predicted_others: (N + 1, V_obs, 4) [m, m, rad, m/s], the observed vehicles' predicted poses.

    Raises:
        ValueError: an array's shape does not fit the others' (the message names the field).
    """

    measured_state: np.ndarray
    linearization_states: np.ndarray
    linearization_inputs: np.ndarray
    tracking_reference: np.ndarray
    last_input: np.ndarray
    predicted_others: np.ndarray

    def __post_init__(self) -> None:
        for name in ("measured_state", "linearization_states", "linearization_inputs", "tracking_reference",
                     "last_input", "predicted_others"):
            object.__setattr__(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float64))
        if self.linearization_inputs.ndim != 2:
            raise ValueError(f"OcpStepData.linearization_inputs must have shape (N, {INPUT_DIM}), "
                             f"not {self.linearization_inputs.shape}")
        stages = self.horizon + 1
        for name, shape in (("measured_state", (STATE_DIM,)), ("linearization_states", (stages, STATE_DIM)),
                            ("linearization_inputs", (self.horizon, INPUT_DIM)),
                            ("tracking_reference", (stages, STATE_DIM)), ("last_input", (INPUT_DIM,))):
            if getattr(self, name).shape != shape:
                raise ValueError(f"OcpStepData.{name} must have shape {shape}, not {getattr(self, name).shape}")
        others = self.predicted_others
        if others.ndim != 3 or others.shape[0] != stages or others.shape[2] != STATE_DIM:
            raise ValueError(f"OcpStepData.predicted_others must have shape (N + 1, V_obs, 4) = ({stages}, V_obs, "
                             f"{STATE_DIM}), not {others.shape}")

    @property
    def horizon(self) -> int:
        """N, the number of control intervals (u^r's rows)."""
        return int(self.linearization_inputs.shape[0])

    @property
    def n_observed(self) -> int:
        """V_obs, the observed vehicles."""
        return int(self.predicted_others.shape[1])


__all__ = ["OcpStepData"]
