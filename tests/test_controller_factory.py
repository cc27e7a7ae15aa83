"""srmpc.controller_factory: the planner's defaults are the OCP's own, whatever route a config takes."""

from __future__ import annotations

from srmpc.config.compose import compose_config, to_objects
from srmpc.config.schema import Config
from srmpc.controller_factory import planner_ocp
from srmpc.mpc.problem import CollisionGeometry, OcpConfig, TrackingWeights
from srmpc.mpc.solvers import DEFAULT_SOLVER


def test_default_planner_builds_the_ocps_own_defaults():
    """conf/planner/ltv_mpc.yaml and PlannerConfig repeat no number of srmpc/mpc/problem/ocp.py: composed or
    constructed, the default planner gives OcpConfig's horizon, slots, weights and geometry."""
    for config in (Config(), to_objects(compose_config(["tracking.enabled=false"]))):
        ocp, _ = planner_ocp(config)
        assert ocp.weights == TrackingWeights()
        assert ocp.geometry == CollisionGeometry()
        assert (ocp.horizon, ocp.max_vehicles) == (OcpConfig().horizon, OcpConfig().max_vehicles)
        assert config.planner.solver == DEFAULT_SOLVER


def test_a_planner_option_changes_only_what_it_names():
    ocp, _ = planner_ocp(to_objects(compose_config(["planner=margin_1m_speed_weight_2"])))
    assert ocp.geometry == CollisionGeometry(safety_margin_longitudinal_m=1.0)
    assert ocp.weights == TrackingWeights(state=(0.0, 0.5, 20.0, 2.0))
