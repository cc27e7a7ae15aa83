"""The LTV-MPC QP (``srmpc.mpc.problem.LtvMpcQp``) written as HPIPM's stage-wise OCP QP, and back.

HPIPM solves, for stages k = 0..N with states x~_k and controls u~_k of per-stage sizes,

    min  sum_k 1/2 [u~_k; x~_k]^T [R_k S_k; S_k^T Q_k] [u~_k; x~_k] + r_k^T u~_k + q_k^T x~_k
    s.t. x~_{k+1} = A_k x~_k + B_k u~_k + b_k                         (k < N)
         lb_k <= (x~_k, u~_k)[idxb_k] <= ub_k,   lg_k <= C_k x~_k + D_k u~_k <= ug_k.

Our QP has two couplings that are not stage-wise: the rate cost ||u_k - u_{k-1}||_S^2 and the collision
slacks s_j, one per vehicle for the whole horizon. Both are carried as states, the standard exact
embedding (our own Riccati solver carries u_{k-1} the same way, and eliminates s by a Schur complement
instead, which HPIPM's OCP form has no place for). With m = V_obs observed vehicles:

    stage 0:          x~_0 = x_0 (4),                 u~_0 = (u_0, s) (2 + m),                  ng_0 = 0
    stage 1..N-2:     x~_k = (x_k, u_{k-1}, s) (6 + m), u~_k = (u_k, sigma_k) (2 + m),          ng_k = m
    stage N-1:        x~   = (x_{N-1}, u_{N-2}, s),    u~   = (u_{N-1}, sigma_{N-1}, sigma_N),  ng   = 2 m
    stage N:          x~_N = x_N (4),                  no controls,                              ng_N = 0

- dynamics: x_{k+1} = A_k x_k + B_k u_k + c_k, u_k copied into x~_{k+1}, s copied (identity);
- cost (the full Hessian of our 1/2 z^T P z + q^T z, so the objective is ours exactly): 2Q and
  q = -2Q x^ref on x_k (k >= 1); 2R + 2S on u_k, 2S on the carried u_{k-1} and -2S between them (the
  rate term of stage k); the rate term of stage 0 is linear, -2S u_hat on u_0 (u_hat is data);
  2 w_c2 and w_c1 on s (stage 0), 2 w_s2 and w_s1 on sigma;
- collision rows (stage k = 1..N-1, vehicle j): n_kj^T x_k[0:3] + s_j + sigma_kj >= h_kj; the rows of
  stage N go to stage N-1 through the dynamics, n^T (A x + B u + c)[0:3] + s_j + sigma_Nj >= h - ...,
  because CasADi's interface allows no controls at stage N (sigma_N is therefore a control of N-1);
- boxes only where our QP has them: x_0 = x_hat (equal bounds), y and v of x_k (k >= 1), u_k, s >= 0,
  0 <= sigma_kj <= sigma_hi. One-sided bounds and rows (s >= 0, the rows' upper side) are marked in
  ``upper_finite`` / ``row_upper_finite`` (HPIPM's C API masks them; CasADi replaces +inf by its ``inf``).

Empty vehicle slots (j >= m) do not enter; their slacks are 0 in the returned z, their unique optimum in
our QP (see ``interior_point``). Sizes at the default N = 25, m = 6: nx = 4, 12, ..., 12, 4;
nu = 8, ..., 8, 14, 0; ng = 0, 6, ..., 6, 12, 0.

``z_from_stagewise`` and ``stagewise_from_z`` map HPIPM's (x~, u~) to our z and back (warm starts).
"""

from __future__ import annotations

import numpy as np

from srmpc.mpc.problem import INPUT_DIM, LATERAL_INDEX, SPEED_INDEX, STATE_DIM

_POSITION_ROWS = 3
"""The collision normal acts on (x, y, psi) of x_k."""


class StagewiseQp:
    """Per-stage arrays of HPIPM's OCP QP for horizon N and m observed vehicles (module doc).

    Every array is allocated once and overwritten by ``update`` (stable memory for HPIPM's C API).
    Matrices are Fortran-ordered (column-major, as HPIPM and CasADi read them). Per stage k:
    ``A[k]`` (nx_{k+1}, nx_k), ``B[k]`` (nx_{k+1}, nu_k), ``b[k]``; ``Q[k]``, ``S[k]`` (nu_k, nx_k),
    ``R[k]``, ``q[k]``, ``r[k]``; ``C[k]`` (ng_k, nx_k), ``D[k]`` (ng_k, nu_k), ``lg[k]``, ``ug[k]``;
    boxes ``idxbx[k]`` / ``idxbu[k]`` (int32 indices into x~_k / u~_k), ``lbx``, ``ubx``, ``lbu``, ``ubu``,
    ``ubx_finite``, ``ubu_finite``, ``ug_finite`` (1.0 where the upper side exists, else 0.0).
    """

    def __init__(self, horizon: int, n_observed: int) -> None:
        if horizon < 2:
            raise ValueError(f"horizon={horizon}: the stage-wise form needs N >= 2")
        n, m = horizon, n_observed
        self.horizon, self.n_observed = n, m
        self.nx = np.array([STATE_DIM] + [STATE_DIM + INPUT_DIM + m] * (n - 1) + [STATE_DIM], dtype=np.int32)
        self.nu = np.array([INPUT_DIM + m] + [INPUT_DIM + m] * (n - 2) + [INPUT_DIM + 2 * m, 0], dtype=np.int32)
        self.ng = np.array([0] + [m] * (n - 2) + [2 * m, 0], dtype=np.int32)
        nx, nu, ng = self.nx, self.nu, self.ng

        def mat(rows, cols):
            return np.zeros((rows, cols), order="F")

        self.A = [mat(nx[k + 1], nx[k]) for k in range(n)]
        self.B = [mat(nx[k + 1], nu[k]) for k in range(n)]
        self.b = [np.zeros(nx[k + 1]) for k in range(n)]
        self.Q = [mat(nx[k], nx[k]) for k in range(n + 1)]
        self.S = [mat(nu[k], nx[k]) for k in range(n + 1)]
        self.R = [mat(nu[k], nu[k]) for k in range(n + 1)]
        self.q = [np.zeros(nx[k]) for k in range(n + 1)]
        self.r = [np.zeros(nu[k]) for k in range(n + 1)]
        self.C = [mat(ng[k], nx[k]) for k in range(n + 1)]
        self.D = [mat(ng[k], nu[k]) for k in range(n + 1)]
        self.lg = [np.zeros(ng[k]) for k in range(n + 1)]
        self.ug = [np.full(ng[k], np.inf) for k in range(n + 1)]
        self.ug_finite = [np.zeros(ng[k]) for k in range(n + 1)]
        # boxes: x_0 all (equal), x_k: y and v (k >= 1); u_k both inputs, s (stage 0), sigma
        self.idxbx = ([np.arange(STATE_DIM, dtype=np.int32)]
                      + [np.array([LATERAL_INDEX, SPEED_INDEX], dtype=np.int32)] * n)
        sigma_count = [0] + [m] * (n - 2) + [2 * m, 0]
        self.idxbu = [np.arange(nu[k], dtype=np.int32) for k in range(n)] + [np.zeros(0, dtype=np.int32)]
        self.lbx = [np.zeros(len(i)) for i in self.idxbx]
        self.ubx = [np.zeros(len(i)) for i in self.idxbx]
        self.ubx_finite = [np.ones(len(i)) for i in self.idxbx]
        self.lbu = [np.zeros(len(i)) for i in self.idxbu]
        self.ubu = [np.zeros(len(i)) for i in self.idxbu]
        self.ubu_finite = [np.ones(len(i)) for i in self.idxbu]
        self.ubu[0][INPUT_DIM:] = np.inf  # s >= 0 only
        self.ubu_finite[0][INPUT_DIM:] = 0.0
        self._sigma_count = sigma_count
        self._constant_structure()

    # --- the parts that do not change between QPs (identity blocks, weights' places)
    def _constant_structure(self) -> None:
        n, m = self.horizon, self.n_observed
        six = STATE_DIM + INPUT_DIM
        for k in range(n - 1):  # copies into x~_{k+1} = (x, u_k, s)
            self.B[k][STATE_DIM:six, :INPUT_DIM] = np.eye(INPUT_DIM)
            if k == 0:
                self.B[k][six:, INPUT_DIM:] = np.eye(m)  # s is a control of stage 0
            else:
                self.A[k][six:, six:] = np.eye(m)
        for k in range(1, n):  # collision rows of stage k: s_j + sigma_kj
            self.C[k][:m, six:] = np.eye(m)
            self.D[k][:m, INPUT_DIM:INPUT_DIM + m] = np.eye(m)
        self.C[n - 1][m:, six:] = np.eye(m)
        self.D[n - 1][m:, INPUT_DIM + m:] = np.eye(m)

    def update(self, qp) -> None:
        """Overwrite the values with those of an ``LtvMpcQp`` after its ``update`` (same m)."""
        if qp.n_observed != self.n_observed or qp.config.horizon != self.horizon:
            raise ValueError(f"StagewiseQp(N={self.horizon}, m={self.n_observed}) got a QP with "
                             f"N={qp.config.horizon}, m={qp.n_observed}")
        config, weights = qp.config, qp.config.weights
        n, m = self.horizon, self.n_observed
        six = STATE_DIM + INPUT_DIM
        two_q = 2.0 * np.asarray(weights.state, dtype=np.float64)
        two_r = 2.0 * np.asarray(weights.input, dtype=np.float64)
        two_s = 2.0 * np.asarray(weights.input_rate, dtype=np.float64)
        input_lower = np.array([config.steering_bounds_rad[0], config.acceleration_bounds_mps2[0]])
        input_upper = np.array([config.steering_bounds_rad[1], config.acceleration_bounds_mps2[1]])
        state_lower = np.array([config.lateral_bounds_m[0], config.speed_bounds_mps[0]])
        state_upper = np.array([config.lateral_bounds_m[1], config.speed_bounds_mps[1]])
        a_mats, b_mats, offsets = qp.state_matrices, qp.input_matrices, qp.affine_offsets
        normals, row_lower = qp.collision_coefficients[:, :m], qp.collision_row_lower[:, :m]
        sigma_upper = qp.safety_slack_upper[:, :m]
        # dynamics
        for k in range(n):
            self.A[k][:STATE_DIM, :STATE_DIM] = a_mats[k]
            self.B[k][:STATE_DIM, :INPUT_DIM] = b_mats[k]
            self.b[k][:STATE_DIM] = offsets[k]
        # cost
        self.R[0][:INPUT_DIM, :INPUT_DIM] = np.diag(two_r + two_s)
        self.R[0][INPUT_DIM:, INPUT_DIM:] = 2.0 * weights.collision_slack_quadratic * np.eye(m)
        self.r[0][:INPUT_DIM] = -two_s * qp.last_input
        self.r[0][INPUT_DIM:] = weights.collision_slack_linear
        for k in range(1, n + 1):
            self.Q[k][:STATE_DIM, :STATE_DIM] = np.diag(two_q)
            self.q[k][:STATE_DIM] = -two_q * qp.tracking_reference[k]
            if k < n:
                self.Q[k][STATE_DIM:six, STATE_DIM:six] = np.diag(two_s)
                self.S[k][:INPUT_DIM, STATE_DIM:six] = -np.diag(two_s)
                self.R[k][:INPUT_DIM, :INPUT_DIM] = np.diag(two_r + two_s)
                sigma = slice(INPUT_DIM, INPUT_DIM + self._sigma_count[k])
                self.R[k][sigma, sigma] = 2.0 * weights.safety_slack_quadratic * np.eye(self._sigma_count[k])
                self.r[k][sigma] = weights.safety_slack_linear
        # collision rows: stage k = 1..N-1 on x_k; stage N's on stage N-1 through the dynamics
        for k in range(1, n):
            self.C[k][:m, :_POSITION_ROWS] = normals[k - 1]
            self.lg[k][:m] = row_lower[k - 1]
        last = n - 1
        self.C[last][m:, :STATE_DIM] = normals[last] @ a_mats[last][:_POSITION_ROWS]
        self.D[last][m:, :INPUT_DIM] = normals[last] @ b_mats[last][:_POSITION_ROWS]
        self.lg[last][m:] = row_lower[last] - normals[last] @ offsets[last][:_POSITION_ROWS]
        # boxes
        self.lbx[0][:] = self.ubx[0][:] = qp.measured_state
        for k in range(1, n + 1):
            self.lbx[k][:], self.ubx[k][:] = state_lower, state_upper
        for k in range(n):
            self.lbu[k][:INPUT_DIM], self.ubu[k][:INPUT_DIM] = input_lower, input_upper
            if k == 0:
                continue
            count = self._sigma_count[k]
            self.lbu[k][INPUT_DIM:] = 0.0
            self.ubu[k][INPUT_DIM:INPUT_DIM + m] = sigma_upper[k - 1]
            if count > m:
                self.ubu[k][INPUT_DIM + m:] = sigma_upper[last]

    # --- HPIPM's (x~, u~) <-> our z
    def z_from_stagewise(self, qp, states: list[np.ndarray], controls: list[np.ndarray]) -> np.ndarray:
        """Our z (``LtvMpcQp`` layout) from HPIPM's x~_k, u~_k; empty slots' slacks 0."""
        n, m = self.horizon, self.n_observed
        x = np.stack([states[k][:STATE_DIM] for k in range(n + 1)])
        u = np.stack([controls[k][:INPUT_DIM] for k in range(n)])
        z = qp.pack(x, u)
        layout = qp.layout
        z[layout.collision_slack_indices()[:m]] = controls[0][INPUT_DIM:]
        sigma_idx = layout.safety_slack_indices()
        for k in range(1, n):
            z[sigma_idx[k - 1, :m]] = controls[k][INPUT_DIM:INPUT_DIM + m]
        z[sigma_idx[n - 1, :m]] = controls[n - 1][INPUT_DIM + m:]
        return z

    def stagewise_from_z(self, qp, z: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """HPIPM's (x~_k, u~_k) lists from our z (e.g. a shifted previous solution as a warm start)."""
        n, m = self.horizon, self.n_observed
        x, u, s, sigma = qp.split_solution(z)
        s, sigma = s[:m], sigma[:, :m]
        states = [x[0].copy()]
        for k in range(1, n):
            states.append(np.concatenate([x[k], u[k - 1], s]))
        states.append(x[n].copy())
        controls = [np.concatenate([u[0], s])]
        for k in range(1, n - 1):
            controls.append(np.concatenate([u[k], sigma[k - 1]]))
        controls.append(np.concatenate([u[n - 1], sigma[n - 2], sigma[n - 1]]))
        controls.append(np.zeros(0))
        return states, controls
