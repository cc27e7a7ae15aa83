"""95% confidence intervals for the paper's table metrics, over evaluation episodes.

- J_c (a share of episodes, each 0 or 1): the Wilson score interval
      (p + z^2/2n -+ z sqrt(p(1-p)/n + z^2/4n^2)) / (1 + z^2/n),  z = 1.96,
  which stays inside [0, 1] and is not degenerate at p = 0 (where the normal interval is [0, 0]).
- Every other metric (mean J_r, J_r per step, rho_c = sum J_c / sum n_steps, mean n_steps, mean v_x):
  the percentile bootstrap over episodes, resampling whole episodes with replacement.
- J_r per step is the paper's statistic, the ratio of means: ``return_per_step`` = mean J_r / mean n_steps
  (each of the paper's six values is its mean J_r divided by its mean n_steps, e.g. light LTV-MPC
  -1241 / 244 = -5.1); its bootstrap resamples episodes and divides the resample's two means. The mean of
  per-episode ratios J_r / n_steps is kept as ``mean_return_per_step`` and printed only under that name.
- Paired differences (method A minus method B on the same seeds, so the same scenes): the percentile
  bootstrap of the mean per-episode difference, resampling episode pairs; for rho_c (a ratio of sums) the
  bootstrap of rho_c(A) - rho_c(B) over the same resampled pairs (``paired_cost_rate_difference``).
- Ratios of two methods' means on the same seeds (e.g. SRMPC's J_c over LTV-MPC's): the percentile bootstrap
  of sum(a) / sum(b) over resampled episode pairs; resamples with sum(b) = 0 count as +inf, so an interval whose
  denominator can vanish has no finite upper bound (``paired_ratios``).
- The ratio of two event rates (events per step) from counts: the exact conditional interval. Given
  k_a + k_b = n events in t_a and t_b steps, k_a ~ Binomial(n, p) with p = r_a t_a / (r_a t_a + r_b t_b); the
  Clopper-Pearson interval [p_lo, p_hi] of p maps to r_a / r_b in [p_lo / (1 - p_lo), p_hi / (1 - p_hi)] t_b / t_a
  (``rate_ratio_interval``).
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
        "return_per_step": float(returns.mean() / steps.mean()),
        "mean_return_per_step": float((returns / steps).mean()),
        "mean_event_cost": float(events.mean()),
        "cost_rate": float(events.sum() / steps.sum()),
        "mean_n_steps": float(steps.mean()),
        "mean_vx": float(vx.mean()),
    }
    row["mean_return_ci95"] = percentile_interval(returns[index].mean(axis=1))
    row["return_per_step_ci95"] = percentile_interval(returns[index].sum(axis=1) / steps[index].sum(axis=1))
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


def paired_cost_rate_difference(a: pd.DataFrame, b: pd.DataFrame, resamples: int, seed: int) -> dict:
    """rho_c(a) - rho_c(b) (rho_c = sum J_c / sum n_steps) over the seeds both ran, with its bootstrap CI."""
    merged = a.merge(b, on="seed", suffixes=("_a", "_b"))
    if merged.empty:
        raise ValueError("no common seeds to pair")
    index = bootstrap_indices(len(merged), resamples, seed)
    events_a, steps_a = merged["event_cost_a"].to_numpy(float), merged["n_steps_a"].to_numpy(float)
    events_b, steps_b = merged["event_cost_b"].to_numpy(float), merged["n_steps_b"].to_numpy(float)
    samples = (events_a[index].sum(axis=1) / steps_a[index].sum(axis=1)
               - events_b[index].sum(axis=1) / steps_b[index].sum(axis=1))
    difference = events_a.sum() / steps_a.sum() - events_b.sum() / steps_b.sum()
    return {"episodes": len(merged), "cost_rate": float(difference), "cost_rate_ci95": percentile_interval(samples)}


def paired_ratios(a: pd.DataFrame, b: pd.DataFrame, resamples: int, seed: int) -> dict:
    """J_c(a) / J_c(b) and rho_c(a) / rho_c(b) over the seeds both ran, with bootstrap CIs (module doc).

    Per metric: ``ratio`` (None when b's value is 0: no finite ratio) and ``ratio_ci95``, whose upper end is +inf
    when b's value can vanish in a resample."""
    merged = a.merge(b, on="seed", suffixes=("_a", "_b"))
    if merged.empty:
        raise ValueError("no common seeds to pair")
    index = bootstrap_indices(len(merged), resamples, seed)

    def column(name: str) -> np.ndarray:
        return merged[name].to_numpy(float)

    rates = {"mean_event_cost": (column("event_cost_a"), np.ones(len(merged)), column("event_cost_b"),
                                 np.ones(len(merged))),
             "cost_rate": (column("event_cost_a"), column("n_steps_a"), column("event_cost_b"), column("n_steps_b"))}
    result: dict = {"episodes": len(merged)}
    for metric, (events_a, steps_a, events_b, steps_b) in rates.items():
        top = events_a[index].sum(axis=1) / steps_a[index].sum(axis=1)
        bottom = events_b[index].sum(axis=1) / steps_b[index].sum(axis=1)
        samples = np.full(resamples, np.inf)
        np.divide(top, bottom, out=samples, where=bottom > 0)
        with np.errstate(invalid="ignore"):  # interpolating towards +inf can give nan: that end is unbounded
            low, high = np.nan_to_num(np.percentile(samples, [2.5, 97.5]), nan=np.inf)
        denominator = events_b.sum() / steps_b.sum()
        result[metric] = {"ratio": float(events_a.sum() / steps_a.sum() / denominator) if denominator else None,
                          "ratio_ci95": (float(low), float(high))}
    return result


def rate_ratio_interval(events_a: int, steps_a: float, events_b: int, steps_b: float,
                        confidence: float = 0.95) -> tuple[float, float]:
    """Exact conditional (Clopper-Pearson) interval of the rate ratio (events_a / steps_a) / (events_b / steps_b).

    The upper end is +inf when events_b = 0, the lower end 0 when events_a = 0 (module doc)."""
    from scipy.stats import beta

    if min(events_a, events_b) < 0 or steps_a <= 0 or steps_b <= 0:
        raise ValueError(f"events ({events_a}, {events_b}) must be >= 0 and steps ({steps_a}, {steps_b}) > 0")
    n, alpha = events_a + events_b, 1.0 - confidence
    if n == 0:
        return (0.0, math.inf)
    p_low = beta.ppf(alpha / 2, events_a, n - events_a + 1) if events_a > 0 else 0.0
    p_high = beta.ppf(1 - alpha / 2, events_a + 1, n - events_a) if events_a < n else 1.0
    scale = steps_b / steps_a
    return (float(p_low / (1 - p_low) * scale), math.inf if p_high >= 1.0 else float(p_high / (1 - p_high) * scale))


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
