"""Shared QP fixtures for the LTV-MPC tests."""

import numpy as np
import pytest

from srmpc.mpc.problem import (
    LtvMpcQp,
    OcpConfig,
    OcpStepData,
    lane_keeping_tracking_reference,
    predict_constant_velocity,
)

SIX_VEHICLES = np.array([
    [30.0, 4.0, 0.0, 20.0], [-20.0, 4.0, 0.0, 25.0], [10.0, 0.0, 0.0, 24.0],
    [40.0, 8.0, 0.0, 22.0], [-15.0, 8.0, 0.0, 23.0], [60.0, 0.0, 0.0, 25.0]])


@pytest.fixture
def six_vehicles() -> np.ndarray:
    return SIX_VEHICLES.copy()


@pytest.fixture
def loaded_qp() -> LtvMpcQp:
    """A QP linearized about a lane-following rollout in the middle lane among 6 vehicles."""
    config = OcpConfig()
    qp = LtvMpcQp(config)
    horizon = config.horizon
    ego = np.array([0.0, 4.0, 0.0, 22.0])
    inputs = np.zeros((horizon, 2))
    states = qp.model.rollout(ego, inputs)
    qp.update(OcpStepData(ego, states, inputs, lane_keeping_tracking_reference(horizon), np.zeros(2),
                          predict_constant_velocity(SIX_VEHICLES, horizon, config.control_period_s)))
    return qp
