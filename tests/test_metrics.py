"""Episode and aggregate metrics on hand-made traces."""

import pytest

from srmpc.metrics import aggregate_metrics, episode_metrics


def test_episode_metrics_of_a_collision_episode():
    m = episode_metrics([-1.0, -2.0, -3.0], [0.0, 0.0, 1.0], [20.0, 22.0, 24.0], [-0.1, 0.2, 0.5])
    assert (m.episode_return, m.event_cost, m.n_steps, m.mean_vx) == (-6.0, 1.0, 3, 22.0)
    assert m.si_cost_return == pytest.approx(0.6)


def test_aggregate_metrics_cost_rate_is_total_events_over_total_steps():
    crash = episode_metrics([-1.0] * 100, [0.0] * 99 + [1.0], [20.0] * 100)
    safe = episode_metrics([-2.0] * 400, [0.0] * 400, [25.0] * 400)
    agg = aggregate_metrics([crash, safe])
    assert agg.mean_event_cost == 0.5
    assert agg.cost_rate == pytest.approx(1 / 500)
    assert agg.mean_n_steps == 250
    assert agg.mean_return == pytest.approx((-100 - 800) / 2)
    assert agg.mean_return_per_step == pytest.approx(-1.5)
    assert agg.mean_vx == pytest.approx(22.5)


@pytest.mark.parametrize(
    ("event_costs", "message"),
    [([0.0, 0.5], "0 or 1"), ([1.0, 0.0], "before the last step"), ([0.0], "differ in length")],
)
def test_invalid_traces_are_rejected(event_costs, message):
    with pytest.raises(ValueError, match=message):
        episode_metrics([-1.0, -1.0], event_costs, [20.0, 20.0])
