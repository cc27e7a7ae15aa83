"""A numerics fingerprint: the MD5 of each building block of a training on fixed inputs, so that a CPU that trains
other bytes names the first primitive that differs, not a policy file.

    python -m pipelines.numerics_fingerprint          # this process's fingerprint as JSON (pin it: SRMPC_NUMERICS)

The blocks, in the order a difference propagates (a training's bytes follow from them):

- ``rng``: ATen's random streams (``normal_``, ``uniform_``, ``randperm``) from a seeded generator;
- ``unary``: every elementwise function on a training's path, the rerouted ones (exp, log, tanh, sqrt, erf) and
  ATen's own (atanh, log1p, expm1, softplus, sigmoid, pow, reciprocal);
- ``reductions``: sum, mean, std and the 2-norm over a minibatch (ATen's parallel reductions);
- ``gemm``: ``nn.Linear``'s products at the training's shapes, forward (8192 x 30 @ 30 x 64 + bias, 8192 x 64 @
  64 x 64) and the weight gradients' (64 x 8192 @ 8192 x 64, 64 x 8192 @ 8192 x 30);
- ``qr_orthogonal``: ``linalg.qr`` and ``nn.init.orthogonal_`` of a 64 x 30 weight;
- ``action_distribution``: the TanhNormal's sample, log_prob and entropy proxy (srmpc.agents.tanh_normal);
- ``adam``: one Adam step (``foreach=True``, as srmpc.agents.trainer's) on fixed parameters and gradients;
- ``gae``: TorchRL's generalized advantage estimate on a fixed (64, 32) batch;
- ``twin_step``: ten batched steps of the twin (srmpc.sim.vector_env) from a seeded reset, 16 scenes.

tests/test_numerics_fingerprint.py compares each with the golden fingerprint (tests/data/golden_hashes.json) and
names the first block that differs.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

SHAPES = {"batch": 8192, "observation": 30, "hidden": 64, "action": 2}
"""The training's sizes: minibatch rows, observation size, hidden width, action dimensions."""


def _md5(*arrays) -> str:
    digest = hashlib.md5()
    for array in arrays:
        digest.update(array.detach().contiguous().numpy().tobytes() if hasattr(array, "detach") else
                      array.tobytes())
    return digest.hexdigest()[:16]


def _uniform(shape: tuple[int, ...], seed: int, low: float = -1.0, high: float = 1.0):
    import torch

    generator = torch.Generator().manual_seed(seed)
    return low + (high - low) * torch.rand(shape, generator=generator)


def rng() -> str:
    import torch

    generator = torch.Generator().manual_seed(0)
    return _md5(torch.empty(4099).normal_(generator=generator), torch.empty(4099).uniform_(generator=generator),
                torch.randperm(8192, generator=generator))


def unary() -> str:
    import torch

    x, positive = _uniform((8192, 64), 1, -4.0, 4.0), _uniform((8192, 64), 2, 0.01, 8.0)
    inside = _uniform((8192, 64), 3, -0.99, 0.99)
    return _md5(x.exp(), positive.log(), x.tanh(), positive.sqrt(), x.erf(), inside.atanh(), positive.log1p(),
                x.expm1(), torch.nn.functional.softplus(x), x.sigmoid(), positive.pow(1.5), positive.reciprocal())


def reductions() -> str:
    x = _uniform((SHAPES["batch"], SHAPES["hidden"]), 4)
    return _md5(x.sum(0), x.mean(), x.std(), x.norm(), x.sum())


def gemm() -> str:
    import torch

    b, o, h = SHAPES["batch"], SHAPES["observation"], SHAPES["hidden"]
    observation, hidden = _uniform((b, o), 5), _uniform((b, h), 6)
    w1, w2, bias = _uniform((h, o), 7), _uniform((h, h), 8), _uniform((h,), 9)
    return _md5(torch.nn.functional.linear(observation, w1, bias), hidden @ w2, hidden.t() @ hidden,
                hidden.t() @ observation)


def qr_orthogonal() -> str:
    import torch

    q, r = torch.linalg.qr(_uniform((SHAPES["hidden"], SHAPES["observation"]), 10))
    weight = torch.empty(SHAPES["hidden"], SHAPES["observation"])
    torch.nn.init.orthogonal_(weight, gain=2 ** 0.5, generator=torch.Generator().manual_seed(11))
    return _md5(q, r, weight)


def action_distribution() -> str:
    import torch

    from srmpc.agents.tanh_normal import affine_of_box, log_prob, rsample_and_log_prob

    b, a = SHAPES["batch"], SHAPES["action"]
    loc, scale = _uniform((b, a), 12), _uniform((b, a), 13, 0.05, 1.0)
    center, half_range = affine_of_box(torch.tensor([-5.0, -0.3]), torch.tensor([5.0, 0.3]))
    torch.manual_seed(14)
    action, sample_log_prob = rsample_and_log_prob(loc, scale, center, half_range)
    entropy_proxy = -sample_log_prob.mean()  # the loss's entropy term: TanhNormal has no closed form
    return _md5(action, sample_log_prob, log_prob(action, loc, scale, center, half_range), entropy_proxy)


def adam() -> str:
    import torch

    parameters = [torch.nn.Parameter(_uniform((64, 30), 15)), torch.nn.Parameter(_uniform((64,), 16))]
    optimizer = torch.optim.Adam(parameters, lr=3e-4, eps=1e-5, foreach=True)
    for step in range(3):
        for index, parameter in enumerate(parameters):
            parameter.grad = _uniform(tuple(parameter.shape), 17 + 2 * step + index)
        optimizer.step()
    return _md5(*parameters)


def gae() -> str:
    from torchrl.objectives.value.functional import generalized_advantage_estimate

    shape = (64, 32, 1)
    value, next_value, reward = _uniform(shape, 20), _uniform(shape, 21), _uniform(shape, 22)
    done = _uniform(shape, 23) > 0.9
    terminated = done & (_uniform(shape, 24) > 0.5)
    advantage, target = generalized_advantage_estimate(0.99, 0.95, value, next_value, reward, done=done,
                                                       terminated=terminated, time_dim=1)
    return _md5(advantage, target)


def twin_step() -> str:
    import numpy as np

    from srmpc.scenario.parameters import ScenarioParameters
    from srmpc.sim.vector_env import TwinVectorEnv

    env = TwinVectorEnv(ScenarioParameters(), num_envs=16, seed=25)
    observation, _ = env.reset(seed=25)
    arrays = [np.asarray(observation)]
    actions = np.random.default_rng(26).uniform(-1.0, 1.0, size=(10, 16, SHAPES["action"]))
    for action in actions:
        observation, reward, terminated, truncated, _ = env.step(action.astype(np.float32))
        arrays += [np.asarray(observation), np.asarray(reward), np.asarray(terminated)]
    return _md5(*arrays)


BLOCKS: dict[str, Callable[[], str]] = {
    "rng": rng, "unary": unary, "reductions": reductions, "gemm": gemm, "qr_orthogonal": qr_orthogonal,
    "action_distribution": action_distribution, "adam": adam, "gae": gae, "twin_step": twin_step,
}
"""Each building block and its MD5, in the order a difference propagates."""


def fingerprint() -> dict[str, str]:
    """Every block's MD5 in this process (one torch thread, as a training's default)."""
    import srmpc  # noqa: F401, I001  (the pin first: it may start this process again)
    import torch

    torch.set_num_threads(1)
    return {name: block() for name, block in BLOCKS.items()}


def run_fingerprint(environment: dict[str, str]) -> dict[str, str]:
    """The fingerprint of a fresh process with ``environment`` added (``SRMPC_NUMERICS`` and any caps)."""
    env = {**os.environ, **environment}
    done = subprocess.run([sys.executable, "-m", "pipelines.numerics_fingerprint"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        raise RuntimeError(f"numerics fingerprint {environment}: exit {done.returncode}: {done.stderr[-1500:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    print(json.dumps(fingerprint()))


if __name__ == "__main__":
    main()
