"""The paper's evaluation metrics (section "Metrics"), as pure functions of step traces.

Per episode: J_r = sum of r', J_c in {0, 1} (1 if the episode ended in a collision or road exit),
n_steps = control steps taken, mean v_x. Over many episodes: the means of those, and the cost rate
rho_c = total event cost / total steps.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class EpisodeMetrics:
    """Metrics of one episode."""

    episode_return: float
    """J_r: sum of the paper's reward r' over the episode."""
    event_cost: float
    """J_c: 1.0 if the episode ended in a collision or a road exit, else 0.0."""
    n_steps: int
    """Control steps taken."""
    mean_vx: float
    """Mean longitudinal speed over the steps [m/s]."""
    si_cost_return: float
    """Sum of the safety-index cost c (the CMDP's cost, not a paper table metric)."""

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def episode_metrics(
    reward_primes: Sequence[float], event_costs: Sequence[float], vxs: Sequence[float],
    si_costs: Sequence[float] | None = None,
) -> EpisodeMetrics:
    """Metrics of one episode from its per-step traces (one entry per control step)."""
    n_steps = len(reward_primes)
    if len(event_costs) != n_steps or len(vxs) != n_steps:
        raise ValueError(
            f"traces differ in length: reward_primes {n_steps}, event_costs {len(event_costs)}, vxs {len(vxs)}"
        )
    if n_steps == 0:
        raise ValueError("an episode needs at least one step")
    event = np.asarray(event_costs, dtype=np.float64)
    if np.any((event != 0.0) & (event != 1.0)):
        raise ValueError(f"event costs must be 0 or 1, got {sorted(set(event.tolist()))}")
    if np.any(event[:-1] != 0.0):
        raise ValueError("an event cost before the last step: episodes terminate on collision or road exit")
    return EpisodeMetrics(
        episode_return=float(np.sum(reward_primes)),
        event_cost=float(event[-1]),
        n_steps=n_steps,
        mean_vx=float(np.mean(vxs)),
        si_cost_return=float(np.sum(si_costs)) if si_costs is not None else 0.0,
    )


@dataclass(frozen=True)
class AggregateMetrics:
    """The paper's table row: means over episodes and the cost rate."""

    episodes: int
    mean_return: float
    """mean J_r."""
    mean_return_per_step: float
    """mean over episodes of J_r / n_steps: a mean of ratios, not the paper's "J_r per step", which is mean J_r /
    mean n_steps (``srmpc.confidence_intervals``' ``return_per_step``, printed beside the paper's numbers)."""
    mean_event_cost: float
    """mean J_c: the share of episodes that ended in a collision or road exit."""
    cost_rate: float
    """rho_c = total event cost / total steps."""
    mean_n_steps: float
    mean_vx: float
    """mean over episodes of each episode's mean v_x [m/s]."""
    mean_si_cost_return: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def aggregate_metrics(episodes: Sequence[EpisodeMetrics]) -> AggregateMetrics:
    """Table metrics over episodes."""
    if not episodes:
        raise ValueError("no episodes to aggregate")
    returns = np.array([e.episode_return for e in episodes])
    steps = np.array([e.n_steps for e in episodes], dtype=np.float64)
    events = np.array([e.event_cost for e in episodes])
    return AggregateMetrics(
        episodes=len(episodes),
        mean_return=float(returns.mean()),
        mean_return_per_step=float(np.mean(returns / steps)),
        mean_event_cost=float(events.mean()),
        cost_rate=float(events.sum() / steps.sum()),
        mean_n_steps=float(steps.mean()),
        mean_vx=float(np.mean([e.mean_vx for e in episodes])),
        mean_si_cost_return=float(np.mean([e.si_cost_return for e in episodes])),
    )
