"""srmpc: Safety Reinforced Model Predictive Control (Fischer et al., ITSC 2023), reproduced.

Importing the package registers the scenario with gymnasium as ``srmpc/Highway-v0``.
"""

import gymnasium

SCENARIO_ID = "srmpc/Highway-v0"

if SCENARIO_ID not in gymnasium.registry:
    gymnasium.register(id=SCENARIO_ID, entry_point="srmpc.scenario.highway:SrmpcHighwayEnv")

__all__ = ["SCENARIO_ID"]
