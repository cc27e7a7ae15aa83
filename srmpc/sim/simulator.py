""":class:`TwinSimulator`: B scenes of ``srmpc/Highway-v0`` stepped at once (see README, Python API)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

from srmpc.scenario.observation import OBSERVATION_SIZE
from srmpc.scenario.parameters import ScenarioParameters
from srmpc.sim import engine
from srmpc.sim.constants import TERMINATION_REASONS, SimConstants, sim_constants
from srmpc.sim.random import seed_streams
from srmpc.sim.state import SceneState

PARALLEL_MIN_SCENES_PER_THREAD = 8
"""Below this many scenes per thread the serial kernel is faster than waking the thread pool."""


@dataclass
class StepResult:
    """What one batched step returns (arrays of B, copies)."""

    observation: np.ndarray
    """(B, 30) float32 normalized observation; after an auto-reset, the new episode's first."""
    reward: np.ndarray
    """(B,) training reward r = exp(r' / scale)."""
    reward_prime: np.ndarray
    """(B,) evaluation reward r'."""
    cost: np.ndarray
    """(B,) SI cost c."""
    event_cost: np.ndarray
    """(B,) 1.0 on collision or road exit."""
    vx: np.ndarray
    """(B,) ego longitudinal speed [m/s]."""
    terminated: np.ndarray
    """(B,) bool: collision or road exit."""
    truncated: np.ndarray
    """(B,) bool: ``episode_steps`` reached."""
    reason: np.ndarray
    """(B,) int64 code, see :data:`~srmpc.sim.constants.TERMINATION_REASONS`."""
    final_observation: np.ndarray | None = None
    """(B, 30) the step's own observation when auto-reset replaced it, else None."""

    def termination(self, b: int) -> str:
        """``info["termination"]`` of ``SrmpcHighwayEnv`` for scene b: "collision", "offroad" or ""."""
        return TERMINATION_REASONS[int(self.reason[b])]


class TwinSimulator:
    """B independent scenes of the scenario, float64 state, stepped by numba kernels.

    Physically identical to ``SrmpcHighwayEnv`` (see ``tests/test_sim_differential.py``); resets
    draw from the same distributions with the twin's own per-scene random streams.
    """

    def __init__(
        self,
        params: ScenarioParameters,
        scenes: int,
        seed: int = 0,
        threads: int | None = None,
        state: SceneState | None = None,
    ) -> None:
        """``threads``: 1 forces the serial kernel; None uses numba's thread count."""
        if scenes < 1:
            raise ValueError(f"scenes={scenes}: must be >= 1")
        self.params = params
        self.constants: SimConstants = sim_constants(params)
        self.threads = threads
        if state is None:
            self.state = SceneState.empty(scenes, self.constants.vehicles)
            seed_streams(self.state.rng, int(seed), 0)
            self._observation = np.zeros((scenes, OBSERVATION_SIZE), dtype=np.float32)
            engine.reset_scenes(self.state.arrays(), self.constants, np.ones(scenes, dtype=np.bool_), self._observation)
        else:
            if state.vehicle_count != self.constants.vehicles:
                raise ValueError(
                    f"state has {state.vehicle_count} vehicles per scene, params say {self.constants.vehicles}"
                )
            self.state = state
            self._observation = np.zeros((scenes, OBSERVATION_SIZE), dtype=np.float32)
            engine.observe(self.state.arrays(), self.constants, self._observation, np.empty(scenes))
        self._outputs = engine.allocate_outputs(scenes)

    # ----------------------------------------------------------------------- construction
    @classmethod
    def from_highway_env(cls, envs: Sequence, params: ScenarioParameters | None = None, seed: int = 0,
                         threads: int | None = None) -> TwinSimulator:
        """A twin whose scene b is an exact copy of ``envs[b]`` (reset ``SrmpcHighwayEnv`` instances).

        Copies positions, headings, speeds, held actions, crash flags, pending impacts, lanes,
        IDM targets and DELTA, the ego's road rank, the step counter and phi. ``params`` defaults
        to the first env's; if the scenes hold another number of vehicles (hand-built scenes),
        ``vehicles_count`` follows them. Later resets of the twin draw from its own streams (``seed``).
        """
        from srmpc.sim.highway_copy import state_from_highway_envs

        envs = list(envs)
        params = params if params is not None else envs[0].unwrapped.params
        state = state_from_highway_envs(envs)
        others = state.vehicle_count - 1
        if others != params.vehicles_count:  # a hand-built scene: later resets spawn as many vehicles
            params = dataclasses.replace(
                params, vehicles_count=others, vehicles_behind_ego=min(params.vehicles_behind_ego, others)
            )
        seed_streams(state.rng, int(seed), 0)
        return cls(params, len(envs), seed=seed, threads=threads, state=state)

    # ------------------------------------------------------------------------ properties
    @property
    def scenes(self) -> int:
        """B."""
        return self.state.scenes

    @property
    def observation(self) -> np.ndarray:
        """(B, 30) float32 observation of the current states (a copy)."""
        return self._observation.copy()

    def _parallel(self) -> bool:
        threads = numba.get_num_threads() if self.threads is None else self.threads
        return threads > 1 and self.scenes >= PARALLEL_MIN_SCENES_PER_THREAD * threads

    # -------------------------------------------------------------------------- running
    def seed(self, seed: int) -> None:
        """Re-seed every scene's reset stream (scene b gets stream b of ``seed``)."""
        seed_streams(self.state.rng, int(seed), 0)

    def reset(self, mask: np.ndarray | None = None) -> np.ndarray:
        """Spawn new scenes where ``mask`` (B,) is True (all if None); return the (B, 30) observation."""
        mask = np.ones(self.scenes, dtype=np.bool_) if mask is None else np.asarray(mask, dtype=np.bool_).reshape(-1)
        if mask.shape != (self.scenes,):
            raise ValueError(f"mask must have shape ({self.scenes},), got {mask.shape}")
        engine.reset_scenes(self.state.arrays(), self.constants, mask, self._observation)
        return self._observation.copy()

    def step(self, actions: np.ndarray, auto_reset: bool = False) -> StepResult:
        """One control step of every scene with ``actions`` (B, 2) = (delta [rad], a [m/s^2]).

        With ``auto_reset``, scenes that terminate or truncate are respawned in the same call:
        ``observation`` is then the new episode's and ``final_observation`` the step's own.
        """
        actions = np.ascontiguousarray(actions, dtype=np.float64).reshape(self.scenes, 2)
        if not np.isfinite(actions).all():
            raise ValueError("actions must be finite (steering [rad], acceleration [m/s^2])")
        out = self._outputs
        kernel = engine.step_parallel if self._parallel() else engine.step_serial
        kernel(self.state.arrays(), self.constants, out, actions, bool(auto_reset))
        self._observation[...] = out.observation
        return StepResult(
            observation=out.observation.copy(),
            reward=out.reward.copy(),
            reward_prime=out.reward_prime.copy(),
            cost=out.cost.copy(),
            event_cost=out.event_cost.copy(),
            vx=out.vx.copy(),
            terminated=out.terminated.copy(),
            truncated=out.truncated.copy(),
            reason=out.reason.copy(),
            final_observation=out.final_observation.copy() if auto_reset else None,
        )

    def rollout(self, policy, horizon: int, scenes=None, record_others: bool = False):
        """:func:`srmpc.sim.rollout.rollout` of ``policy`` from the current scenes (or ``scenes`` only).

        The simulator's own state is not modified.
        """
        from srmpc.sim.rollout import rollout

        state = self.state if scenes is None else self.state.take(scenes)
        return rollout(state, self.constants, policy, horizon, record_others=record_others)

    # --------------------------------------------------------------------- snapshots
    def snapshot(self) -> SceneState:
        """A copy of the whole state (every scene), to :meth:`restore` later."""
        return self.state.copy()

    def restore(self, snapshot: SceneState, scenes: np.ndarray | list[int] | slice | None = None) -> None:
        """Put ``snapshot``'s scenes back (into ``scenes`` if given); the observation follows."""
        self.state.assign(snapshot, scenes)
        engine.observe(self.state.arrays(), self.constants, self._observation, np.empty(self.scenes))
