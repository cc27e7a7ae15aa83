"""The OCP's collision and safety constraints on the exact ellipse norms, and their linearization.

The NLP the NMPC solves (``sqp``) keeps the ellipse constraints as they are (``problem.collision_constraints``'
g, not the QP's supporting half-planes). With p_c(x) = (x + d_c cos psi, y + d_c sin psi) the
centre of ego circle c and E_kj the ellipse of vehicle j at stage k, for k = 1..N::

    g_E(p) = || diag(1/a, 1/b) R(phi)^T (p - centre) ||_2
    collision:  min_c g_{E_kj}(p_c(x_k))  + s_j            >= 1      s_j >= 0 (one per vehicle)
    safety:     min_c g_{E'_kj}(p_c(x_k)) + sigma_kj       >= 1      sigma_kj >= 0

E' is the safety region (semi-axes a', b'). ``min_c g >= 1 - s`` is the same as ``g_c >= 1 - s``
for every circle c, so the constraints are smooth except where the ellipse norm is 0 (an ego circle
at another vehicle's centre). At the optimum s_j = max_k max(0, 1 - min_c g) and
sigma_kj = max(0, 1 - min_c g'), the slacks ``problem.nonlinear_cost`` charges.

Linearization about x^r (one row per stage and vehicle, as the LTV-MPC's): the circle
c* = argmin_c g(p_c(x^r)) and the first-order Taylor expansion

    g(p_c*(x)) ~= g^r + grad_p g^T J_p (x - x^r),   J_p = [[1, 0, -d sin psi^r], [0, 1, d cos psi^r]],

i.e. the row  n^T J_p x_k + slack >= 1 - g^r + n^T J_p x^r_k  with n = grad_p g(p_c*(x^r)).
Unlike the QP's merged row, the collision and safety rows have their own gradients (E' is not a
scaled E: a' = a + 8 m, b' = b + 0.3 m by default).

If p_c*(x^r) is (numerically) at the ellipse centre the gradient is undefined; the row then takes
the direction from behind the other vehicle along its axis (``DEGENERATE_NORM``).
"""

from __future__ import annotations

import numba
import numpy as np

from srmpc.mpc.problem import closest_circle

DEGENERATE_NORM = 1e-6
"""Ellipse norm (dimensionless) below which the gradient direction is replaced (module doc)."""


@numba.njit(cache=True)
def vehicle_frames(predicted_others, n_others, frames):
    """frames[k, j] = (x, y, cos phi, sin phi) of vehicle j < n_others at stage k: its ellipses' centre and
    axes, computed once for the kernels below (the NMPC evaluates them at every iterate, the vehicles fixed)."""
    for k in range(predicted_others.shape[0]):
        for j in range(n_others):
            frames[k, j, 0] = predicted_others[k, j, 0]
            frames[k, j, 1] = predicted_others[k, j, 1]
            frames[k, j, 2] = np.cos(predicted_others[k, j, 2])
            frames[k, j, 3] = np.sin(predicted_others[k, j, 2])


@numba.njit(cache=True)
def linearize_ellipse_rows(states, frames, n_others, circle_offsets, semi_axes,
                           coefficients, row_lower, norms):
    """One linearized row per stage k = 1..N and vehicle j < n_others (module doc).

    Args:
        states: (N + 1, 4) linearization states x^r.
        frames: (N + 1, >= n_others, 4) other vehicles' (x, y, cos phi, sin phi) (``vehicle_frames``).
        n_others: number of vehicles to fill.
        circle_offsets: (C,) circle offsets d_c [m].
        semi_axes: (2,) ellipse semi-axes (a, b) [m].
        coefficients: out (N, >= n_others, 3) row coefficients on (x, y, psi) of x_k.
        row_lower: out (N, >= n_others) 1 - g^r + n^T J_p x^r (slacks enter with coefficient 1).
        norms: out (N, >= n_others) g^r = min_c g(p_c(x^r_k)).
    """
    horizon = states.shape[0] - 1
    a = semi_axes[0]
    b = semi_axes[1]
    for k in range(horizon):
        px = states[k + 1, 0]
        py = states[k + 1, 1]
        psi = states[k + 1, 2]
        cos_psi = np.cos(psi)
        sin_psi = np.sin(psi)
        for j in range(n_others):
            ox, oy, cos_h, sin_h = frames[k + 1, j, 0], frames[k + 1, j, 1], frames[k + 1, j, 2], frames[k + 1, j, 3]
            best_norm, best, best_l, best_t = closest_circle(px, py, cos_psi, sin_psi, ox, oy, cos_h, sin_h,
                                                             circle_offsets, a, b)
            best_d = circle_offsets[best]
            if best_norm < DEGENERATE_NORM:
                grad_l, grad_t = -1.0 / a, 0.0
            else:
                grad_l = best_l / (a * a) / best_norm
                grad_t = best_t / (b * b) / best_norm
            nx = grad_l * cos_h - grad_t * sin_h
            ny = grad_l * sin_h + grad_t * cos_h
            c_psi = best_d * (-nx * sin_psi + ny * cos_psi)
            coefficients[k, j, 0] = nx
            coefficients[k, j, 1] = ny
            coefficients[k, j, 2] = c_psi
            row_lower[k, j] = 1.0 - best_norm + nx * px + ny * py + c_psi * psi
            norms[k, j] = best_norm


@numba.njit(cache=True)
def min_ellipse_norms(states, frames, n_others, circle_offsets, semi_axes, norms):
    """norms[k, j] = min_c g(p_c(x_{k+1})) for k < N, j < n_others (exact, no linearization); ``frames`` as
    ``linearize_ellipse_rows``'."""
    horizon = states.shape[0] - 1
    a = semi_axes[0]
    b = semi_axes[1]
    for k in range(horizon):
        px = states[k + 1, 0]
        py = states[k + 1, 1]
        cos_psi = np.cos(states[k + 1, 2])
        sin_psi = np.sin(states[k + 1, 2])
        for j in range(n_others):
            ox, oy, cos_h, sin_h = frames[k + 1, j, 0], frames[k + 1, j, 1], frames[k + 1, j, 2], frames[k + 1, j, 3]
            norms[k, j] = closest_circle(px, py, cos_psi, sin_psi, ox, oy, cos_h, sin_h, circle_offsets, a, b)[0]
