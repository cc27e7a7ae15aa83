"""The per-step outcome keys that planner-based controllers count (``episode_outcomes``).

``solved`` / ``shifted_previous`` / ``emergency_brake``: which link of the fallback chain produced the
applied input. ``solved_from_policy`` / ``solved_from_shifted`` / ``solved_from_lane_following``: which
linearization reference the applied QP solution came from (they add up to ``solved``).
``policy_failed``: steps whose policy rollout raised or was non-finite (SRMPC only).
"""

from collections import Counter

from srmpc.mpc.planner import ReferenceSource, StepOutcome

REFERENCE_OUTCOMES = {
    ReferenceSource.GIVEN: "solved_from_policy",
    ReferenceSource.SHIFTED_PREVIOUS: "solved_from_shifted",
    ReferenceSource.LANE_FOLLOWING: "solved_from_lane_following",
}
"""Outcome key of a solved plan by the origin of its linearization reference."""
POLICY_FAILED = "policy_failed"
OUTCOME_KEYS = (*(outcome.value for outcome in StepOutcome), *REFERENCE_OUTCOMES.values(), POLICY_FAILED)
"""Every outcome key, in the column order of ``episodes.csv``."""


def episode_counts(counts: Counter[str]) -> dict[str, int]:
    """Steps per outcome key of an episode, every key of :data:`OUTCOME_KEYS` present (0 when none)."""
    return {key: int(counts.get(key, 0)) for key in OUTCOME_KEYS}
