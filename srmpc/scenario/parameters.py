"""Typed parameters of the scenario, with units. These dataclasses are also the Hydra schema.

Every value that shapes an episode lives here; library code receives an instance, never a raw
config. Validation in ``__post_init__`` names the bad field and value.
"""

from __future__ import annotations

import enum
import math
from dataclasses import astuple, dataclass, field

from srmpc.scenario import road
from srmpc.value_checks import (
    NON_NEGATIVE,
    NON_POSITIVE,
    POSITIVE,
    TEXT,
    UNIT_INTERVAL,
    Interval,
    at_least,
    check_fields,
)

MAX_VEHICLES_COUNT = int(road.LANE_COUNT * road.ROAD_LENGTH / road.VEHICLE_LENGTH)
"""Most IDM vehicles a scene holds: 6000, the 3 lanes of the 10 km road filled bumper to bumper by 5 m
vehicles. The twin keeps a few dozen float64 per vehicle and sweeps them sorted by x, so 8000 vehicles
still ran a 30-step SRMPC episode in 13 s and 0.5 GB; 1,000,000 ended in a ``MemoryError`` inside the
step kernel."""
MAX_EPISODE_STEPS = 10_000
"""Longest episode in control steps: 2000 s at 5 Hz. Traffic at its slowest default spawn speed (21 m/s)
leaves the 10 km road after 476 s (2381 steps), so no longer episode has a scene left to drive in."""


def _check(condition: bool, key: str, value: object, expectation: str) -> None:
    if not condition:
        raise ValueError(f"{key}={value!r}: {expectation}")


@dataclass
class RewardParameters:
    """Paper eq. (reward-function): r' = -g (vx_ref - vx)^2 - (1 - g) (y_ref - y)^2.

    The training reward is r = exp(r' / scale), which lies in (0, 1] and equals 1 exactly on the
    reference (vx = vx_ref on the right-lane centre). With scale = 10, r' = -10 (e.g. 4.5 m/s too
    slow, or 4.5 m off the lane centre at g = 0.5) gives r = 0.37.
    """

    vx_ref_mps: float = 25.0
    """Longitudinal reference speed v_x^ref [m/s] (paper: 25 m/s)."""
    speed_weight: float = 0.5
    """g in [0, 1]: weight of the squared speed error; 1 - g weighs the squared lane error."""
    scale: float = 10.0
    """Scale of the exponentiation r = exp(r' / scale) [units of r']."""

    def __post_init__(self) -> None:
        check_fields(self, vx_ref_mps=POSITIVE, speed_weight=UNIT_INTERVAL, scale=POSITIVE)


class SafetyIndexKind(enum.Enum):
    """Which safe distance the safety index's barrier uses (``srmpc.scenario.safety_index``)."""

    paper = "paper"
    """sigma + d_min, a constant (paper eq. (si))."""
    rss = "rss"
    """sigma + the pair's Responsibility-Sensitive Safety distance (speed-dependent)."""


@dataclass
class RssParameters:
    """Responsibility-Sensitive Safety's parameters (Shalev-Shwartz et al. 2017), for ``kind: rss``.

    Defaults: the "aggressive" set calibrated on naturalistic driving data in the IEEE study
    ieeexplore.ieee.org/document/9304756 (response time 0.53 s). Its "conservative" set has rho 1.94 s,
    5.91 / 4.13 / 9.50 m/s^2, 0.45 / 0.86 m/s^2, mu 0.07 m; intel/ad-rss-lib's defaults are rho 1 s (ego)
    and 2 s (others), 3.5 / 4 / 8 m/s^2, 0.2 / 0.8 m/s^2, mu 0.1 m
    (``conf/experiment/training/rss_sensitivity/ad_rss_lib.yaml``).
    Why the aggressive set by default: at 25 m/s behind a leader at 25 m/s it asks for 54 m, the
    library's defaults for 89 m, twice dense traffic's mean same-lane gap (3 lanes x 15 m).

    Ranges: response times in [0, 10] s; accelerations at most 20 m/s^2 (2 g, beyond any road tyre),
    brakings above 0 (they divide) and a_brake,min <= a_brake,max (RSS's definition); mu in [0, 10] m.
    """

    response_time_ego_s: float = 0.53
    """rho of the ego [s]: how long it may keep accelerating before it responds."""
    response_time_others_s: float = 0.53
    """rho of the other vehicles [s] (the rear one's in a same-lane pair with the ego in front)."""
    longitudinal_acceleration_max_mps2: float = 4.10
    """a_accel,max [m/s^2]: the rear vehicle's worst acceleration during its response time."""
    longitudinal_brake_min_mps2: float = 4.64
    """a_brake,min [m/s^2]: the braking the rear vehicle guarantees afterwards."""
    longitudinal_brake_max_mps2: float = 8.03
    """a_brake,max [m/s^2]: the front vehicle's hardest braking."""
    lateral_acceleration_max_mps2: float = 0.43
    """a^lat_accel,max [m/s^2]: lateral acceleration towards the other vehicle during the response time."""
    lateral_brake_min_mps2: float = 0.96
    """a^lat_brake,min [m/s^2]: lateral braking afterwards."""
    lateral_margin_m: float = 0.07
    """mu [m]: lateral fluctuation margin."""

    def __post_init__(self) -> None:
        check_fields(
            self, response_time_ego_s=Interval(0.0, 10.0), response_time_others_s=Interval(0.0, 10.0),
            longitudinal_acceleration_max_mps2=Interval(0.0, 20.0),
            longitudinal_brake_min_mps2=Interval(0.0, 20.0, low_open=True),
            longitudinal_brake_max_mps2=Interval(0.0, 20.0, low_open=True),
            lateral_acceleration_max_mps2=Interval(0.0, 20.0),
            lateral_brake_min_mps2=Interval(0.0, 20.0, low_open=True), lateral_margin_m=Interval(0.0, 10.0),
        )
        _check(self.longitudinal_brake_min_mps2 <= self.longitudinal_brake_max_mps2, "longitudinal_brake_min_mps2",
               self.longitudinal_brake_min_mps2,
               f"must be <= longitudinal_brake_max_mps2={self.longitudinal_brake_max_mps2} (RSS)")

    def as_tuple(self) -> tuple[float, ...]:
        """The values as floats in field order, the layout of ``srmpc.scenario.safety_index``'s ``RSS_*`` indices."""
        return tuple(float(value) for value in astuple(self))


@dataclass
class SafetyIndexParameters:
    """Paper eq. (si): phi = (sigma + d_min)^n - d^n - k * d_dot, and the cost c of the SI transition.

    Per surrounding vehicle, d is the gap between the two axis-aligned bounding boxes [m] (0 when
    they overlap) and d_dot its rate [m/s]; on lanes other than the ego's the longitudinal part of
    d_dot is zeroed, as in the paper. The road edges count as obstacles too, with d the distance of
    the ego's centre to the edge (the ego leaves the road when its centre crosses it) and
    ``edge_d_min_m`` in place of d_min. phi(s) is the maximum over the observed vehicles and both
    edges.

    Why these values: with n = 1, phi > 0 exactly when the gap is below sigma + d_min + k * closing
    speed, so k is a look-ahead time [s]. k = 1 s with d_min = 1 m and sigma = 0.5 m flags a
    same-lane leader at 11.5 m when closing at 10 m/s (its stopping distance at 5 m/s^2 is 10 m), a
    vehicle alongside (2 m box gap) when drifting towards it faster than 0.5 m/s, and a road edge
    from the lane centre (2 m) when drifting towards it faster than 1.5 m/s. eta = 0.1 m makes an
    unsafe state recover by at least 0.1 m per 0.2 s step.
    """

    sigma_m: float = 0.5
    """Safety margin sigma [m], added to d_min."""
    d_min_m: float = 1.0
    """Minimum bumper-to-bumper gap to another vehicle d_min [m]."""
    edge_d_min_m: float = 0.0
    """Minimum distance from the ego's centre to a road edge [m]."""
    n: float = 1.0
    """Exponent n of the distances (> 0)."""
    k_s: float = 1.0
    """Gain k on the gap rate d_dot [s when n = 1]."""
    eta: float = 0.1
    """Slack eta of the safe-control condition phi(s') < max(phi(s) - eta, 0) [units of phi]."""
    cost_floor: float = -0.1
    """Lower clip of the cost, the paper's -0.1 (keeps the policy from becoming too conservative)."""
    kind: SafetyIndexKind = SafetyIndexKind.paper
    """paper (sigma + d_min) or rss (sigma + the RSS distance of each pair, ``rss``'s parameters)."""
    rss: RssParameters = field(default_factory=RssParameters)
    """RSS's parameters; used only with ``kind: rss`` (and recorded in a run's config.yaml only then)."""

    def __post_init__(self) -> None:
        if isinstance(self.rss, dict):
            self.rss = RssParameters(**self.rss)
        check_fields(self, sigma_m=NON_NEGATIVE, d_min_m=NON_NEGATIVE, edge_d_min_m=NON_NEGATIVE, n=POSITIVE,
                     k_s=NON_NEGATIVE, eta=NON_NEGATIVE, cost_floor=NON_POSITIVE)


@dataclass
class ScenarioParameters:
    """The paper's highway scenario: 3 lanes, IDM traffic without lane changes, one ego vehicle.

    Spawning follows highway-env's ``Vehicle.create_random``: each new vehicle goes on a random lane
    ahead of the furthest vehicle so far, by ``spacing * (12 + speed) * exp(-5/40 * 3) * U(0.9, 1.1)``
    metres. ``spacing`` is derived from ``mean_spawn_gap_m`` so that the expected gap between
    successively spawned vehicles is that value (paper: about 25 m light, 15 m dense). First
    ``vehicles_behind_ego`` vehicles are spawned, then the ego, then the rest, so traffic surrounds
    the ego. 16 behind and 24 ahead cover 400 m behind and 600 m ahead in light traffic (240 m and
    360 m in dense), more than the ego gains on the traffic in 80 s at 25 m/s against the 21-24 m/s
    IDM vehicles plus the 100 m perception range. Measured with the lane-keeping baseline (6
    episodes per level, 400 steps each): every step had a leader and a follower within 100 m, and
    on average 5.2 (light) and 5.8 (dense) of the 6 observation slots were filled.
    """

    traffic: str = "light"
    """Label of the traffic level, used in run names and result files."""
    vehicles_count: int = 40
    """Number of IDM vehicles besides the ego (at most ``MAX_VEHICLES_COUNT``, what the road holds)."""
    vehicles_behind_ego: int = 16
    """How many of them are spawned behind the ego."""
    mean_spawn_gap_m: float = 25.0
    """Expected longitudinal gap between successively spawned vehicles [m]."""
    other_speed_min_mps: float = 21.0
    """Lower bound of the uniform initial (and IDM target) speed of other vehicles [m/s]."""
    other_speed_max_mps: float = 24.0
    """Upper bound of the same [m/s] (21-24 m/s is highway-env's 0.7-0.8 x speed limit)."""
    ego_speed_min_mps: float = 20.0
    """Lower bound of the uniform initial ego speed [m/s]."""
    ego_speed_max_mps: float = 25.0
    """Upper bound of the uniform initial ego speed [m/s]."""
    simulation_frequency_hz: int = 15
    """Integration frequency of the vehicle dynamics [Hz]."""
    policy_frequency_hz: int = 5
    """Control frequency [Hz]; dt = 0.2 s, 3 integration sub-steps per step."""
    episode_steps: int = 400
    """Truncation after this many control steps (400 x 0.2 s = 80 s; at most ``MAX_EPISODE_STEPS``)."""
    steering_max_rad: float = 0.1
    """Steering angle range [-max, max] [rad]. At 25 m/s, 0.1 rad already commands ~12 m/s^2 of
    lateral acceleration, beyond tyre limits, so the range limits no highway manoeuvre."""
    acceleration_min_mps2: float = -5.0
    """Lowest acceleration command [m/s^2] (highway-env's default range)."""
    acceleration_max_mps2: float = 5.0
    """Highest acceleration command [m/s^2]."""
    perception_range_m: float = 100.0
    """Vehicles further than this longitudinally are not observed [m]."""
    reward: RewardParameters = field(default_factory=RewardParameters)
    safety_index: SafetyIndexParameters = field(default_factory=SafetyIndexParameters)

    def __post_init__(self) -> None:
        if isinstance(self.reward, dict):
            self.reward = RewardParameters(**self.reward)
        if isinstance(self.safety_index, dict):
            self.safety_index = SafetyIndexParameters(**self.safety_index)
        check_fields(
            self, traffic=TEXT, vehicles_count=Interval(1, MAX_VEHICLES_COUNT), vehicles_behind_ego=NON_NEGATIVE,
            mean_spawn_gap_m=POSITIVE, other_speed_min_mps=NON_NEGATIVE, other_speed_max_mps=NON_NEGATIVE,
            ego_speed_min_mps=NON_NEGATIVE, ego_speed_max_mps=Interval(0.0, road.MAX_SPEED),
            simulation_frequency_hz=at_least(1), policy_frequency_hz=at_least(1),
            episode_steps=Interval(1, MAX_EPISODE_STEPS),
            steering_max_rad=Interval(0.0, math.pi / 2, low_open=True, high_open=True),
            acceleration_min_mps2=NON_POSITIVE, acceleration_max_mps2=NON_NEGATIVE, perception_range_m=POSITIVE,
        )
        _check(
            0 <= self.vehicles_behind_ego <= self.vehicles_count,
            "vehicles_behind_ego",
            self.vehicles_behind_ego,
            f"must lie in [0, vehicles_count={self.vehicles_count}]",
        )
        for low_key, high_key in (
            ("other_speed_min_mps", "other_speed_max_mps"),
            ("ego_speed_min_mps", "ego_speed_max_mps"),
            ("acceleration_min_mps2", "acceleration_max_mps2"),
        ):
            low, high = getattr(self, low_key), getattr(self, high_key)
            _check(low <= high, low_key, low, f"must be <= {high_key}={high}")
        _check(
            self.simulation_frequency_hz >= self.policy_frequency_hz
            and self.simulation_frequency_hz % self.policy_frequency_hz == 0,
            "simulation_frequency_hz",
            self.simulation_frequency_hz,
            f"must be a multiple of policy_frequency_hz={self.policy_frequency_hz}",
        )
        _check(self.acceleration_min_mps2 < self.acceleration_max_mps2, "acceleration_min_mps2",
               self.acceleration_min_mps2, "must be < acceleration_max_mps2")

    @property
    def control_period_s(self) -> float:
        """dt of one control step [s]."""
        return 1.0 / self.policy_frequency_hz

    @property
    def substeps(self) -> int:
        """Integration sub-steps per control step."""
        return self.simulation_frequency_hz // self.policy_frequency_hz

    @property
    def spawn_spacing(self) -> float:
        """highway-env's ``spacing`` argument (1 / vehicles_density) giving ``mean_spawn_gap_m``.

        E[gap] = spacing * (12 + E[speed]) * exp(-5/40 * lanes), with E[U(0.9, 1.1)] = 1 and the
        other vehicles' mean speed.
        """
        mean_speed = 0.5 * (self.other_speed_min_mps + self.other_speed_max_mps)
        return self.mean_spawn_gap_m / ((12.0 + mean_speed) * math.exp(-5.0 / 40.0 * road.LANE_COUNT))
