"""How much of SRMPC's rollout could a provably exact pruning skip? An upper bound, on closed-loop scenes.

    python benchmarks/rollout_pruning_bound.py [--episodes 10] [--out results/benchmarks/rollout_pruning_bound.json]

The twin's other vehicles keep their lanes (IDM, lane changes off: ``srmpc/sim/idm.py``) and follow their
leader at any distance, so a vehicle ahead of anything the rollout depends on always changes its followers'
floats: none can be skipped bit-exactly. A vehicle *behind* the ego can be skipped only if, over the whole
horizon T (25 control steps, 5 s), it can neither enter the policy's observation (the closest vehicle per lane
and direction within the perception range R: ``srmpc/scenario/observation.py``), nor touch a vehicle that is
simulated. Two necessary conditions, each an upper bound on what any exact rule could skip:

1. ``beyond_perception``: the vehicle is more than R behind the ego now (a vehicle within R may be observed at
   the first step already);
2. ``beyond_reach``: it stays more than R + 2 r (r = 2.69 m: the half-diagonal of a 5 m x 2 m vehicle) behind the
   ego even if it drives at its speed bound max(v, v0) (an IDM vehicle never exceeds the larger of its speed and
   its target speed v0) while the ego brakes straight at the action box's -5 m/s^2:
   x_ego - x_j > R + 2 r + max_{t <= T} [(max(v_j, v0_j) - v_ego) t + 2.5 t^2].
   A sound rule must also cover the ego turning and reversing (the rollout keeps simulating a terminated ego) and
   vehicles between the skipped one and the ego, so it skips at most this many;
3. ``beyond_sound_reach``: what a rule that is exact in every case may skip. The twin clips every speed to
   highway-env's [MIN_SPEED, MAX_SPEED] = [-40, 40] m/s and bounds no heading over 5 s (a vehicle braking
   behind a close leader can reverse; an IDM vehicle's speed bound max(v, v0) holds only while it drives
   forward), so the ego and the vehicle may close in at up to 80 m/s:
   x_ego - x_j > R + 2 r + 2 * 40 m/s * T.

Scenes: every control step of ``--episodes`` closed-loop episodes per traffic level driven by the paper's SRMPC
(the committed config, seeds ``1000 e`` / ``1000 e + 1`` as the latency benchmarks). Writes the share of other
vehicles meeting each condition (mean over scenes, and by episode time), and the implied ceiling on the
rollout's saving: the twin's step is at least linear in the vehicle count (IDM leader search, collisions), so
skipping a share f of the vehicles saves at most about f of the rollout's simulation time.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np

from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import build_controller
from srmpc.output_folder import atomic_write_text
from srmpc.sim.constants import MAX_SPEED, MIN_SPEED
from srmpc.sim.single_env import TwinScenarioEnv

OUTPUT = Path("results/benchmarks/rollout_pruning_bound.json")
HORIZON_S = 5.0
"""SRMPC's rollout horizon: 25 control steps at 5 Hz [s]."""
EGO_BRAKE_MPS2 = 5.0
"""The action box's strongest braking [m/s^2]."""
SPEED_LIMIT_MPS = max(MAX_SPEED, -MIN_SPEED)
"""The twin's speed clip (highway-env's Vehicle.MAX_SPEED and MIN_SPEED) [m/s]."""
VEHICLE_HALF_DIAGONAL_M = float(np.hypot(2.5, 1.0))
"""Half-diagonal of a 5 m x 2 m vehicle [m]: two vehicles farther apart than twice this cannot touch."""


def worst_case_closing_m(ego_speed: np.ndarray, other_speed_bound: np.ndarray) -> np.ndarray:
    """max_{0 <= t <= T} [(v_bound - v_ego) t + EGO_BRAKE t^2 / 2] [m] (convex in t: the max is at an end)."""
    at_end = (other_speed_bound - ego_speed) * HORIZON_S + 0.5 * EGO_BRAKE_MPS2 * HORIZON_S**2
    return np.maximum(at_end, 0.0)


def measure(traffic: str, episodes: int) -> dict:
    config = to_objects(compose_config([f"+experiment={traffic}_traffic", "tracking.enabled=false",
                                        "controller=srmpc"]))
    env = TwinScenarioEnv(config.scenario)
    controller = build_controller(config, env)
    perception_m = config.scenario.perception_range_m
    beyond_perception, beyond_reach, beyond_sound_reach, by_time = [], [], [], {}
    for episode in range(episodes):
        observation, _ = env.reset(seed=1000 * episode + (traffic == "dense"))
        controller.reset()
        for step in range(config.scenario.episode_steps):
            state = env.simulator.state
            vehicles = state.vehicles[0]
            ego, others = vehicles[-1], vehicles[:-1]
            behind_m = ego[0] - others[:, 0]
            speed_bound = np.maximum(others[:, 3], state.target_speed[0, :-1])
            reach_m = perception_m + 2 * VEHICLE_HALF_DIAGONAL_M + worst_case_closing_m(ego[3], speed_bound)
            beyond_perception.append(float(np.mean(behind_m > perception_m)))
            beyond_reach.append(float(np.mean(behind_m > reach_m)))
            beyond_sound_reach.append(float(np.mean(behind_m > perception_m + 2 * VEHICLE_HALF_DIAGONAL_M
                                                    + 2 * SPEED_LIMIT_MPS * HORIZON_S)))
            by_time.setdefault(step // 50, []).append(beyond_reach[-1])
            action = controller.act(observation, env.measurement)
            observation, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
    return {
        "scenes": len(beyond_reach),
        "others_per_scene": int(config.scenario.vehicles_count),
        "beyond_perception_share_mean": float(np.mean(beyond_perception)),
        "beyond_reach_share_mean": float(np.mean(beyond_reach)),
        "beyond_reach_share_max": float(np.max(beyond_reach)),
        "beyond_sound_reach_share_mean": float(np.mean(beyond_sound_reach)),
        "beyond_sound_reach_share_max": float(np.max(beyond_sound_reach)),
        "beyond_reach_share_by_10s_of_episode": {f"{10 * k}-{10 * (k + 1)} s": float(np.mean(v))
                                                  for k, v in sorted(by_time.items())},
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10, help="closed-loop episodes per traffic level")
    parser.add_argument("--out", type=Path, default=OUTPUT)
    args = parser.parse_args()
    start = time.perf_counter()
    traffic = {name: measure(name, args.episodes) for name in ("light", "dense")}
    ceiling = max(t["beyond_reach_share_mean"] for t in traffic.values())
    record = {
        "traffic": traffic,
        "rollout_saving_ceiling_share": ceiling,
        "note": "beyond_reach: the most any exact pruning could skip in practice; beyond_sound_reach: what a rule "
                "exact in every case may skip (module doc)",
        "horizon_s": HORIZON_S,
        "episodes": args.episodes,
        "wall_s": time.perf_counter() - start,
        "machine": platform.machine(),
        "measured_at": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    atomic_write_text(args.out, json.dumps(record, indent=1) + "\n")
    print(json.dumps(record, indent=1))


if __name__ == "__main__":
    main()
