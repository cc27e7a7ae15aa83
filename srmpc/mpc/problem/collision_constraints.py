"""Linearized ellipse collision constraints with a safety region (paper eq. collision-constraint).

For an ego circle centre p (offset d along the ego's heading psi) and another vehicle at
c = (c_x, c_y) with heading phi, the ellipse norm is

    g(p) = || diag(1/a, 1/b) R(phi)^T (p - c) ||_2,    p(x) = (x + d cos psi, y + d sin psi),

and the collision constraint is g(p) >= 1 (paper: the squared form > 1).  The ego is the union
of its circles, so it is collision-free with vehicle j iff min_c g(p_c(x)) >= 1.  Linearizing this
about the reference x^r (first-order Taylor, as the paper linearizes all constraints) keeps the
critical circle c* = argmin_c g(p_c(x^r)): one row per stage and vehicle.

g is positively 1-homogeneous in p - c, so its Taylor expansion

    g(p(x)) ~= n^T (p(x^r) - c) + n^T J_p(x^r) (x - x^r),    n = grad g(p(x^r)),

is the supporting half-plane of the ellipse in the direction of p(x^r) - c (the tangent at the
boundary point on that ray).  It implies g(p) >= 1 for p(x) itself, a conservative convex inner
approximation of the collision-free set.  Row coefficients on (x, y, psi):
(n_x, n_y, d (-n_x sin psi^r + n_y cos psi^r)).

Safety region (Jain et al. 2019): a larger ellipse E' (semi-axes a', b') about the same vehicle.
Its supporting half-plane with the same normal n lies at n^T (p - c) >= h'(n), where
h'(n) = sqrt(a'^2 n_l^2 + b'^2 n_t^2) (n_l, n_t: n in the other vehicle's frame) is E''s
support function (the collision ellipse's is 1 for this n).  Both half-planes share one row with
the expensive collision slack s_j >= 0 and the cheap safety slack 0 <= sigma_kj <= h'(n) - 1:

    n^T J_p x_k + s_j + sigma_kj >= h'(n) - n^T (p(x^r) - c) + n^T J_p x^r.

Inside the safety half-plane only sigma is spent (cheap); past the collision half-plane sigma is
exhausted and s_j pays (expensive).

If p(x^r) is (numerically) at the ellipse centre the gradient is undefined; the direction is then
taken from the current relative position (stage 0), and if that too is degenerate, from behind
the other vehicle along its axis.
"""
from __future__ import annotations

import numba
import numpy as np

_DEGENERATE_NORM = 1e-6


@numba.njit(cache=True)
def _ellipse_normal(dx, dy, heading, semi_major, semi_minor, out):
    """grad of g at relative position (dx, dy); returns g; writes the gradient to out[0:2]."""
    cos_h = np.cos(heading)
    sin_h = np.sin(heading)
    longitudinal = cos_h * dx + sin_h * dy
    lateral = -sin_h * dx + cos_h * dy
    norm = np.sqrt((longitudinal / semi_major) ** 2 + (lateral / semi_minor) ** 2)
    if norm < _DEGENERATE_NORM:
        out[0] = 0.0
        out[1] = 0.0
        return norm
    gl = longitudinal / (semi_major * semi_major) / norm
    gt = lateral / (semi_minor * semi_minor) / norm
    out[0] = gl * cos_h - gt * sin_h
    out[1] = gl * sin_h + gt * cos_h
    return norm


@numba.njit(cache=True)
def _direction_normal(dx, dy, now_dx, now_dy, heading, semi_major, semi_minor, out):
    """Normal for the half-plane, with the degenerate-direction fallbacks of the module doc."""
    norm = _ellipse_normal(dx, dy, heading, semi_major, semi_minor, out)
    if norm >= _DEGENERATE_NORM:
        return
    norm = _ellipse_normal(now_dx, now_dy, heading, semi_major, semi_minor, out)
    if norm >= _DEGENERATE_NORM:
        return
    _ellipse_normal(-np.cos(heading), -np.sin(heading), heading, semi_major, semi_minor, out)


@numba.njit(inline="always")
def closest_circle(px, py, cos_psi, sin_psi, ox, oy, cos_h, sin_h, circle_offsets_m, a, b):
    """(g, c*, longitudinal, lateral) of the ego circle c* = argmin_c g(p_c(x)) (module doc) in the ellipse (a, b)
    of the vehicle at (ox, oy) with heading (cos_h, sin_h): its norm, its index and its centre's offset from the
    vehicle's in the vehicle's frame [m]. The ego is at (px, py) [m] with heading (cos_psi, sin_psi)."""
    best_norm, best, best_l, best_t = np.inf, 0, 0.0, 0.0
    for c in range(circle_offsets_m.shape[0]):
        d = circle_offsets_m[c]
        dx = px + d * cos_psi - ox
        dy = py + d * sin_psi - oy
        longitudinal = cos_h * dx + sin_h * dy
        lateral = -sin_h * dx + cos_h * dy
        norm = np.sqrt((longitudinal / a) ** 2 + (lateral / b) ** 2)
        if norm < best_norm:
            best_norm, best, best_l, best_t = norm, c, longitudinal, lateral
    return best_norm, best, best_l, best_t


@numba.njit(cache=True, inline="always")
def _empty_row(k, j, coefficients, row_lower, safety_slack_upper, critical_circle):
    """An empty slot's row: zero coefficients and bounds, s_j + sigma_kj >= 0."""
    coefficients[k, j, 0] = 0.0
    coefficients[k, j, 1] = 0.0
    coefficients[k, j, 2] = 0.0
    row_lower[k, j] = 0.0
    safety_slack_upper[k, j] = 0.0
    critical_circle[k, j] = 0


@numba.njit(cache=True, inline="always")
def _vehicle_row(k, j, ego_states, predicted_others, circle_offsets_m, collision_semi_axes_m, safety_semi_axes_m,
                 normal, coefficients, row_lower, safety_slack_upper, critical_circle):
    """Row (k, j) for an observed vehicle (module doc): the critical circle c*, the normal n of the collision
    ellipse's supporting half-plane at p_{c*}(x^r_{k+1}), E''s support h'(n), and the merged row
    n^T J_p x + s_j + sigma_kj >= h'(n) - n^T (p(x^r) - c) + n^T J_p x^r with 0 <= sigma_kj <= h'(n) - 1."""
    a = collision_semi_axes_m[0]
    b = collision_semi_axes_m[1]
    stage = k + 1
    px = ego_states[stage, 0]
    py = ego_states[stage, 1]
    psi = ego_states[stage, 2]
    cos_psi = np.cos(psi)
    sin_psi = np.sin(psi)
    ox = predicted_others[stage, j, 0]
    oy = predicted_others[stage, j, 1]
    heading = predicted_others[stage, j, 2]
    cos_h = np.cos(heading)
    sin_h = np.sin(heading)
    best = closest_circle(px, py, cos_psi, sin_psi, ox, oy, cos_h, sin_h, circle_offsets_m, a, b)[1]
    d = circle_offsets_m[best]
    cx = px + d * cos_psi
    cy = py + d * sin_psi
    now_dx = ego_states[0, 0] + d - predicted_others[0, j, 0]
    now_dy = ego_states[0, 1] - predicted_others[0, j, 1]
    _direction_normal(cx - ox, cy - oy, now_dx, now_dy, heading, a, b, normal)
    c_x = normal[0]
    c_y = normal[1]
    c_psi = d * (-normal[0] * sin_psi + normal[1] * cos_psi)
    normal_longitudinal = cos_h * normal[0] + sin_h * normal[1]
    normal_lateral = -sin_h * normal[0] + cos_h * normal[1]
    safety_support = np.sqrt((safety_semi_axes_m[0] * normal_longitudinal) ** 2
                             + (safety_semi_axes_m[1] * normal_lateral) ** 2)
    coefficients[k, j, 0] = c_x
    coefficients[k, j, 1] = c_y
    coefficients[k, j, 2] = c_psi
    row_lower[k, j] = (safety_support - (normal[0] * (cx - ox) + normal[1] * (cy - oy))
                       + c_x * px + c_y * py + c_psi * psi)
    safety_slack_upper[k, j] = max(safety_support - 1.0, 0.0)
    critical_circle[k, j] = best


@numba.njit(cache=True)
def linearize_collision_constraints(
    ego_states,
    predicted_others,
    n_valid_others,
    circle_offsets_m,
    collision_semi_axes_m,
    safety_semi_axes_m,
    coefficients,
    row_lower,
    safety_slack_upper,
    critical_circle,
):
    """Fill one linearized collision/safety row per stage k = 1..N and vehicle slot j.

    Args:
        ego_states: (N + 1, 4) linearization states x^r_k (stage 0 = measured state).
        predicted_others: (N + 1, V_obs, 4) predicted other vehicles, V_obs <= V.
        n_valid_others: number of observed vehicles (slots >= it are empty).
        circle_offsets_m: (C,) circle offsets d_c [m].
        collision_semi_axes_m, safety_semi_axes_m: (2,) arrays (a, b), (a', b') [m].
        coefficients: out (N, V, 3) coefficients on (x, y, psi) of x_k.
        row_lower: out (N, V) row lower bounds (slacks enter with coefficient 1).
        safety_slack_upper: out (N, V) upper bounds h'(n) - 1 of the safety slacks.
        critical_circle: out (N, V) index of the circle kept.

    Empty slots get zero coefficients and zero bounds, i.e. the row reads s_j + sigma_kj >= 0.
    """
    normal = np.empty(2)
    for k in range(coefficients.shape[0]):
        for j in range(coefficients.shape[1]):
            if j >= n_valid_others:
                _empty_row(k, j, coefficients, row_lower, safety_slack_upper, critical_circle)
            else:
                _vehicle_row(k, j, ego_states, predicted_others, circle_offsets_m, collision_semi_axes_m,
                             safety_semi_axes_m, normal, coefficients, row_lower, safety_slack_upper,
                             critical_circle)


def collision_norms(
    ego_states: np.ndarray, predicted_others: np.ndarray, circle_offsets: np.ndarray,
    semi_axes: tuple[float, float],
) -> np.ndarray:
    """Exact (nonlinear) ellipse norms g for every stage, vehicle and circle: (K, V, C).

    ``ego_states`` (K, 4) and ``predicted_others`` (K, V, 4) share the stage axis.
    """
    ego_states = np.asarray(ego_states, dtype=np.float64)
    predicted_others = np.asarray(predicted_others, dtype=np.float64)
    offsets = np.asarray(circle_offsets, dtype=np.float64)
    cx = ego_states[:, None, 0] + offsets[None, :] * np.cos(ego_states[:, None, 2])
    cy = ego_states[:, None, 1] + offsets[None, :] * np.sin(ego_states[:, None, 2])
    dx = cx[:, None, :] - predicted_others[:, :, None, 0]
    dy = cy[:, None, :] - predicted_others[:, :, None, 1]
    heading = predicted_others[:, :, None, 2]
    longitudinal = np.cos(heading) * dx + np.sin(heading) * dy
    lateral = -np.sin(heading) * dx + np.cos(heading) * dy
    return np.sqrt((longitudinal / semi_axes[0]) ** 2 + (lateral / semi_axes[1]) ** 2)
