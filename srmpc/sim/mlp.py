"""The actor as SRMPC sees it: a tanh MLP from the normalized observation to a physical action.

Layers follow ``torch.nn.Linear``'s convention, ``weights[i]`` of shape (out, in) and
``biases[i]`` of shape (out,): h_0 = o, h_{i+1} = tanh(W_i h_i + b_i) for hidden layers, and
z = W_L h_L + b_L for the last. The action is the first two outputs (delta, a) (a TorchRL
``NormalParamExtractor`` head puts the mean first), either used as is (``squash=False``) or
squashed into the action box like a ``TanhNormal``'s mode (``squash=True``):

    action = low + (tanh(z) + 1) / 2 * (high - low).

The environment clips actions to the box in both cases. :class:`MlpPolicy` evaluates it in numpy
on (B, 30) float32 observations; :func:`mlp_action` is the same network inside numba kernels.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numba import njit


class MlpPolicy:
    """Callable policy: (B, 30) float32 normalized observations -> (B, 2) float64 physical actions."""

    def __init__(
        self,
        weights: Sequence[np.ndarray],
        biases: Sequence[np.ndarray],
        action_low: Sequence[float] = (-0.1, -5.0),
        action_high: Sequence[float] = (0.1, 5.0),
        squash: bool = False,
    ) -> None:
        if len(weights) != len(biases) or len(weights) < 1:
            raise ValueError("need as many bias vectors as weight matrices, at least one layer")
        self.weights = [np.ascontiguousarray(w, dtype=np.float64) for w in weights]
        self.biases = [np.ascontiguousarray(b, dtype=np.float64).reshape(-1) for b in biases]
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            if w.ndim != 2 or w.shape[0] != b.shape[0]:
                raise ValueError(f"layer {i}: weight {w.shape} and bias {b.shape} do not match (out, in), (out,)")
            if i > 0 and w.shape[1] != self.weights[i - 1].shape[0]:
                previous = self.weights[i - 1].shape[0]
                raise ValueError(f"layer {i}: input size {w.shape[1]} != previous output {previous}")
        if self.weights[-1].shape[0] < 2:
            raise ValueError("the last layer needs at least 2 outputs (delta, a)")
        self.action_low = np.asarray(action_low, dtype=np.float64)
        self.action_high = np.asarray(action_high, dtype=np.float64)
        self.squash = bool(squash)
        self._weights_t = [np.ascontiguousarray(w.T) for w in self.weights]

    @classmethod
    def random(cls, seed: int = 0, hidden: tuple[int, ...] = (64, 64), inputs: int = 30, outputs: int = 2,
               squash: bool = True) -> MlpPolicy:
        """An untrained network with PyTorch's default init U(+-1/sqrt(fan_in)) (tests, benchmarks)."""
        rng = np.random.default_rng(seed)
        sizes = [inputs, *hidden, outputs]
        weights, biases = [], []
        for fan_in, fan_out in zip(sizes[:-1], sizes[1:], strict=True):
            bound = 1.0 / np.sqrt(fan_in)
            weights.append(rng.uniform(-bound, bound, (fan_out, fan_in)))
            biases.append(rng.uniform(-bound, bound, fan_out))
        return cls(weights, biases, squash=squash)

    @classmethod
    def from_torch(cls, module, squash: bool = False, action_low=(-0.1, -5.0), action_high=(0.1, 5.0)) -> MlpPolicy:
        """From a torch module whose ``nn.Linear`` layers, in order, form the MLP (tanh assumed between)."""
        import torch

        layers = [m for m in module.modules() if isinstance(m, torch.nn.Linear)]
        return cls(
            [m.weight.detach().cpu().double().numpy() for m in layers],
            [m.bias.detach().cpu().double().numpy() for m in layers],
            action_low, action_high, squash,
        )

    @property
    def packed(self) -> tuple:
        """(transposed weights tuple, biases tuple, low, high, squash) for :func:`mlp_action`."""
        return tuple(self._weights_t), tuple(self.biases), self.action_low, self.action_high, self.squash

    def __call__(self, observation: np.ndarray) -> np.ndarray:
        hidden = np.asarray(observation, dtype=np.float64).reshape(-1, self.weights[0].shape[1])
        for w_t, b in zip(self._weights_t[:-1], self.biases[:-1], strict=True):
            hidden = np.tanh(hidden @ w_t + b)
        z = (hidden @ self._weights_t[-1] + self.biases[-1])[:, :2]
        if self.squash:
            return self.action_low + (np.tanh(z) + 1.0) / 2.0 * (self.action_high - self.action_low)
        return z


@njit(cache=True, error_model="numpy", inline="always")
def _dense(weight_t: np.ndarray, bias: np.ndarray, x: np.ndarray, out: np.ndarray, activate: bool) -> None:
    """out = act(W x + b) with W given transposed (in, out): the inner loop runs over outputs and
    vectorizes, each output still summing b + W[i, 0] x[0] + W[i, 1] x[1] + ... in that order."""
    outputs = weight_t.shape[1]
    for i in range(outputs):
        out[i] = bias[i]
    for j in range(weight_t.shape[0]):
        xj = np.float64(x[j])
        for i in range(outputs):
            out[i] += weight_t[j, i] * xj
    if activate:
        for i in range(outputs):
            out[i] = np.tanh(out[i])


@njit(cache=True, error_model="numpy")
def mlp_action(
    observation: np.ndarray,
    w0: np.ndarray, b0: np.ndarray, w1: np.ndarray, b1: np.ndarray, w2: np.ndarray, b2: np.ndarray,
    low: np.ndarray, high: np.ndarray, squash: bool,
    h0: np.ndarray, h1: np.ndarray, z: np.ndarray,
) -> tuple[float, float]:
    """(delta, a) of a 2-hidden-layer tanh MLP for one observation (work buffers h0, h1, z).

    ``w0, w1, w2`` are the transposed weights (in, out), see :attr:`MlpPolicy.packed`.
    """
    _dense(w0, b0, observation, h0, True)
    _dense(w1, b1, h0, h1, True)
    _dense(w2, b2, h1, z, False)
    if squash:
        return (
            low[0] + (np.tanh(z[0]) + 1.0) / 2.0 * (high[0] - low[0]),
            low[1] + (np.tanh(z[1]) + 1.0) / 2.0 * (high[1] - low[1]),
        )
    return z[0], z[1]
