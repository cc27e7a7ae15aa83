"""Episode videos: highway-env's own ``rgb_array`` rendering of a closed-loop episode.

The episode runs on highway-env itself (``SrmpcHighwayEnv``), so the frames are highway-env's view of
the scene: road, IDM vehicles (blue), the ego (yellow), crashed vehicles (red). Every simulation step
is a frame (15 Hz: the control step's frame plus the two intermediate sub-steps, caught through
highway-env's ``_record_video_wrapper`` hook), so the video plays in real time at 15 fps.

Drawn on top, in world coordinates (the viewer's ``pos2pix``), the controller's prediction at the
current control step:
- SRMPC: the policy's rollout, its linearization reference x^r (orange dots), and the QP's plan
  (magenta line, the applied first input);
- LTV-MPC: its QP's plan (magenta line);
- a policy alone: nothing (it plans nothing).

Black frames: highway-env's ``EnvViewer`` switches drawing off (``enabled = False``) when
``SDL_VIDEODRIVER=dummy`` is set, which headless containers set; every frame is then black. The
viewer here is switched back on and renders offscreen (no window, no display needed).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from srmpc.scenario import road
from srmpc.scenario.highway import SrmpcHighwayEnv
from srmpc.scenario.parameters import ScenarioParameters

FPS_PER_CONTROL_STEP = 3
"""Frames per control step: highway-env's 3 simulation sub-steps (15 Hz at 5 Hz control)."""
REFERENCE_COLOR = (255, 140, 0)
"""The policy's rollout (SRMPC's linearization reference): orange dots."""
PLAN_COLOR = (220, 0, 200)
"""The MPC's plan (QP solution): magenta line."""
TEXT_COLOR = (255, 255, 255)
FRAME_WIDTH_PX, FRAME_HEIGHT_PX = 960, 120
"""Frame size: a 160 m by 20 m window of the road (both multiples of 8, as H.264 wants)."""
SCALING_PX_PER_M = 6.0
CENTERING = (0.2, 0.5)
"""The ego at 20% of the frame's width (32 m behind it in view, 128 m ahead: the 5 s horizon)."""
ROAD_CENTRE_Y_M = (road.LEFT_ROAD_EDGE + road.RIGHT_ROAD_EDGE) / 2
"""The window follows the ego along x only; vertically it stays on the road's centre line."""


@dataclass
class Path2D:
    """A trajectory to draw: (T, >= 2) world [x, y, ...] [m]."""

    points: np.ndarray
    color: tuple[int, int, int]
    dots: bool = False


@dataclass
class EpisodeFrames:
    """The frames of one recorded episode and how it went."""

    frames: list[np.ndarray] = field(default_factory=list)
    steps: int = 0
    termination: str = ""
    """"collision", "offroad", "truncated" or "" (stopped after the requested steps)."""
    ego_trace: list[np.ndarray] = field(default_factory=list)
    """The ego's [x, y, heading, speed] at each control step."""
    others_trace: list[np.ndarray] = field(default_factory=list)
    """All other vehicles' states (V, 4) at each control step."""


def rendering_env(scenario: ScenarioParameters) -> SrmpcHighwayEnv:
    """The scenario on highway-env with offscreen ``rgb_array`` rendering (960 x 120 frames)."""
    env = SrmpcHighwayEnv(scenario, render_mode="rgb_array")
    env.config.update(offscreen_rendering=True, centering_position=list(CENTERING), scaling=SCALING_PX_PER_M,
                      screen_width=FRAME_WIDTH_PX, screen_height=FRAME_HEIGHT_PX)
    return env


def _viewer(env: SrmpcHighwayEnv):
    """The env's viewer, created if needed and drawing even under ``SDL_VIDEODRIVER=dummy`` (module doc)."""
    if env.viewer is None:
        from highway_env.envs.common.graphics import EnvViewer

        env.viewer = EnvViewer(env)
        env.viewer.window_position = lambda: np.array([env.vehicle.position[0], ROAD_CENTRE_Y_M])
    env.viewer.enabled = True
    return env.viewer


def render_frame(env: SrmpcHighwayEnv, paths: Sequence[Path2D] = (), caption: str = "") -> np.ndarray:
    """The current scene as an (H, W, 3) uint8 frame, with ``paths`` and ``caption`` drawn on it."""
    import pygame

    viewer = _viewer(env)
    viewer.display()
    env.enable_auto_render = True  # highway-env's render() does this: intermediate sub-steps get frames
    surface = viewer.sim_surface
    for path in paths:
        pixels = [surface.pos2pix(float(x), float(y)) for x, y in np.asarray(path.points)[:, :2]]
        if path.dots:
            for pixel in pixels:
                pygame.draw.circle(surface, path.color, pixel, 2)
        elif len(pixels) > 1:
            pygame.draw.lines(surface, path.color, False, pixels, 2)
    if caption:
        font = pygame.font.Font(None, 20)
        surface.blit(font.render(caption, True, TEXT_COLOR), (6, 4))
    return viewer.get_image()


class _FrameHook:
    """highway-env calls ``_capture_frame`` of ``env._record_video_wrapper`` at every intermediate sub-step."""

    def __init__(self, capture: Callable[[], None]) -> None:
        self._capture_frame = capture


def controller_paths(controller) -> list[Path2D]:
    """What the controller planned at its last step: SRMPC's reference and plan, LTV-MPC's plan."""
    paths = []
    rollout = getattr(controller, "last_rollout", None)
    if rollout is not None:
        paths.append(Path2D(rollout.ego[0], REFERENCE_COLOR, dots=True))
    plan = getattr(controller, "last_plan", None)
    report = getattr(controller, "last_report", None)
    if plan is None and report is not None:
        plan = report.plan
    if plan is not None:
        paths.append(Path2D(plan.states, PLAN_COLOR))
    return paths


def record_episode(env: SrmpcHighwayEnv, controller, seed: int, steps: int, label: str,
                   draw_plans: bool = True) -> EpisodeFrames:
    """Run ``controller`` from ``env.reset(seed=seed)`` for at most ``steps`` control steps, a frame per
    simulation step, the controller's plans drawn (``draw_plans``); the last frame is held for 1 s."""
    result = EpisodeFrames()
    observation, _ = env.reset(seed=seed)
    controller.reset()
    paths: list[Path2D] = []
    def caption() -> str:
        time_s = env.steps / env.params.simulation_frequency_hz
        return f"{label}   t = {time_s:4.1f} s   v = {env.vehicle.speed:4.1f} m/s"

    env._record_video_wrapper = _FrameHook(lambda: result.frames.append(render_frame(env, paths, caption())))
    try:
        for _ in range(steps):
            scene = env.measurement
            result.ego_trace.append(scene.ego.copy())
            result.others_trace.append(scene.others.copy())
            action = controller.act(observation, scene)
            paths = controller_paths(controller) if draw_plans else []
            result.frames.append(render_frame(env, paths, caption()))
            observation, _, terminated, truncated, info = env.step(action)
            result.steps += 1
            if terminated or truncated:
                result.termination = info["termination"] if terminated else "truncated"
                break
        result.ego_trace.append(env.measurement.ego.copy())
        result.others_trace.append(env.measurement.others.copy())
        ending = f"   [{result.termination}]" if result.termination not in ("", "truncated") else ""
        last = render_frame(env, (), caption() + ending)
        result.frames.extend([last] * int(env.params.simulation_frequency_hz))
    finally:
        env._record_video_wrapper = None
    return result


LEADER_RANGE_M = 60.0
"""A same-lane vehicle at most this far ahead counts as the leader being closed on."""


def overtakes(ego_trace: list[np.ndarray], others_trace: list[np.ndarray]) -> list[dict]:
    """Vehicles that were a slower leader in the ego's lane (centres within half a lane, 0..60 m ahead)
    at some control step and more than a vehicle length behind the ego at a later one."""
    ego, others = np.asarray(ego_trace), np.asarray(others_trace)  # (T, 4), (T, V, 4)
    dx = others[:, :, 0] - ego[:, None, 0]
    same_lane = np.abs(others[:, :, 1] - ego[:, None, 1]) < road.LANE_WIDTH / 2
    slower_leader = same_lane & (dx > 0) & (dx < LEADER_RANGE_M) & (others[:, :, 3] < ego[:, None, 3])
    found = []
    for vehicle in np.flatnonzero(slower_leader.any(axis=0)):
        first_ahead = int(np.argmax(slower_leader[:, vehicle]))
        behind = np.flatnonzero(dx[first_ahead:, vehicle] < -road.VEHICLE_LENGTH)
        if behind.size:
            found.append({"vehicle": int(vehicle), "leader_at_step": first_ahead,
                          "passed_at_step": first_ahead + int(behind[0])})
    return found


def legend_bar(width: int, entries: Sequence[tuple[str, tuple[int, int, int]]], height: int = 24) -> np.ndarray:
    """A dark (height, width, 3) strip naming the drawn paths."""
    import pygame

    pygame.font.init()
    surface = pygame.Surface((width, height))
    surface.fill((30, 30, 30))
    font = pygame.font.Font(None, 18)
    x = 8
    for text, color in entries:
        pygame.draw.line(surface, color, (x, height // 2), (x + 18, height // 2), 3)
        rendered = font.render(text, True, TEXT_COLOR)
        surface.blit(rendered, (x + 24, (height - rendered.get_height()) // 2))
        x += 24 + rendered.get_width() + 24
    return np.moveaxis(pygame.surfarray.array3d(surface), 0, 1)


def stack_videos(videos: Sequence[Sequence[np.ndarray]], footer: np.ndarray | None = None) -> list[np.ndarray]:
    """Frames of ``videos`` stacked top to bottom (a finished video holds its last frame), plus ``footer``."""
    length = max(len(v) for v in videos)
    frames = []
    for i in range(length):
        rows = [v[min(i, len(v) - 1)] for v in videos]
        if footer is not None:
            rows.append(footer)
        frames.append(np.concatenate(rows, axis=0))
    return frames


def write_video(path: Path, frames: Sequence[np.ndarray], fps: int) -> None:
    """Write ``frames`` as H.264 MP4 (yuv420p, plays everywhere) through imageio-ffmpeg, via a temporary file."""
    import imageio.v2 as imageio

    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.stem + ".tmp" + path.suffix)
    with imageio.get_writer(temporary, fps=fps, codec="libx264", quality=6, pixelformat="yuv420p",
                            macro_block_size=8, ffmpeg_log_level="error") as writer:
        for frame in frames:
            writer.append_data(frame)
    temporary.replace(path)
