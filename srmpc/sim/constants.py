"""The scenario's numbers in the form the numba kernels take: a flat named tuple of floats and ints.

Vehicle and IDM constants are highway-env 1.12.1's (``Vehicle``, ``ControlledVehicle``,
``IDMVehicle``, ``StraightLane``), written out with their units; the scenario's parameters come
from :class:`~srmpc.scenario.parameters.ScenarioParameters`.
"""

from __future__ import annotations

import math
from collections import namedtuple

from srmpc.scenario import road
from srmpc.scenario.parameters import SafetyIndexKind, ScenarioParameters

# --- highway-env vehicle geometry and limits --------------------------------------------------
VEHICLE_LENGTH = road.VEHICLE_LENGTH
"""Vehicle length l [m]; the bicycle's rear axle sits at l/2."""
VEHICLE_WIDTH = road.VEHICLE_WIDTH
"""Vehicle width [m]."""
VEHICLE_DIAGONAL = math.sqrt(VEHICLE_LENGTH**2 + VEHICLE_WIDTH**2)
"""Diagonal of the vehicle rectangle [m], the radius sum of the collision pre-check."""
MAX_SPEED = road.MAX_SPEED
"""Speed above which acceleration is clipped towards it [m/s]."""
MIN_SPEED = -40.0
"""Speed below which acceleration is clipped towards it [m/s]."""

# --- lanes (highway-env StraightLane) -----------------------------------------------------------
LANE_HALF_WIDTH = road.LANE_WIDTH / 2
"""Half the lane width [m]: |lateral| <= this is on the lane."""
NEIGHBOUR_LANE_MARGIN = 1.0
"""Extra lateral margin [m] of ``Road.neighbour_vehicles`` (``on_lane(..., margin=1)``)."""
LANE_END_MARGIN = 5.0
"""``AbstractLane.VEHICLE_LENGTH`` [m]: a lane extends this far before its start and after its end."""

# --- ControlledVehicle lane-following controller --------------------------------------------------
KP_LATERAL = 1 / 0.6
"""Lateral position gain 1/TAU_LATERAL [1/s]."""
KP_HEADING = 1 / 0.2
"""Heading gain 1/TAU_HEADING [1/s]."""
MAX_STEERING_ANGLE = math.pi / 3
"""Steering clip of controlled vehicles [rad]."""

# --- IDMVehicle ------------------------------------------------------------------------------------
IDM_ACC_MAX = 6.0
"""Acceleration clip [m/s^2]."""
IDM_COMFORT_ACC_MAX = 3.0
"""Desired maximum acceleration a [m/s^2]."""
IDM_COMFORT_ACC_MIN = -5.0
"""Desired maximum deceleration -b [m/s^2]."""
IDM_DISTANCE_WANTED = 5.0 + VEHICLE_LENGTH
"""Jam distance s0 plus a vehicle length [m]."""
IDM_TIME_WANTED = 1.5
"""Desired time gap T [s]."""
IDM_DELTA_RANGE = (3.5, 4.5)
"""Range of the randomized velocity exponent delta [-]."""

# --- spawning (Vehicle.create_random) ----------------------------------------------------------------
SPAWN_BASE_GAP = 12.0
"""Speed-independent part of create_random's default spacing [m]."""
SPAWN_GAP_PER_SPEED = 1.0
"""Speed-dependent part of create_random's default spacing [s]."""
SPAWN_JITTER = (0.9, 1.1)
"""Uniform factor on the spawn offset [-]."""

TERMINATION_NONE = 0
"""Reason code: the episode goes on (or was truncated)."""
TERMINATION_COLLISION = 1
"""Reason code: the ego crashed."""
TERMINATION_OFFROAD = 2
"""Reason code: the ego's centre left its closest lane (the road)."""
TERMINATION_REASONS = ("", "collision", "offroad")
"""Reason code -> ``info["termination"]`` string of ``SrmpcHighwayEnv``."""

SimConstants = namedtuple(
    "SimConstants",
    [
        "vehicles",  # N = vehicles_count + 1 (ego stored last) [-]
        "vehicles_behind_ego",  # IDM vehicles spawned before the ego [-]
        "substeps",  # integration sub-steps per control step [-]
        "dt",  # integration step 1 / simulation_frequency [s]
        "episode_steps",  # truncation [control steps]
        "road_length",  # lane length [m]
        "speed_limit",  # lane speed limit, clip of IDM target speeds [m/s]
        "lane_count",  # lanes [-]
        "lane_width",  # [m]
        "steering_max",  # action box [rad]
        "acceleration_min",  # [m/s^2]
        "acceleration_max",  # [m/s^2]
        "perception_range",  # [m]
        "other_speed_min",  # [m/s]
        "other_speed_max",  # [m/s]
        "ego_speed_min",  # [m/s]
        "ego_speed_max",  # [m/s]
        "spawn_spacing",  # create_random's spacing = 1 / density [-]
        "vx_ref",  # reward reference speed [m/s]
        "y_ref",  # reward reference lateral position [m]
        "speed_weight",  # g [-]
        "reward_scale",  # [units of r']
        "si_sigma",  # [m]
        "si_d_min",  # [m]
        "si_edge_d_min",  # [m]
        "si_n",  # [-]
        "si_k",  # [s]
        "si_eta",  # [units of phi]
        "si_cost_floor",  # [units of phi]
        "si_rss",  # the RSS index (scenario.safety_index.kind == rss) instead of the paper's
        # RssParameters, field by field (a parallel kernel takes no tuple argument):
        "rss_response_time_ego",  # [s]
        "rss_response_time_others",  # [s]
        "rss_longitudinal_acceleration_max",  # [m/s^2]
        "rss_longitudinal_brake_min",  # [m/s^2]
        "rss_longitudinal_brake_max",  # [m/s^2]
        "rss_lateral_acceleration_max",  # [m/s^2]
        "rss_lateral_brake_min",  # [m/s^2]
        "rss_lateral_margin",  # [m]
    ],
)
"""Everything a kernel needs to know about the scenario (see :func:`sim_constants`)."""


def sim_constants(params: ScenarioParameters) -> SimConstants:
    """Flatten ``params`` (and the road geometry) into :data:`SimConstants`."""
    si, reward = params.safety_index, params.reward
    return SimConstants(
        vehicles=int(params.vehicles_count + 1),
        vehicles_behind_ego=int(params.vehicles_behind_ego),
        substeps=int(params.substeps),
        dt=1 / params.simulation_frequency_hz,  # as highway-env: 1 / simulation_frequency
        episode_steps=int(params.episode_steps),
        road_length=float(road.ROAD_LENGTH),
        speed_limit=float(road.SPEED_LIMIT),
        lane_count=int(road.LANE_COUNT),
        lane_width=float(road.LANE_WIDTH),
        steering_max=float(params.steering_max_rad),
        acceleration_min=float(params.acceleration_min_mps2),
        acceleration_max=float(params.acceleration_max_mps2),
        perception_range=float(params.perception_range_m),
        other_speed_min=float(params.other_speed_min_mps),
        other_speed_max=float(params.other_speed_max_mps),
        ego_speed_min=float(params.ego_speed_min_mps),
        ego_speed_max=float(params.ego_speed_max_mps),
        spawn_spacing=float(params.spawn_spacing),
        vx_ref=float(reward.vx_ref_mps),
        y_ref=float(road.LANE_CENTERS[road.RIGHT_LANE]),
        speed_weight=float(reward.speed_weight),
        reward_scale=float(reward.scale),
        si_sigma=float(si.sigma_m),
        si_d_min=float(si.d_min_m),
        si_edge_d_min=float(si.edge_d_min_m),
        si_n=float(si.n),
        si_k=float(si.k_s),
        si_eta=float(si.eta),
        si_cost_floor=float(si.cost_floor),
        si_rss=si.kind is SafetyIndexKind.rss,
        rss_response_time_ego=float(si.rss.response_time_ego_s),
        rss_response_time_others=float(si.rss.response_time_others_s),
        rss_longitudinal_acceleration_max=float(si.rss.longitudinal_acceleration_max_mps2),
        rss_longitudinal_brake_min=float(si.rss.longitudinal_brake_min_mps2),
        rss_longitudinal_brake_max=float(si.rss.longitudinal_brake_max_mps2),
        rss_lateral_acceleration_max=float(si.rss.lateral_acceleration_max_mps2),
        rss_lateral_brake_min=float(si.rss.lateral_brake_min_mps2),
        rss_lateral_margin=float(si.rss.lateral_margin_m),
    )
