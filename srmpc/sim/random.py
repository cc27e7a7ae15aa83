"""One splitmix64 random stream per scene (Steele, Lea & Flood 2014), as numba kernels.

A stream's whole state is one uint64 (``SceneState.rng[b]``), so resets are reproducible per
scene whatever the thread count, and a snapshot carries the stream with the scene.
"""

import numpy as np
from numba import njit

_GOLDEN_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_MIX_1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX_2 = np.uint64(0x94D049BB133111EB)
_TWO_POW_MINUS_53 = 1.0 / 9007199254740992.0
"""2^-53: the spacing of the 53-bit uniform grid on [0, 1)."""


@njit(cache=True, error_model="numpy")
def _mix(z: np.uint64) -> np.uint64:
    """splitmix64's output function (a bijection of uint64)."""
    z = (z ^ (z >> np.uint64(30))) * _MIX_1
    z = (z ^ (z >> np.uint64(27))) * _MIX_2
    return z ^ (z >> np.uint64(31))


@njit(cache=True, error_model="numpy")
def seed_streams(rng: np.ndarray, seed: int, first_scene: int) -> None:
    """rng[i] = mix(mix(seed) + gamma * (first_scene + i + 1)): independent streams per scene."""
    base = _mix(np.uint64(seed) + _GOLDEN_GAMMA)
    for i in range(rng.shape[0]):
        rng[i] = _mix(base + _GOLDEN_GAMMA * np.uint64(first_scene + i + 1))


@njit(cache=True, error_model="numpy")
def uniform(rng: np.ndarray, b: int, low: float, high: float) -> float:
    """Advance scene b's stream; low + (high - low) * U with U on the 53-bit grid of [0, 1)."""
    state = rng[b] + _GOLDEN_GAMMA
    rng[b] = state
    unit = np.float64(_mix(state) >> np.uint64(11)) * _TWO_POW_MINUS_53
    return low + (high - low) * unit


@njit(cache=True, error_model="numpy")
def integer(rng: np.ndarray, b: int, count: int) -> int:
    """Uniform integer in [0, count)."""
    return min(int(uniform(rng, b, 0.0, 1.0) * count), count - 1)
