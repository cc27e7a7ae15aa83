"""Geometry of the paper's straight three-lane highway (fixed by highway-env's straight road).

Coordinates are highway-env's: x [m] along the road in the driving direction, y [m] across it,
growing to the driver's *right*. Lane ``i`` has its centre at ``y = i * LANE_WIDTH``, so lane 0 is
the left lane and lane 2 the right lane, the paper's reference lane.
"""

import numpy as np

LANE_COUNT = 3
"""Number of lanes; the observation (3 lanes x leader/follower) is defined for exactly three."""
LANE_WIDTH = 4.0
"""Lane width [m] (highway-env's ``StraightLane.DEFAULT_WIDTH``)."""
LANE_CENTERS = np.arange(LANE_COUNT) * LANE_WIDTH
"""Lateral position of each lane centre [m]: 0, 4, 8."""
RIGHT_LANE = LANE_COUNT - 1
"""Index of the right lane, the paper's y_ref lane."""
LEFT_ROAD_EDGE = -LANE_WIDTH / 2
"""Lateral position of the left road edge [m]."""
RIGHT_ROAD_EDGE = LANE_CENTERS[-1] + LANE_WIDTH / 2
"""Lateral position of the right road edge [m]."""
ROAD_LENGTH = 10000.0
"""Length of highway-env's straight road [m]; vehicles cover < 4 km in an 80 s episode."""
SPEED_LIMIT = 30.0
"""Speed limit of every lane [m/s]; IDM target speeds are clipped to it."""

VEHICLE_LENGTH = 5.0
"""Length of every vehicle [m] (highway-env ``Vehicle.LENGTH``)."""
VEHICLE_WIDTH = 2.0
"""Width of every vehicle [m] (highway-env ``Vehicle.WIDTH``)."""
MAX_SPEED = 40.0
"""Speed above which highway-env clips acceleration [m/s]."""
