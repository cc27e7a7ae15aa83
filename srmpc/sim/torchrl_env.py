""":class:`TwinHighwayEnv`: the twin as a TorchRL ``EnvBase`` with ``batch_size=[B]``.

Keys (all float32 unless said):

- ``"observation"`` (B, 30): the scenario's normalized observation;
- ``"action"`` (B, 2): physical (delta [rad], a [m/s^2]), ``Bounded`` to the scenario's box;
- in ``"next"``: ``"reward"`` (B, 1) training reward r, ``"cost"`` (B, 1) SI cost c,
  ``"reward_prime"`` (B, 1) r', ``"event_cost"`` (B, 1) 1 on collision or road exit,
  ``"vx"`` (B, 1) ego longitudinal speed [m/s], and bool ``"done"``, ``"terminated"``,
  ``"truncated"`` (B, 1).

``cost``, ``reward_prime``, ``event_cost`` and ``vx`` are declared in the observation spec (so
collectors carry them); a reset returns zeros for them. Resets honour TorchRL's partial
``"_reset"`` mask (B, 1): only masked scenes are respawned, the others keep their state.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from srmpc.scenario.observation import OBSERVATION_SIZE
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.sim.simulator import TwinSimulator

INFO_KEYS = ("cost", "reward_prime", "event_cost", "vx")
"""Per-step scalars besides the reward, carried as (B, 1) float32 entries."""


class TwinHighwayEnv(EnvBase):
    """B scenes of ``srmpc/Highway-v0`` in one TorchRL env (numba engine, numpy <-> torch at the edge)."""

    def __init__(self, params: ScenarioParameters, num_envs: int, seed: int, device="cpu",
                 threads: int | None = 1) -> None:
        """``threads``: numba threads for the scenes (1: the serial kernel, the default, which never
        competes with torch's own thread pool; scale across cores with processes instead)."""
        super().__init__(device=device, batch_size=torch.Size([num_envs]))
        self.params = params
        self.num_envs = num_envs
        self.simulator = TwinSimulator(params, num_envs, seed=seed, threads=threads)
        self._done = np.zeros(num_envs, dtype=np.bool_)
        b = num_envs
        self.observation_spec = Composite(
            observation=Unbounded(shape=(b, OBSERVATION_SIZE), dtype=torch.float32, device=self.device),
            **{key: Unbounded(shape=(b, 1), dtype=torch.float32, device=self.device) for key in INFO_KEYS},
            shape=(b,),
            device=self.device,
        )
        self.action_spec = Bounded(
            low=torch.tensor([-params.steering_max_rad, params.acceleration_min_mps2], dtype=torch.float32)
            .expand(b, 2).clone(),
            high=torch.tensor([params.steering_max_rad, params.acceleration_max_mps2], dtype=torch.float32)
            .expand(b, 2).clone(),
            shape=(b, 2),
            dtype=torch.float32,
            device=self.device,
        )
        self.reward_spec = Unbounded(shape=(b, 1), dtype=torch.float32, device=self.device)
        self.done_spec = Composite(
            done=Categorical(2, shape=(b, 1), dtype=torch.bool, device=self.device),
            terminated=Categorical(2, shape=(b, 1), dtype=torch.bool, device=self.device),
            truncated=Categorical(2, shape=(b, 1), dtype=torch.bool, device=self.device),
            shape=(b,),
            device=self.device,
        )

    def _tensor(self, array: np.ndarray, dtype=torch.float32) -> torch.Tensor:
        """A torch copy (never a view: the simulator's arrays are overwritten in place)."""
        return torch.tensor(np.ascontiguousarray(array), dtype=dtype, device=self.device)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(self.num_envs).cpu().numpy()
        observation = self.simulator.reset(mask)
        self._done[mask if mask is not None else slice(None)] = False
        zeros = torch.zeros(self.num_envs, 1, dtype=torch.float32, device=self.device)
        done = self._tensor(self._done.reshape(-1, 1), torch.bool)
        return TensorDict(
            {
                "observation": self._tensor(observation),
                **{key: zeros.clone() for key in INFO_KEYS},
                "done": done,
                "terminated": done.clone(),
                "truncated": torch.zeros_like(done),
            },
            batch_size=self.batch_size,
            device=self.device,
        )

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get("action").detach().cpu().numpy().astype(np.float64)
        result = self.simulator.step(actions)
        self._done = result.terminated | result.truncated

        def column(values: np.ndarray, dtype=torch.float32) -> torch.Tensor:
            return self._tensor(values.reshape(-1, 1), dtype)

        return TensorDict(
            {
                "observation": self._tensor(result.observation),
                "reward": column(result.reward),
                "cost": column(result.cost),
                "reward_prime": column(result.reward_prime),
                "event_cost": column(result.event_cost),
                "vx": column(result.vx),
                "done": column(self._done, torch.bool),
                "terminated": column(result.terminated, torch.bool),
                "truncated": column(result.truncated, torch.bool),
            },
            batch_size=self.batch_size,
            device=self.device,
        )

    def step_and_reset_into(self, action: torch.Tensor, next_out: dict[str, torch.Tensor],
                            observation_out: torch.Tensor) -> None:
        """``step_and_maybe_reset`` written into the caller's tensors, without TensorDicts.

        One step of every scene with ``action`` (B, 2); ``next_out`` gets the step's own "next"
        entries (each a (B, ...) tensor, any strides: "observation", "reward", "done",
        "terminated", "truncated" and :data:`INFO_KEYS`), ``observation_out`` (B, 30) the
        observations to act on next: the new episode's where a scene ended. Scenes are respawned
        in the simulator's step (``auto_reset``), which spawns scene b from its own random stream
        exactly as a partial reset after the step does, so the floats are those of ``step`` then
        ``reset`` with the done mask.
        """
        result = self.simulator.step(action.detach().cpu().numpy().astype(np.float64), auto_reset=True)
        next_out["observation"].copy_(torch.from_numpy(result.final_observation))
        for key in ("reward", *INFO_KEYS):
            next_out[key].copy_(torch.from_numpy(getattr(result, key)).unsqueeze(-1))
        next_out["terminated"].copy_(torch.from_numpy(result.terminated).unsqueeze(-1))
        next_out["truncated"].copy_(torch.from_numpy(result.truncated).unsqueeze(-1))
        next_out["done"].copy_(torch.from_numpy(result.terminated | result.truncated).unsqueeze(-1))
        observation_out.copy_(torch.from_numpy(result.observation))
        self._done[...] = False  # every scene that ended has been respawned

    def _set_seed(self, seed: int | None) -> None:
        self.simulator.seed(0 if seed is None else int(seed))
