"""DVC stage: episode videos, results/videos/<method>_<traffic>.mp4 and side_by_side_<traffic>.mp4.

For each traffic level, the first seed (from ``--first-seed``) in which SRMPC overtakes within
``--steps`` control steps: the ego closes on a slower leader in its own lane and later has it behind.
The search runs on the twin (fast); the videos then run PPO-L-SI, LTV-MPC and SRMPC on highway-env
itself from ``reset(seed)``, so all three start from the same initial state, rendered by highway-env's
``rgb_array`` renderer (srmpc/video.py: 15 frames per second of simulated time, real time, SRMPC's
policy reference and QP plan and LTV-MPC's plan drawn on the frames). The overtake is checked again
on highway-env (the twin and highway-env agree step for step; a seed where they would not is skipped).

Writes results/videos/{ppo_lsi,ltv_mpc,srmpc}_{light,dense}.mp4, side_by_side_{light,dense}.mp4 (the
three stacked, same time axis) and videos.json (seed, steps, how each episode ended, its overtakes).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from srmpc.config.compose import compose_config, to_objects
from srmpc.controller_factory import build_controller, make_env
from srmpc.video import (
    FPS_PER_CONTROL_STEP,
    PLAN_COLOR,
    REFERENCE_COLOR,
    legend_bar,
    overtakes,
    record_episode,
    rendering_env,
    stack_videos,
    write_video,
)

ROOT = Path(__file__).resolve().parents[1]

OUTPUT = ROOT / "results" / "videos"
METHODS = {"ppo_lsi": "PPO-L-SI", "ltv_mpc": "LTV-MPC", "srmpc": "SRMPC"}
LEGEND = (("PPO-L-SI rollout (SRMPC's linearization reference)", REFERENCE_COLOR),
          ("MPC plan (QP solution)", PLAN_COLOR))
def config_for(traffic: str, method: str, simulator: str):
    controller = "controller=policy" if method == "ppo_lsi" else f"controller={method}"
    return to_objects(compose_config([f"+experiment={traffic}_traffic", controller,
                                      f"evaluation.simulator={simulator}", "tracking.enabled=false"]))


def twin_candidates(traffic: str, first_seed: int, max_seeds: int, steps: int):
    """Seeds in which SRMPC on the twin overtakes within ``steps`` without crashing, in order."""
    config = config_for(traffic, "srmpc", "twin")
    env = make_env(config)
    controller = build_controller(config, env)
    for seed in range(first_seed, first_seed + max_seeds):
        observation, _ = env.reset(seed=seed)
        controller.reset()
        ego_trace, others_trace, crashed = [], [], False
        for _ in range(steps):
            scene = env.unwrapped.measurement
            ego_trace.append(scene.ego)
            others_trace.append(scene.others)
            observation, _, terminated, truncated, info = env.step(controller.act(observation, scene))
            if terminated or truncated:
                crashed = bool(terminated)
                break
        if not crashed and overtakes(ego_trace, others_trace):
            yield seed
    env.close()


def record(traffic: str, method: str, seed: int, steps: int):
    config = config_for(traffic, method, "highway_env")
    env = rendering_env(config.scenario)
    try:
        controller = build_controller(config, env)
        return record_episode(env, controller, seed, steps, f"{METHODS[method]}, {traffic} traffic, seed {seed}")
    finally:
        env.close()


def videos_for(traffic: str, args: argparse.Namespace) -> dict:
    """Find the scene, record the three methods, write their videos and the composite; returns the record."""
    for seed in twin_candidates(traffic, args.first_seed, args.max_seeds, args.steps):
        episodes = {"srmpc": record(traffic, "srmpc", seed, args.steps)}
        passed = overtakes(episodes["srmpc"].ego_trace, episodes["srmpc"].others_trace)
        if not passed or episodes["srmpc"].termination in ("collision", "offroad"):
            print(f"{traffic}: seed {seed} overtakes on the twin but not on highway-env; next seed")
            continue
        for method in ("ppo_lsi", "ltv_mpc"):
            episodes[method] = record(traffic, method, seed, args.steps)
        break
    else:
        last = args.first_seed + args.max_seeds - 1
        raise SystemExit(f"{traffic}: no overtake by SRMPC in seeds {args.first_seed}..{last}")
    fps = FPS_PER_CONTROL_STEP * config_for(traffic, "srmpc", "twin").scenario.policy_frequency_hz
    legend = legend_bar(episodes["srmpc"].frames[0].shape[1], LEGEND)
    summary = {"seed": seed, "steps": args.steps, "fps": fps, "methods": {}}
    for method in METHODS:
        episode = episodes[method]
        frames = [np.concatenate([f, legend]) for f in episode.frames] if method != "ppo_lsi" else episode.frames
        write_video(OUTPUT / f"{method}_{traffic}.mp4", frames, fps)
        summary["methods"][method] = {
            "control_steps": episode.steps, "termination": episode.termination or "none within the video",
            "overtakes": overtakes(episode.ego_trace, episode.others_trace),
        }
    write_video(OUTPUT / f"side_by_side_{traffic}.mp4",
                stack_videos([episodes[m].frames for m in METHODS], footer=legend), fps)
    return summary


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=150, help="control steps per video (5 per second)")
    parser.add_argument("--first-seed", type=int, default=0, help="first seed of the search")
    parser.add_argument("--max-seeds", type=int, default=100, help="seeds to search")
    parser.add_argument("--traffic", nargs="+", default=["light", "dense"], choices=["light", "dense"])
    args = parser.parse_args()
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # no window; srmpc.video draws under it (its doc)
    record_file = OUTPUT / "videos.json"
    videos = json.loads(record_file.read_text()) if record_file.exists() else {}
    for traffic in args.traffic:
        videos[traffic] = videos_for(traffic, args)
        for name in [f"{m}_{traffic}.mp4" for m in METHODS] + [f"side_by_side_{traffic}.mp4"]:
            print(f"{OUTPUT / name}: {(OUTPUT / name).stat().st_size / 1e6:.2f} MB")
    record_file.write_text(json.dumps(videos, indent=2) + "\n")
    print(json.dumps(videos, indent=2))


if __name__ == "__main__":
    main()
