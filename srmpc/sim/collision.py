"""highway-env's collisions between vehicles: ``RoadObject.handle_collisions`` for every pair.

For each pair (i, j), i before j in road order, after all vehicles have moved by one integration
step dt:

1. pre-check: skip if |p_j - p_i| > diagonal + v_i dt;
2. separating axes (``utils.are_polygons_intersecting``) on the two rotated LENGTH x WIDTH
   rectangles, along the 4 + 4 edge normals n: the projections [min, max] of the two polygons
   overlap on every axis <=> intersecting; with polygon i's interval extended by
   n . (u_i - u_j) dt, u = v (cos psi, sin psi), they overlap on every axis <=> will_intersect;
3. will_intersect: impact_i = t / 2, impact_j = -t / 2 with t = the minimum overlap times its axis,
   oriented from j to i; a later pair overwrites an earlier one's impact. The impact is applied
   at the next integration step (which marks the vehicle crashed);
4. intersecting: both vehicles are crashed.

Only pairs less than diagonal + max(v) dt apart in x can pass the pre-check, so candidates come
from a sweep over the x-sorted order; they are then processed in road order, as highway-env does.
"""

import numpy as np
from numba import njit

from srmpc.sim.constants import VEHICLE_DIAGONAL, VEHICLE_LENGTH, VEHICLE_WIDTH
from srmpc.sim.state import HEADING, SPEED, X, Y

_CORNERS = np.array(
    [
        [-VEHICLE_LENGTH / 2, -VEHICLE_WIDTH / 2],
        [-VEHICLE_LENGTH / 2, +VEHICLE_WIDTH / 2],
        [+VEHICLE_LENGTH / 2, +VEHICLE_WIDTH / 2],
        [+VEHICLE_LENGTH / 2, -VEHICLE_WIDTH / 2],
    ]
)
"""Rectangle corners in the vehicle frame [m], in highway-env's ``polygon()`` order."""
SWEEP_MARGIN = 1e-6
"""Slack [m] on the sweep bound, so that it never drops a pair the exact pre-check would keep."""


@njit(cache=True, error_model="numpy", inline="always")
def polygon(x: float, y: float, heading: float, out: np.ndarray) -> None:
    """Corners (5, 2) of the rotated rectangle, first corner repeated (``RoadObject.polygon``)."""
    c = np.cos(heading)
    s = np.sin(heading)
    for corner in range(4):
        px = _CORNERS[corner, 0]
        py = _CORNERS[corner, 1]
        out[corner, 0] = (c * px + (-s) * py) + x
        out[corner, 1] = (s * px + c * py) + y
    out[4, 0] = out[0, 0]
    out[4, 1] = out[0, 1]


@njit(cache=True, error_model="numpy", inline="always")
def _project(points: np.ndarray, nx: float, ny: float) -> tuple[float, float]:
    low = points[0, 0] * nx + points[0, 1] * ny
    high = low
    for p in range(1, points.shape[0]):
        projected = points[p, 0] * nx + points[p, 1] * ny
        if projected < low:
            low = projected
        if projected > high:
            high = projected
    return low, high


@njit(cache=True, error_model="numpy", inline="always")
def _interval_distance(min_a: float, max_a: float, min_b: float, max_b: float) -> float:
    """Gap between [min_a, max_a] and [min_b, max_b], negative when they overlap."""
    return min_b - max_a if min_a < min_b else min_a - max_b


@njit(cache=True, error_model="numpy")
def polygons_intersecting(
    a: np.ndarray, b: np.ndarray, displacement_x: float, displacement_y: float
) -> tuple[bool, bool, float, float]:
    """(intersecting, will_intersect, translation x, translation y) of polygons a and b.

    ``displacement`` is u_a dt - u_b dt. Replicates ``utils.are_polygons_intersecting``.
    """
    intersecting = True
    will_intersect = True
    min_distance = np.inf
    axis_x = 0.0
    axis_y = 0.0
    for which in range(2):
        poly = a if which == 0 else b
        for edge in range(4):
            nx = -poly[edge + 1, 1] + poly[edge, 1]
            ny = poly[edge + 1, 0] - poly[edge, 0]
            norm = np.sqrt(nx * nx + ny * ny)
            nx /= norm
            ny /= norm
            min_a, max_a = _project(a, nx, ny)
            min_b, max_b = _project(b, nx, ny)
            if _interval_distance(min_a, max_a, min_b, max_b) > 0:
                intersecting = False
            velocity_projection = nx * displacement_x + ny * displacement_y
            if velocity_projection < 0:
                min_a += velocity_projection
            else:
                max_a += velocity_projection
            distance = _interval_distance(min_a, max_a, min_b, max_b)
            if distance > 0:
                will_intersect = False
            if not intersecting and not will_intersect:
                return False, False, 0.0, 0.0
            if abs(distance) < min_distance:
                min_distance = abs(distance)
                dx = (((a[0, 0] + a[1, 0]) + a[2, 0]) + a[3, 0]) / 4 - (((b[0, 0] + b[1, 0]) + b[2, 0]) + b[3, 0]) / 4
                dy = (((a[0, 1] + a[1, 1]) + a[2, 1]) + a[3, 1]) / 4 - (((b[0, 1] + b[1, 1]) + b[2, 1]) + b[3, 1]) / 4
                if dx * nx + dy * ny > 0:
                    axis_x, axis_y = nx, ny
                else:
                    axis_x, axis_y = -nx, -ny
    if will_intersect:
        return intersecting, True, min_distance * axis_x, min_distance * axis_y
    return intersecting, False, 0.0, 0.0


SIDE_BY_SIDE_MARGIN = 1e-9
"""Relative slack on the lateral gap of :func:`side_by_side_apart` (the SAT's rounding is ~1e-15 m)."""
COORDINATE_LIMIT = 1e6
"""|x|, |y| [m] below which :func:`side_by_side_apart`'s rounding argument holds."""


@njit(cache=True, error_model="numpy", inline="always")
def side_by_side_apart(x_i: float, y_i: float, v_i: float, x_j: float, y_j: float, v_j: float) -> bool:
    """Whether :func:`polygons_intersecting` of two vehicles with heading exactly 0 surely returns
    (False, False), because their lateral gap |y_j - y_i| - WIDTH is positive.

    With heading 0, cos = 1 and sin = 0 exactly, so the second edge normal of polygon a is (0, ~1)
    (nx exactly 0, ny within an ulp of 1), the displacement's y component is exactly 0, and on that
    axis both the static and the extended interval distance are |y_j - y_i| - WIDTH up to a few ulps
    of |y| + 1. Both positive: the SAT returns (False, False) there at the latest, and
    :func:`handle_pair` does nothing. Finite, moderate coordinates and speeds keep that argument
    exact; anything else goes through the SAT.
    """
    if not (abs(x_i) < COORDINATE_LIMIT and abs(x_j) < COORDINATE_LIMIT and abs(y_i) < COORDINATE_LIMIT
            and abs(y_j) < COORDINATE_LIMIT and abs(v_i) < np.inf and abs(v_j) < np.inf):
        return False
    return abs(y_j - y_i) - VEHICLE_WIDTH > SIDE_BY_SIDE_MARGIN * (1.0 + abs(y_i) + abs(y_j))


@njit(cache=True, error_model="numpy", inline="always")
def handle_pair(
    vehicles: np.ndarray,
    crashed: np.ndarray,
    impact: np.ndarray,
    has_impact: np.ndarray,
    i: int,
    j: int,
    dt: float,
    poly_a: np.ndarray,
    poly_b: np.ndarray,
) -> None:
    """``vehicles[i].handle_collisions(vehicles[j], dt)`` (storage indices; i first in road order)."""
    dx = vehicles[j, X] - vehicles[i, X]
    dy = vehicles[j, Y] - vehicles[i, Y]
    if np.sqrt(dx * dx + dy * dy) > (VEHICLE_DIAGONAL + VEHICLE_DIAGONAL) / 2 + vehicles[i, SPEED] * dt:
        return
    if vehicles[i, HEADING] == 0.0 and vehicles[j, HEADING] == 0.0 and side_by_side_apart(
        vehicles[i, X], vehicles[i, Y], vehicles[i, SPEED], vehicles[j, X], vehicles[j, Y], vehicles[j, SPEED]
    ):
        return  # vehicles side by side in their lanes, driving straight: no contact, no impact
    polygon(vehicles[i, X], vehicles[i, Y], vehicles[i, HEADING], poly_a)
    polygon(vehicles[j, X], vehicles[j, Y], vehicles[j, HEADING], poly_b)
    displacement_x = vehicles[i, SPEED] * np.cos(vehicles[i, HEADING]) * dt - vehicles[j, SPEED] * np.cos(
        vehicles[j, HEADING]
    ) * dt
    displacement_y = vehicles[i, SPEED] * np.sin(vehicles[i, HEADING]) * dt - vehicles[j, SPEED] * np.sin(
        vehicles[j, HEADING]
    ) * dt
    intersecting, will_intersect, tx, ty = polygons_intersecting(poly_a, poly_b, displacement_x, displacement_y)
    if will_intersect:
        impact[i, 0] = tx / 2
        impact[i, 1] = ty / 2
        impact[j, 0] = -tx / 2
        impact[j, 1] = -ty / 2
        has_impact[i] = True
        has_impact[j] = True
    if intersecting:
        crashed[i] = True
        crashed[j] = True


@njit(cache=True, error_model="numpy", inline="always")
def handle_collisions(
    vehicles: np.ndarray,
    crashed: np.ndarray,
    impact: np.ndarray,
    has_impact: np.ndarray,
    order: np.ndarray,
    rank: np.ndarray,
    dt: float,
    pair_keys: np.ndarray,
    poly_a: np.ndarray,
    poly_b: np.ndarray,
    pair_first: np.ndarray,
    pair_second: np.ndarray,
) -> None:
    """All pairs of one scene, in road order (``order`` sorted by x; ``rank``: road rank by storage).

    ``pair_keys``, ``pair_first``, ``pair_second`` are work buffers of at least N (N - 1) / 2 + 1
    int64 (the candidate pairs' road-order keys and storage indices, sorted by key).
    """
    n = order.shape[0]
    fastest = 0.0
    for k in range(n):
        fastest = max(fastest, vehicles[k, SPEED])
    bound = VEHICLE_DIAGONAL + fastest * dt + SWEEP_MARGIN
    pairs = 0
    for p in range(n):
        i = order[p]
        for q in range(p + 1, n):
            j = order[q]
            if vehicles[j, X] - vehicles[i, X] > bound:
                break
            first, second = (i, j) if rank[i] < rank[j] else (j, i)
            key = rank[first] * n + rank[second]
            slot = pairs  # insertion sort by key: road order of pairs
            while slot > 0 and pair_keys[slot - 1] > key:
                pair_keys[slot] = pair_keys[slot - 1]
                pair_first[slot] = pair_first[slot - 1]
                pair_second[slot] = pair_second[slot - 1]
                slot -= 1
            pair_keys[slot] = key
            pair_first[slot] = first
            pair_second[slot] = second
            pairs += 1
    for m in range(pairs):
        handle_pair(vehicles, crashed, impact, has_impact, pair_first[m], pair_second[m], dt, poly_a, poly_b)
