"""A tiny batched constrained task with the simulator's TensorDict contract, for tests and smoke runs.

A point p = (x, y) starts near (-4, 0) and should reach the goal (4, 0); a hazard disk of radius
``HAZARD_RADIUS`` sits at the origin, on the straight path. Actions have the simulator's box
(steering [-0.1, 0.1] -> lateral step, acceleration [-5, 5] -> longitudinal step). Per step:

    r' = -|p - goal|^2 / 4,  r = exp(r' / 10) in (0, 1]
    phi(s) = SAFE_RADIUS - |p|  (> 0 inside the unsafe disk), c = max(phi(s') - max(phi(s) - eta, 0), -0.1)
    event_cost = 1 and termination when |p| < HAZARD_RADIUS (collision) or |p|_inf > 6 (road exit)
    truncation after ``MAX_STEPS`` steps.

Keys match srmpc.sim.torchrl_env.TwinHighwayEnv: "observation" (B, 30), "action" (B, 2); in "next":
"reward", "cost", "reward_prime", "event_cost", "vx" (B, 1), "done"/"terminated"/"truncated".
``runtime_state`` / ``load_runtime_state`` expose the full simulator state (positions, step counters
and the generator), which the trainer checkpoints so that a resume continues the same episodes.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Composite, Unbounded
from torchrl.envs import EnvBase

OBSERVATION_DIM = 30
GOAL = (4.0, 0.0)
HAZARD_RADIUS = 1.0
SAFE_RADIUS = 1.8
ETA = 0.05
MAX_STEPS = 50
DT = 0.2


class ToyConstrainedEnv(EnvBase):
    """Batched point-mass task with a hazard disk; see the module docstring."""

    max_steps = MAX_STEPS

    def __init__(self, num_envs: int, seed: int = 0, device: str = "cpu") -> None:
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        b = num_envs
        scalar = Unbounded(shape=(b, 1), dtype=torch.float32)
        self.observation_spec = Composite(
            observation=Unbounded(shape=(b, OBSERVATION_DIM), dtype=torch.float32),
            cost=scalar.clone(), reward_prime=scalar.clone(), event_cost=scalar.clone(), vx=scalar.clone(),
            shape=(b,),
        )
        self.action_spec = Bounded(low=torch.tensor([-0.1, -5.0]).expand(b, 2),
                                   high=torch.tensor([0.1, 5.0]).expand(b, 2), shape=(b, 2))
        self.reward_spec = Unbounded(shape=(b, 1))
        self.done_spec = Composite(
            done=Bounded(0, 1, shape=(b, 1), dtype=torch.bool),
            terminated=Bounded(0, 1, shape=(b, 1), dtype=torch.bool),
            truncated=Bounded(0, 1, shape=(b, 1), dtype=torch.bool),
            shape=(b,),
        )
        self.generator = torch.Generator().manual_seed(seed)
        self.position = torch.zeros(b, 2)
        self.steps = torch.zeros(b, dtype=torch.long)
        self._goal = torch.tensor(GOAL)

    def runtime_state(self) -> dict:
        return {"position": self.position.clone(), "steps": self.steps.clone(), "generator": self.generator.get_state()}

    def load_runtime_state(self, state: dict) -> None:
        self.position.copy_(state["position"])
        self.steps.copy_(state["steps"])
        self.generator.set_state(state["generator"])

    def _set_seed(self, seed: int | None) -> None:
        self.generator.manual_seed(0 if seed is None else seed)

    def _observation(self) -> torch.Tensor:
        obs = torch.zeros(self.batch_size[0], OBSERVATION_DIM)
        obs[:, 0:2] = self.position / 5.0
        obs[:, 2:4] = (self.position - self._goal) / 5.0
        obs[:, 4] = self.position.norm(dim=-1) / 5.0
        obs[:, 5] = self.steps.float() / MAX_STEPS
        return obs

    def _phi(self, position: torch.Tensor) -> torch.Tensor:
        return SAFE_RADIUS - position.norm(dim=-1)

    def _reset(self, tensordict: TensorDictBase | None, **kwargs) -> TensorDictBase:
        b = self.batch_size[0]
        mask = torch.ones(b, dtype=torch.bool)
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(b)
        fresh = torch.stack([-4.0 + 0.5 * torch.rand(b, generator=self.generator),
                             0.6 * (torch.rand(b, generator=self.generator) - 0.5)], dim=-1)
        self.position = torch.where(mask[:, None], fresh, self.position)
        self.steps = torch.where(mask, torch.zeros_like(self.steps), self.steps)
        zeros = torch.zeros(b, 1)
        false = torch.zeros(b, 1, dtype=torch.bool)
        return TensorDict({
            "observation": self._observation(), "cost": zeros, "reward_prime": zeros.clone(),
            "event_cost": zeros.clone(), "vx": zeros.clone(), "done": false, "terminated": false.clone(),
            "truncated": false.clone(),
        }, batch_size=self.batch_size)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        action = tensordict.get("action")
        step = torch.stack([action[:, 1] / 5.0, action[:, 0] / 0.1], dim=-1) * 0.5
        phi_before = self._phi(self.position)
        self.position = self.position + step
        self.steps = self.steps + 1
        phi_after = self._phi(self.position)
        cost = torch.clamp(phi_after - torch.clamp(phi_before - ETA, min=0.0), min=-0.1)
        reward_prime = -((self.position - self._goal) ** 2).sum(-1) / 4.0
        collided = self.position.norm(dim=-1) < HAZARD_RADIUS
        left = self.position.abs().amax(dim=-1) > 6.0
        terminated = collided | left
        truncated = (self.steps >= MAX_STEPS) & ~terminated
        return TensorDict({
            "observation": self._observation(),
            "reward": torch.exp(reward_prime / 10.0)[:, None],
            "cost": cost[:, None], "reward_prime": reward_prime[:, None],
            "event_cost": terminated.float()[:, None], "vx": (step[:, 0] / DT)[:, None],
            "done": (terminated | truncated)[:, None], "terminated": terminated[:, None],
            "truncated": truncated[:, None],
        }, batch_size=self.batch_size)
