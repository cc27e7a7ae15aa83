"""The NMPC's KKT residual (``srmpc.mpc.nmpc.kkt_residual``) on the committed closed-loop states (``test_nmpc.py``'s).

A residual built from wrong multipliers, signs or Jacobians would not vanish at a KKT point: these tests drive the
SQP to tight tolerances and check that it does, and that it sees a plan moved off the KKT point along a feasible
direction.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from srmpc.mpc.nmpc import NmpcSettings, NmpcSolver
from srmpc.mpc.nmpc.kkt_residual import SCALE_THRESHOLD, scaled_residual
from srmpc.mpc.problem import OcpConfig, OcpStepData

STATES = Path(__file__).parent.parent / "data" / "nmpc_states.npz"
TIGHT = NmpcSettings(primal_tolerance=1e-9, stationarity_tolerance=1e-9, max_iterations=300, qp_tolerance=1e-10)
"""SQP and QP tolerances far below the defaults: the plan is then a KKT point up to the QP's accuracy."""
TIGHT_ERROR = 1e-6
"""E at ``TIGHT``'s plans; measured up to 1.3e-7 (the QP's tolerance 1e-10 times multipliers up to ~1e3)."""


@pytest.fixture(scope="module")
def states() -> dict[str, np.ndarray]:
    with np.load(STATES) as data:
        return {key: data[key] for key in data.files}


def solve(solver, states, i):
    n = int(states["n_observed"][i])
    return solver.solve(OcpStepData(states["ego"][i], states["rollout_states"][i], states["rollout_inputs"][i],
                                    states["tracking"][i], states["last_input"][i], states["others"][i][:, :n]))


def test_the_residual_vanishes_at_a_tightly_converged_plan(states):
    default, tight = NmpcSolver(OcpConfig()), NmpcSolver(OcpConfig(), TIGHT)
    for i in range(states["ego"].shape[0]):
        loose, exact = solve(default, states, i), solve(tight, states, i)
        assert loose.converged and exact.converged, i
        assert np.isfinite(loose.kkt.error) and loose.kkt.primal_infeasibility == loose.primal_infeasibility
        assert exact.kkt.error <= TIGHT_ERROR, (i, exact.kkt)
        assert exact.kkt.stationarity_scale >= 1.0 and exact.kkt.complementarity_scale >= 1.0


def test_a_feasible_move_off_the_kkt_point_is_seen(states):
    """Raising every collision slack by 1e-4 keeps the plan feasible (theta unchanged) but breaks complementarity
    (the slack's bound multiplier is at least w_col,1 = 1e4) and, where the slack is in the QP, stationarity."""
    solver = NmpcSolver(OcpConfig(), TIGHT)
    i = 2  # dense: 6 observed vehicles
    n = int(states["n_observed"][i])
    others = np.ascontiguousarray(states["others"][i][:, :n])
    result = solve(solver, states, i)
    slacks = np.concatenate([result.collision_slacks, np.zeros(n)])  # the safety rows' s'_j are 0 at a solution
    w = np.concatenate([result.states.ravel(), result.inputs.ravel(), slacks, result.safety_slacks.ravel()])
    assert solver._kkt_residual(w, n, others, 0, result.iterations, 0.0).error <= TIGHT_ERROR
    w[w.size - n * (solver.config.horizon + 2):w.size - n * (solver.config.horizon + 1)] += 1e-4
    moved = solver._kkt_residual(w, n, others, 0, result.iterations, 0.0)
    assert moved.complementarity >= solver.config.weights.collision_slack_linear * 1e-4 * 0.99
    assert moved.error >= 0.1


def test_ipopt_scaling():
    """s_d = max(s_max, mean |multiplier|) / s_max (Waechter & Biegler 2006, eq. 5), the same for s_c."""
    small = scaled_residual(1e-3, 1e-3, 1e-9, 10.0, 5.0, 4, 6)
    assert small.stationarity_scale == small.complementarity_scale == 1.0 and small.error == 1e-3
    large = scaled_residual(1e-3, 1e-3, 1e-9, 10 * SCALE_THRESHOLD * 200.0, 6 * SCALE_THRESHOLD * 400.0, 4, 6)
    assert large.stationarity_scale == pytest.approx(200.0) and large.complementarity_scale == pytest.approx(400.0)
    assert large.error == pytest.approx(1e-3 / 200.0)
