"""Statistics of the scenario's initial scenes (spawn gaps, speeds, lanes), measured over resets."""

from __future__ import annotations

import numpy as np

from srmpc.scenario.highway import SrmpcHighwayEnv
from srmpc.scenario.observation import closest_lane


def spawn_statistics(env: SrmpcHighwayEnv, seeds: range) -> dict[str, float]:
    """Reset ``env`` with each seed and measure the initial scene.

    The spawn gap is the longitudinal distance between successively spawned vehicles (road order,
    the ego included), the quantity the paper gives as ~25 m (light) and ~15 m (dense).
    """
    gaps, other_speeds, ego_speeds, lanes, behind, ahead = [], [], [], [], [], []
    for seed in seeds:
        env.reset(seed=seed)
        xs = np.array([v.position[0] for v in env.road.vehicles])
        gaps.append(np.diff(xs))
        others = env.measurement.others
        other_speeds.append(others[:, 3])
        ego_speeds.append(env.measurement.ego[3])
        lanes.append([closest_lane(y) for y in others[:, 1]])
        behind.append(np.sum(others[:, 0] < env.measurement.ego[0]))
        ahead.append(np.sum(others[:, 0] > env.measurement.ego[0]))
    gaps = np.concatenate(gaps)
    lane_counts = np.bincount(np.concatenate(lanes), minlength=3)
    return {
        "resets": len(seeds),
        "vehicles": int(env.params.vehicles_count),
        "spawn_gap_mean_m": float(gaps.mean()),
        "spawn_gap_std_m": float(gaps.std()),
        "spawn_gap_min_m": float(gaps.min()),
        "spawn_gap_max_m": float(gaps.max()),
        "other_speed_mean_mps": float(np.concatenate(other_speeds).mean()),
        "ego_speed_mean_mps": float(np.mean(ego_speeds)),
        "lane_share": [float(c) for c in lane_counts / lane_counts.sum()],
        "vehicles_behind_ego_mean": float(np.mean(behind)),
        "vehicles_ahead_of_ego_mean": float(np.mean(ahead)),
    }
