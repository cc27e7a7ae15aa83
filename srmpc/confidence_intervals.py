"""95% confidence intervals for the paper's table metrics, over evaluation episodes.

- J_c (a share of episodes, each 0 or 1): the Wilson score interval
      (p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n),  z = 1.96,
  which stays inside [0, 1] and is not degenerate at p = 0 (where the normal interval is [0, 0]).
- Every other metric (mean J_r, mean J_r per step, rho_c = sum J_c / sum n_steps, mean n_steps, mean v_x):
  the percentile bootstrap over episodes, resampling whole episodes with replacement.
- Paired differences (method A minus method B on the same seeds, so the same scenes): the percentile
  bootstrap of the mean per-episode difference, resampling episode pairs.
- Over training seeds (few independent runs): the Student-t interval of the mean.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

Z_95 = 1.959963984540054
"""Standard normal quantile of 0.975."""
BOOTSTRAP_RESAMPLES = 2000
"""Resamples of every bootstrap the results report (results/*.md, and the table ``python -m srmpc`` ends with)."""
BOOTSTRAP_SEED = 0
"""Seed of those bootstraps, so an interval is the same wherever it is printed."""


def wilson_interval(successes: float, trials: int, z: float = Z_95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (module doc)."""
    if trials < 1:
        raise ValueError(f"trials={trials}: need at least one")
    p = successes / trials
    denominator = 1.0 + z**2 / trials
    centre = p + z**2 / (2 * trials)
    half_width = z * np.sqrt(p * (1 - p) / trials + z**2 / (4 * trials**2))
    return float(max((centre - half_width) / denominator, 0.0)), float(min((centre + half_width) / denominator, 1.0))


def bootstrap_indices(episodes: int, resamples: int, seed: int) -> np.ndarray:
    """(resamples, episodes) episode indices drawn with replacement."""
    return np.random.default_rng(seed).integers(0, episodes, size=(resamples, episodes))


def percentile_interval(samples: np.ndarray) -> tuple[float, float]:
    low, high = np.percentile(samples, [2.5, 97.5])
    return float(low), float(high)


def table_metrics_with_intervals(episodes: pd.DataFrame, resamples: int, seed: int) -> dict:
    """The table row of an ``episodes.csv`` with a ``<metric>_ci95`` [low, high] next to each metric."""
    returns = episodes["episode_return"].to_numpy(float)
    steps = episodes["n_steps"].to_numpy(float)
    events = episodes["event_cost"].to_numpy(float)
    vx = episodes["mean_vx"].to_numpy(float)
    n = len(episodes)
    index = bootstrap_indices(n, resamples, seed)
    row = {
        "episodes": n,
        "mean_return": float(returns.mean()),
        "mean_return_per_step": float((returns / steps).mean()),
        "mean_event_cost": float(events.mean()),
        "cost_rate": float(events.sum() / steps.sum()),
        "mean_n_steps": float(steps.mean()),
        "mean_vx": float(vx.mean()),
    }
    row["mean_return_ci95"] = percentile_interval(returns[index].mean(axis=1))
    row["mean_return_per_step_ci95"] = percentile_interval((returns / steps)[index].mean(axis=1))
    row["mean_event_cost_ci95"] = wilson_interval(events.sum(), n)
    row["cost_rate_ci95"] = percentile_interval(events[index].sum(axis=1) / steps[index].sum(axis=1))
    row["mean_n_steps_ci95"] = percentile_interval(steps[index].mean(axis=1))
    row["mean_vx_ci95"] = percentile_interval(vx[index].mean(axis=1))
    return row


PAIRED_METRICS = {"episode_return": "mean_return", "event_cost": "mean_event_cost", "n_steps": "mean_n_steps",
                  "mean_vx": "mean_vx"}
"""Per-episode column -> the table metric its mean is."""


def paired_differences(a: pd.DataFrame, b: pd.DataFrame, resamples: int, seed: int) -> dict:
    """Mean of a - b per metric over the episodes both ran from the same seed, with bootstrap CIs."""
    merged = a.merge(b, on="seed", suffixes=("_a", "_b"))
    if merged.empty:
        raise ValueError("no common seeds to pair")
    index = bootstrap_indices(len(merged), resamples, seed)
    result = {"episodes": len(merged)}
    for column, metric in PAIRED_METRICS.items():
        difference = merged[f"{column}_a"].to_numpy(float) - merged[f"{column}_b"].to_numpy(float)
        result[metric] = float(difference.mean())
        result[f"{metric}_ci95"] = percentile_interval(difference[index].mean(axis=1))
    return result


def t_interval(values: list[float], confidence: float = 0.95) -> tuple[float, float]:
    """Student-t interval of the mean of independent runs (e.g. training seeds): mean +- t s / sqrt(n).

    With n = 1 the interval is undefined and (nan, nan) is returned.
    """
    from scipy.stats import t

    sample = np.asarray(values, dtype=float)
    if sample.size < 2:
        return (math.nan, math.nan)
    half = t.ppf(0.5 + confidence / 2.0, sample.size - 1) * sample.std(ddof=1) / math.sqrt(sample.size)
    return (float(sample.mean() - half), float(sample.mean() + half))
