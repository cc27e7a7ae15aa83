"""A/B measurement of a policy on fresh episodes: the same resets for every policy compared."""

from __future__ import annotations

import torch
from tensordict.nn import TensorDictModule
from torchrl.envs import EnvBase


@torch.no_grad()
def first_episode_returns(env: EnvBase, policy: TensorDictModule, steps: int, seed: int) -> dict[str, float]:
    """Reset every env of the batch (after ``env.set_seed(seed)``), run ``policy`` for ``steps`` steps
    and score each env's first episode only (steps after its first done are ignored).

    Returns means over the batch of: ``train_return`` (sum of r), ``return`` (sum of r', the paper's
    J_r, up to ``steps``), ``cost_return`` (event costs, J_c), ``steps`` (episode length, capped at
    ``steps``). The policy acts with its default interaction type (outside ``set_exploration_type``:
    TorchRL's deterministic mode, for this actor the squashed mean). The global torch RNG is seeded
    with ``seed`` and restored after.
    """
    rng = torch.get_rng_state()
    torch.manual_seed(seed)
    env.set_seed(seed)
    try:
        data = env.rollout(steps, policy, break_when_any_done=False)
    finally:
        torch.set_rng_state(rng)
    nxt = data.get("next")
    done = nxt.get("done").squeeze(-1).float()  # (B, T)
    alive = ((torch.cumsum(done, dim=-1) - done) == 0).float()  # 1 up to and including the first done

    def episode_sum(key: str) -> float:
        return float((nxt.get(key).squeeze(-1) * alive).sum(-1).mean())

    return {"train_return": episode_sum("reward"), "return": episode_sum("reward_prime"),
            "cost_return": episode_sum("event_cost"), "steps": float(alive.sum(-1).mean())}
