"""Episode videos: highway-env's frames are drawn (not black) even under SDL_VIDEODRIVER=dummy."""

import numpy as np

from srmpc.scenario.parameters import ScenarioParameters
from srmpc.video import (
    PLAN_COLOR,
    REFERENCE_COLOR,
    Path2D,
    overtakes,
    render_frame,
    rendering_env,
    stack_videos,
    write_video,
)

ROAD_GREY = (100, 100, 100)


def test_rendered_frame_shows_road_vehicles_and_plans_under_the_dummy_video_driver(monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")  # what the Dockerfile sets; highway-env then draws nothing
    env = rendering_env(ScenarioParameters())
    try:
        env.reset(seed=0)
        ego = env.measurement.ego
        ahead = np.array([[ego[0] + 4.0 * i, ego[1], 0.0, 20.0] for i in range(1, 26)])
        frame = render_frame(env, [Path2D(ahead, PLAN_COLOR), Path2D(ahead + [0, 2, 0, 0], REFERENCE_COLOR, dots=True)],
                             "caption")
    finally:
        env.close()
    assert frame.shape == (120, 960, 3) and frame.dtype == np.uint8
    assert frame.mean() > 60, "black frame: the viewer did not draw"
    colors = {tuple(c) for c in frame.reshape(-1, 3)}
    assert ROAD_GREY in colors and (255, 255, 255) in colors  # road and lane markings / caption
    assert np.all(frame == PLAN_COLOR, axis=-1).sum() > 200  # the plan's line
    assert np.all(frame == REFERENCE_COLOR, axis=-1).sum() > 50  # the reference's dots
    vehicles = (frame[..., 2] > 200) & (frame[..., 0] < 150)  # highway-env's IDM vehicles are light blue
    assert vehicles.sum() > 100


def test_overtake_is_a_slower_same_lane_leader_passed():
    ego = [np.array([25.0 * t, 8.0 if t < 3 else 4.0, 0.0, 25.0]) for t in range(8)]
    leader = [np.array([[30.0 + 10.0 * t, 8.0, 0.0, 10.0], [200.0 + 30.0 * t, 4.0, 0.0, 30.0]]) for t in range(8)]
    assert overtakes(ego, leader) == [{"vehicle": 0, "leader_at_step": 0, "passed_at_step": 3}]
    assert overtakes(ego[:2], leader[:2]) == []  # still ahead


def test_composite_holds_finished_videos_and_writes_a_small_mp4(tmp_path):
    short = [np.full((16, 32, 3), 10, np.uint8)] * 2
    long = [np.full((16, 32, 3), 200, np.uint8)] * 5
    frames = stack_videos([short, long], footer=np.zeros((8, 32, 3), np.uint8))
    assert len(frames) == 5 and frames[-1].shape == (40, 32, 3) and frames[-1][0, 0, 0] == 10
    write_video(tmp_path / "v.mp4", frames, fps=15)
    assert 0 < (tmp_path / "v.mp4").stat().st_size < 100_000 and not list(tmp_path.glob("*.tmp*"))
