"""srmpc: Safety Reinforced Model Predictive Control (Fischer et al., ITSC 2023), reproduced.

Importing the package first applies the numeric environment that ``SRMPC_NUMERICS`` asks for
(:mod:`srmpc.numerics`: pinned before numpy or torch load), then registers the scenario with
gymnasium as ``srmpc/Highway-v0``.
"""

import sys

from srmpc.numerics import NumericsError, pin_process

try:
    pin_process()
except NumericsError as error:  # a bad SRMPC_NUMERICS, a CPU without AVX2: one line, no traceback
    print(f"srmpc: config error: {error}", file=sys.stderr)
    raise SystemExit(2) from None

import gymnasium  # noqa: E402  (after the pin: gymnasium loads numpy)

SCENARIO_ID = "srmpc/Highway-v0"

if SCENARIO_ID not in gymnasium.registry:
    gymnasium.register(id=SCENARIO_ID, entry_point="srmpc.scenario.highway:SrmpcHighwayEnv")

__all__ = ["SCENARIO_ID"]
