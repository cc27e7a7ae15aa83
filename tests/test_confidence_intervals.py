"""The statistics the reports set beside the paper's: J_r per step as a ratio of means, paired ratios, rate ratios."""

import math

import numpy as np
import pandas as pd
import pytest
from scipy.stats import binom

from srmpc.confidence_intervals import paired_ratios, rate_ratio_interval, table_metrics_with_intervals


def _episodes(returns, steps, events=None, seeds=None):
    n = len(returns)
    return pd.DataFrame({"seed": seeds if seeds is not None else range(n), "episode_return": returns,
                         "n_steps": steps, "event_cost": events if events is not None else [0.0] * n,
                         "mean_vx": [20.0] * n})


def test_return_per_step_is_the_ratio_of_means_as_in_the_paper():
    # one long episode and one short crash: the mean of ratios and the ratio of means differ by a factor ~3
    row = table_metrics_with_intervals(_episodes([-2000.0, -482.0], [400, 88], [0.0, 1.0]), 500, 0)
    assert row["return_per_step"] == pytest.approx((-2000.0 - 482.0) / (400 + 88))  # -5.09: the paper's -5.1
    assert row["mean_return_per_step"] == pytest.approx((-2000.0 / 400 - 482.0 / 88) / 2)  # -5.24
    assert row["return_per_step"] != pytest.approx(row["mean_return_per_step"])
    low, high = row["return_per_step_ci95"]
    assert -482.0 / 88 <= low <= row["return_per_step"] <= high <= -2000.0 / 400  # between the two episodes


def test_return_per_step_interval_brackets_the_estimate_on_many_episodes():
    rng = np.random.default_rng(3)
    steps = rng.integers(50, 401, size=400)
    returns = -4.0 * steps + rng.normal(0.0, 300.0, size=400)
    row = table_metrics_with_intervals(_episodes(returns, steps), 2000, 0)
    low, high = row["return_per_step_ci95"]
    assert low < row["return_per_step"] < high and high - low < 0.5


def test_paired_ratios_of_event_shares_and_rates():
    a = _episodes([0.0] * 1000, [400] * 1000, [1.0 if i % 500 == 0 else 0.0 for i in range(1000)])
    b = _episodes([0.0] * 1000, [200] * 1000, [1.0 if i % 20 == 0 else 0.0 for i in range(1000)])
    r = paired_ratios(a, b, 2000, 0)
    assert r["mean_event_cost"]["ratio"] == pytest.approx(2 / 50)
    assert r["cost_rate"]["ratio"] == pytest.approx((2 / 400_000) / (50 / 200_000))
    low, high = r["mean_event_cost"]["ratio_ci95"]
    assert low == 0.0 < r["mean_event_cost"]["ratio"] < high < 0.2  # 2 events: the lower end touches 0


def test_a_ratio_over_a_vanishing_denominator_has_no_upper_bound():
    a = _episodes([0.0] * 100, [100] * 100, [1.0] * 3 + [0.0] * 97)
    b = _episodes([0.0] * 100, [100] * 100, [1.0] + [0.0] * 99)  # one event: most resamples keep it, some lose it
    r = paired_ratios(a, b, 2000, 0)
    assert r["mean_event_cost"]["ratio"] == pytest.approx(3.0)
    assert r["mean_event_cost"]["ratio_ci95"][1] == math.inf
    none = paired_ratios(a, _episodes([0.0] * 100, [100] * 100), 200, 0)
    assert none["mean_event_cost"]["ratio"] is None and none["cost_rate"]["ratio_ci95"][1] == math.inf


@pytest.mark.parametrize(("k_a", "t_a", "k_b", "t_b"), [(10, 1e3, 20, 1e3), (33, 9.2e5, 68, 9.3e5), (3, 5e4, 40, 8e4)])
def test_rate_ratio_interval_is_exact_at_its_ends(k_a, t_a, k_b, t_b):
    low, high = rate_ratio_interval(k_a, t_a, k_b, t_b)
    assert low < (k_a / t_a) / (k_b / t_b) < high
    n = k_a + k_b
    p = lambda ratio: ratio * t_a / (ratio * t_a + t_b)  # noqa: E731  (share of events from a at a rate ratio)
    assert binom.sf(k_a - 1, n, p(low)) == pytest.approx(0.025, rel=1e-6)  # P(K >= k_a) at the lower end
    assert binom.cdf(k_a, n, p(high)) == pytest.approx(0.025, rel=1e-6)  # P(K <= k_a) at the upper end


def test_rate_ratio_interval_edges():
    assert rate_ratio_interval(0, 100.0, 5, 100.0)[0] == 0.0
    assert rate_ratio_interval(5, 100.0, 0, 100.0)[1] == math.inf
    with pytest.raises(ValueError, match="steps"):
        rate_ratio_interval(1, 0.0, 1, 1.0)
