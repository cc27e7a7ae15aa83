"""Closed-loop evaluation: run a controller for episodes of the scenario, collect the metrics."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import gymnasium

from srmpc.controllers import Controller
from srmpc.metrics import EpisodeMetrics, episode_metrics


@dataclass(frozen=True)
class EpisodeRecord:
    """One evaluated episode."""

    episode: int
    seed: int
    metrics: EpisodeMetrics
    termination: str
    """"collision", "offroad" or "truncated"."""
    outcomes: dict[str, int] = field(default_factory=dict)
    """Steps per controller outcome (e.g. a planner's solved / fallback counts)."""


def run_episode(env: gymnasium.Env, controller: Controller, seed: int) -> tuple[EpisodeMetrics, str, dict[str, int]]:
    """One episode from ``env.reset(seed=seed)`` until termination or truncation."""
    observation, _ = env.reset(seed=seed)
    controller.reset()
    scenario = env.unwrapped
    reward_primes, event_costs, vxs, si_costs = [], [], [], []
    while True:
        observation, _, terminated, truncated, info = env.step(controller.act(observation, scenario.measurement))
        reward_primes.append(info["reward_prime"])
        event_costs.append(info["event_cost"])
        vxs.append(info["vx"])
        si_costs.append(info["cost"])
        if terminated or truncated:
            reason = info["termination"] if terminated else "truncated"
            metrics = episode_metrics(reward_primes, event_costs, vxs, si_costs)
            return metrics, reason, controller.episode_outcomes()


def evaluate(
    env: gymnasium.Env,
    controller: Controller,
    episodes: int,
    seed: int,
    on_episode: Callable[[EpisodeRecord], None] | None = None,
    first_episode: int = 0,
) -> list[EpisodeRecord]:
    """Episodes ``first_episode .. episodes-1``, episode i seeded with ``seed + i``."""
    records = []
    for episode in range(first_episode, episodes):
        metrics, reason, outcomes = run_episode(env, controller, seed + episode)
        record = EpisodeRecord(episode, seed + episode, metrics, reason, outcomes)
        records.append(record)
        if on_episode is not None:
            on_episode(record)
    return records
