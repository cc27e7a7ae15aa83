"""A scripted scenario and controller for the episode loop's tests (workers, fan-out shards), picklable.

The episode from seed s has s % 3 + 1 steps, with r' = -s and v_x = 21 m/s; SLOW_SEED takes 2 s to reset (so it
finishes after later episodes), FAILING_SEED raises after 1 s (after the episodes before it).
"""

from __future__ import annotations

import time

SLOW_SEED, FAILING_SEED = 10, 22


class Unwrapped:
    measurement = None


class ScriptedEnv:
    """Episode from seed s: s % 3 + 1 steps; SLOW_SEED takes 2 s (it finishes after later episodes);
    FAILING_SEED raises after 1 s (after the episodes before it)."""

    unwrapped = Unwrapped()

    def reset(self, seed):
        if seed in (SLOW_SEED, FAILING_SEED):
            time.sleep(2.0 if seed == SLOW_SEED else 1.0)
        if seed == FAILING_SEED:
            raise ValueError(f"scripted failure at seed {seed}")
        self.left, self.seed = seed % 3 + 1, seed
        return 0.0, {}

    def step(self, action):
        self.left -= 1
        info = {"reward_prime": -float(self.seed), "event_cost": 0.0, "vx": 20.0 + action, "cost": 0.0,
                "termination": "collision"}
        return 0.0, 0.0, False, self.left == 0, info

    def close(self):
        pass


class ScriptedController:
    def reset(self):
        pass

    def act(self, observation, measurement):
        return 1.0

    def episode_outcomes(self):
        return {"solved": 1}


def scripted_setup():
    return ScriptedEnv(), ScriptedController()
