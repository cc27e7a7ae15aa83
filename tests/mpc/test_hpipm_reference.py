"""HPIPM on the LTV-MPC QP in its stage-wise form solves the same QP as our solver and Clarabel.

Measured on these QPs (6, 3 and 0 observed vehicles; a cold start, then a warm start from HPIPM's own
shifted solution; Clarabel at 1e-9): the largest deviation from Clarabel's z was 1.96e-6 for HPIPM (1.95e-6
through its C API, 1.96e-6 through CasADi's plugin; 1.29e-6 far down the road) and 1.26e-6 for our solver,
2.19e-6 between HPIPM and ours; objectives within 1.1e-10 relative; constraint violations below 4e-12.
``TOLERANCE`` leaves a factor 5."""

import numpy as np
import pytest

from srmpc.mpc.problem import (
    LtvMpcQp,
    OcpConfig,
    OcpStepData,
    lane_keeping_tracking_reference,
    predict_constant_velocity,
)
from srmpc.mpc.solvers import make_solver

casadi = pytest.importorskip("casadi", reason="casadi (optional extra 'nmpc') is not installed")

from srmpc.mpc.solvers.hpipm_native import HpipmNativeSolver  # noqa: E402
from srmpc.mpc.solvers.hpipm_reference import HpipmCasadiSolver  # noqa: E402
from srmpc.mpc.solvers.hpipm_stagewise import StagewiseQp  # noqa: E402

TOLERANCE = 1e-5
"""Largest |z - z_Clarabel| accepted (m, rad, m/s, m/s^2 and slack units)."""
OBJECTIVE_TOLERANCE = 1e-6
"""Largest |f - f_Clarabel| / max(1, |f_Clarabel|) accepted."""


def _qp(six_vehicles: np.ndarray, n_vehicles: int, ego_x: float = 0.0) -> LtvMpcQp:
    config = OcpConfig()
    qp = LtvMpcQp(config)
    horizon = config.horizon
    ego = np.array([ego_x, 4.0, 0.0, 22.0])
    inputs = np.zeros((horizon, 2))
    qp.update(OcpStepData(ego, qp.model.rollout(ego, inputs), inputs, lane_keeping_tracking_reference(horizon),
                          np.array([0.01, 0.3]),
                          predict_constant_velocity(six_vehicles[:n_vehicles], horizon, config.control_period_s)))
    return qp


def test_stagewise_round_trip_and_sizes(six_vehicles):
    qp = _qp(six_vehicles, 6)
    stages = StagewiseQp(qp.config.horizon, qp.n_observed)
    stages.update(qp)
    assert stages.nx.tolist() == [4] + [12] * 24 + [4]
    assert stages.nu.tolist() == [8] * 24 + [14, 0]
    assert stages.ng.tolist() == [0] + [6] * 23 + [12, 0]
    z = make_solver("clarabel").solve(qp).z
    np.testing.assert_array_equal(stages.z_from_stagewise(qp, *stages.stagewise_from_z(qp, z)), z)


@pytest.mark.parametrize("n_vehicles", [6, 3, 0])
@pytest.mark.parametrize("solver_class", [HpipmNativeSolver, HpipmCasadiSolver])
def test_hpipm_matches_clarabel_and_ours(six_vehicles, n_vehicles, solver_class):
    qp = _qp(six_vehicles, n_vehicles)
    reference = make_solver("clarabel").solve(qp)
    ours = make_solver("riccati_ipm_cold").solve(qp)
    assert reference.solved and ours.solved
    hpipm = solver_class(warm_start=True)
    for _ in range(2):  # cold, then warm from its own (shifted) solution
        solution = hpipm.solve(qp)
        assert solution.solved, solution.status
        assert np.max(np.abs(solution.z - reference.z)) < TOLERANCE
        assert np.max(np.abs(solution.z - ours.z)) < TOLERANCE
        f, f_reference = qp.objective(solution.z), qp.objective(reference.z)
        assert abs(f - f_reference) / max(1.0, abs(f_reference)) < OBJECTIVE_TOLERANCE
        violation = qp.constraint_violation(solution.z)
        assert max(violation.values()) < 1e-9


def test_hpipm_native_boxes_only_bounded_components(six_vehicles):
    """No artificial bounds: far down the road (x = 2e4 m) the native form solves; through CasADi, which
    boxes the free x at +-1e4 (``CASADI_INFINITY``), the same QP is infeasible."""
    far = six_vehicles + np.array([2e4, 0.0, 0.0, 0.0])
    qp = _qp(far, 6, ego_x=2e4)
    reference = make_solver("clarabel").solve(qp)
    solution = HpipmNativeSolver().solve(qp)
    assert reference.solved and solution.solved
    assert np.max(np.abs(solution.z - reference.z)) < TOLERANCE
    assert not HpipmCasadiSolver().solve(qp).solved
