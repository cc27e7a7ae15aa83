"""DVC stage: the paper's Fig. rl-trajectory, results/figures/srmpc_trajectory.{png,json}.

Runs SRMPC (the committed config, light traffic, on the twin) from seed 0 on until the policy's rollout
overtakes and SRMPC's QP keeps the overtake: both end at least ``--lane-change-m`` to the left of where
the ego is, while a slower leader drives ahead in the ego's lane. At that step it draws
- left: SRMPC, the policy's rollout (dashed, the linearization reference) and the QP's solution (solid);
- right: the plain LTV-MPC from the same state and the same previous solution: its shifted-previous
  reference (dashed) and its QP solution (solid);
each with a top view of the scene (vehicles at the current step, their constant-velocity prediction at
the horizon's end) and y, v, heading, a and delta over the horizon.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from srmpc.config.compose import compose_config, to_objects  # noqa: E402
from srmpc.controller_factory import build_controller, make_env  # noqa: E402
from srmpc.mpc.planner import ReferenceSource  # noqa: E402
from srmpc.scenario import road  # noqa: E402

OUTPUT = Path("results/figures/srmpc_trajectory.png")


def find_overtake(controller, env, lane_change_m: float, max_seeds: int):
    """(seed, step, scene, rollout, SRMPC plan, LTV-MPC plan, its reference) at the first overtaking rollout."""
    for seed in range(max_seeds):
        observation, _ = env.reset(seed=seed)
        controller.reset()
        for step in range(env.unwrapped.params.episode_steps):
            scene = env.unwrapped.measurement
            ego = scene.ego
            observed = scene.slot_vehicle[scene.slot_vehicle >= 0]
            predicted = controller.planner.predict(scene.others[observed])
            ref_states, ref_inputs, source = controller.planner.default_reference(ego)
            ltv_plan, _ = controller.planner.solve_about(ego, predicted, controller.last_input, ref_states, ref_inputs,
                                                         source, controller.tracking_reference)
            action = controller.act(observation, scene)
            rollout, plan = controller.last_rollout, controller.last_plan
            leader = scene.slot_vehicle[2 * int(np.argmin(np.abs(road.LANE_CENTERS - ego[1])))]
            slower_leader = leader >= 0 and scene.others[leader, 3] < ego[3] and scene.others[leader, 0] > ego[0]
            if (rollout is not None and ltv_plan is not None and slower_leader and step > 0
                    and plan.reference_source is ReferenceSource.GIVEN
                    and ego[1] - rollout.ego[0, -1, 1] >= lane_change_m
                    and ego[1] - plan.states[-1, 1] >= lane_change_m):
                return seed, step, scene, predicted, rollout, plan, ltv_plan, (ref_states, ref_inputs)
            observation, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                break
    raise SystemExit(f"no overtaking rollout in {max_seeds} seeds")


def draw_column(axes, title, scene, predicted, reference, plan, dt, reference_label):
    ref_states, ref_inputs = reference
    time_s = np.arange(ref_states.shape[0]) * dt
    top = axes[0]
    for edge in (road.LEFT_ROAD_EDGE, road.RIGHT_ROAD_EDGE):
        top.axhline(edge, color="k", lw=1)
    for boundary in road.LANE_CENTERS[:-1] + road.LANE_WIDTH / 2:
        top.axhline(boundary, color="0.6", lw=0.8, ls=(0, (6, 6)))
    x0 = scene.ego[0]
    labels = {0: "observed vehicles now", -1: "... at the horizon's end (constant velocity)"}
    for j in range(predicted.shape[1]):
        for stage, alpha in ((0, 0.9), (-1, 0.25)):
            x, y = predicted[stage, j, 0] - x0, predicted[stage, j, 1]
            top.add_patch(Rectangle((x - road.VEHICLE_LENGTH / 2, y - road.VEHICLE_WIDTH / 2), road.VEHICLE_LENGTH,
                                    road.VEHICLE_WIDTH, color="tab:blue", alpha=alpha,
                                    label=labels.pop(stage, None)))
    top.add_patch(Rectangle((-road.VEHICLE_LENGTH / 2, scene.ego[1] - road.VEHICLE_WIDTH / 2), road.VEHICLE_LENGTH,
                            road.VEHICLE_WIDTH, color="tab:red", label="ego"))
    top.plot(ref_states[:, 0] - x0, ref_states[:, 1], "k--", label=reference_label)
    top.plot(plan.states[:, 0] - x0, plan.states[:, 1], "tab:red", label="QP solution (applied plan)")
    top.set_xlim(-30, max(plan.states[-1, 0], ref_states[-1, 0]) - x0 + 20)
    # y grows to the right: right lane at the bottom; room above the road for the legend
    top.set_ylim(road.RIGHT_ROAD_EDGE + 1, road.LEFT_ROAD_EDGE - 7)
    top.set_yticks(road.LANE_CENTERS)
    top.set_title(title)
    top.set_xlabel("x - x_ego [m]")
    top.set_ylabel("y [m] (lane centres)")
    top.legend(loc="upper right", fontsize=7, ncol=2)
    series = [("y [m]", ref_states[:, 1], plan.states[:, 1], time_s),
              ("v [m/s]", ref_states[:, 3], plan.states[:, 3], time_s),
              ("heading [rad]", ref_states[:, 2], plan.states[:, 2], time_s),
              ("a [m/s^2]", ref_inputs[:, 1], plan.inputs[:, 1], time_s[:-1]),
              ("delta [rad]", ref_inputs[:, 0], plan.inputs[:, 0], time_s[:-1])]
    for ax, (label, ref, sol, t) in zip(axes[1:], series, strict=True):
        ax.plot(t, ref, "k--")
        ax.plot(t, sol, "tab:red")
        ax.set_ylabel(label)
    axes[-1].set_xlabel("time over the horizon [s]")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lane-change-m", type=float, default=3.0, help="leftward lateral move of the rollout [m]")
    parser.add_argument("--max-seeds", type=int, default=200, help="seeds to search")
    args = parser.parse_args()
    config = to_objects(compose_config(["+experiment=light_traffic", "controller=srmpc",
                                        "tracking.enabled=false"]))
    env = make_env(config)
    controller = build_controller(config, env)
    seed, step, scene, predicted, rollout, plan, ltv_plan, ltv_reference = find_overtake(
        controller, env, args.lane_change_m, args.max_seeds)
    dt = controller.planner.config.control_period_s
    figure, axes = plt.subplots(6, 2, figsize=(12, 14), sharex="row",
                                gridspec_kw={"height_ratios": [2, 1, 1, 1, 1, 1]})
    draw_column(axes[:, 0], f"SRMPC (seed {seed}, step {step})", scene, predicted,
                (rollout.ego[0], rollout.actions[0]), plan, dt, "PPO-L-SI rollout (linearization reference)")
    draw_column(axes[:, 1], "LTV-MPC from the same state", scene, predicted, ltv_reference, ltv_plan, dt,
                "shifted previous solution (linearization reference)")
    figure.tight_layout()
    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    temporary = OUTPUT.with_name("srmpc_trajectory.tmp.png")
    figure.savefig(temporary, dpi=120)
    os.replace(temporary, OUTPUT)
    data = {"seed": seed, "step": step, "ego": scene.ego.tolist(),
            "rollout_states": rollout.ego[0].tolist(), "rollout_inputs": rollout.actions[0].tolist(),
            "srmpc_states": plan.states.tolist(), "srmpc_inputs": plan.inputs.tolist(),
            "ltv_mpc_states": ltv_plan.states.tolist(), "ltv_mpc_inputs": ltv_plan.inputs.tolist()}
    OUTPUT.with_suffix(".json").write_text(json.dumps(data) + "\n")
    print(f"{OUTPUT}: seed {seed}, step {step}; rollout ends at y = {rollout.ego[0, -1, 1]:.2f} m, "
          f"SRMPC plan at {plan.states[-1, 1]:.2f} m, LTV-MPC plan at {ltv_plan.states[-1, 1]:.2f} m")


if __name__ == "__main__":
    main()
