"""TorchRL's ``TanhNormal`` in the action box as plain tensor functions: the same operations, in the
same order, so the same floats and the same gradients (``tests/test_training_equivalence.py``).

With u ~ N(loc, scale) per action dimension, ``TanhNormal(loc, scale, low, high)`` is the law of

    a = c + h tanh(u),   c = (high + low) / 2,  h = (high - low) / 2,

its tanh clamped to +-(1 - eps) (eps = float32 resolution, 1e-6) by TorchRL's "safe" tanh, and

    log pi(a) = sum_i [ log N(u_i; loc_i, scale_i) - log|da_i/du_i| ],
    log|da/du| = 2 (log 2 - u - softplus(-2u)) + log|h|,   u = atanh(clamp((a - c) / h)).

``TanhNormal`` computes these through ``torch.distributions`` objects (a composed tanh and affine
transform over an ``Independent(Normal)``), which validate their arguments and build the transforms
on every call: most of the cost of a (1024, 2) or (8192, 2) call. Here the arithmetic alone runs,
written as ``torch.distributions`` writes it (``Normal.log_prob``, ``TanhTransform`` and
``AffineTransform.log_abs_det_jacobian``, ``TransformedDistribution.log_prob``,
``TanhNormal.rsample_and_log_prob``), including the draw ``torch.empty(shape).normal_()``.
"""

from __future__ import annotations

import math

import torch
from torch.nn.functional import softplus

LOG_2 = math.log(2.0)
LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))
SAFE_TANH_LIMIT = 1.0 - torch.finfo(torch.float32).resolution
"""TorchRL's safe tanh / atanh clamp for float32 (``safetanh_noeps``, ``safeatanh_noeps``)."""


def affine_of_box(low: torch.Tensor, high: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(c, h) of the box as ``TanhNormal.__init__`` computes them: ((high + low) / 2, (high - low) / 2)."""
    return (high + low) / 2, (high - low) / 2


def normal_log_prob(value: torch.Tensor, loc: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """``torch.distributions.Normal(loc, scale).log_prob(value)``, element by element.

    log(scale) is taken on a contiguous copy: the actor's scale is one value per action dimension
    expanded over the batch, whose strided log runs 4x slower; the values and the gradient
    (grad / scale, element by element, passed through the copy) are the same.
    """
    var = scale**2
    return -((value - loc) ** 2) / (2 * var) - scale.contiguous().log() - LOG_SQRT_2PI


def log_abs_det_jacobian(u: torch.Tensor, half_range: torch.Tensor) -> torch.Tensor:
    """log|da/du| per element: the tanh term plus the affine one (``ComposeTransform`` order)."""
    tanh_term = 2.0 * (LOG_2 - u - softplus(-2.0 * u))
    affine_term = torch.abs(half_range).log().expand(u.shape)
    return tanh_term + affine_term


def log_prob(action: torch.Tensor, loc: torch.Tensor, scale: torch.Tensor, center: torch.Tensor,
             half_range: torch.Tensor) -> torch.Tensor:
    """``TanhNormal(loc, scale, low, high).log_prob(action)`` (summed over the last dimension)."""
    u = ((action - center) / half_range).clamp(-SAFE_TANH_LIMIT, SAFE_TANH_LIMIT).atanh()
    result = 0.0 - log_abs_det_jacobian(u, half_range).sum(-1)
    return result + normal_log_prob(u, loc, scale).sum(-1)


NO_SAMPLE_SHAPE = torch.Size()
"""One draw per distribution (torch's default ``sample_shape``)."""


def rsample_and_log_prob(loc: torch.Tensor, scale: torch.Tensor, center: torch.Tensor, half_range: torch.Tensor,
                         sample_shape: torch.Size = NO_SAMPLE_SHAPE) -> tuple[torch.Tensor, torch.Tensor]:
    """``TanhNormal(loc, scale, low, high).rsample_and_log_prob(sample_shape)``: a draw and its log-probability."""
    eps = torch.empty(sample_shape + loc.shape, dtype=loc.dtype, device=loc.device).normal_()
    u = loc + eps * scale
    action = center + half_range * u.tanh().clamp(-SAFE_TANH_LIMIT, SAFE_TANH_LIMIT)
    return action, normal_log_prob(u, loc, scale).sum(-1) - log_abs_det_jacobian(u, half_range).sum(-1)


def actor_box(actor) -> tuple[torch.Tensor, torch.Tensor] | None:
    """(c, h) of a ``ProbabilisticActor`` whose distribution is ``TanhNormal`` with the default
    ``upscale`` / ``tanh_loc`` / ``safe_tanh`` / ``event_dims`` (what ``networks.make_actor`` builds);
    None for any other actor."""
    from torchrl.modules import TanhNormal

    probabilistic = actor.module[-1]
    kwargs = dict(probabilistic.distribution_kwargs)
    if probabilistic.distribution_class is not TanhNormal or set(kwargs) != {"low", "high"}:
        return None
    return affine_of_box(torch.as_tensor(kwargs["low"]), torch.as_tensor(kwargs["high"]))
