"""Units — the one place that fixes them.

* **Observations, goals, tip positions, metrics**: metres and radians, world frame, *real* (dVRK) size.
  Table top is at z = 0.675 m; the 5 mm success tolerance is 0.005.
* **Simulation**: the PyBullet scene of PSM tasks is built ``SCALING`` = 5 times larger than real
  (as in the original SurRoL, for stabler contacts of millimetre-sized objects). Only
  :mod:`surrol_data.envs` sees scaled units; everything it returns is converted back with :func:`to_real`.
* **Actions**: dimensionless in [-1, 1]; 1 = 1 cm of tool-tip motion per step (``ACTION_POSITION_M``),
  yaw 1 = ``ACTION_YAW_RAD`` per step; jaw < 0 closes.
* **Time**: one env step = ``CONTROL_PERIOD_S`` = 0.2 s of simulated time.
* **Metrics**: path lengths are reported in centimetres (economy of motion), times in seconds.
"""

import numpy as np

SCALING = 5.0
CONTROL_PERIOD_S = 0.2
ACTION_POSITION_M = 0.01
ACTION_YAW_RAD = np.deg2rad(30.0)
SUCCESS_TOLERANCE_M = 0.005


def to_real(x):
    """Scaled simulation units → real metres."""
    return np.asarray(x, dtype=np.float64) / SCALING


def to_sim(x):
    """Real metres → scaled simulation units."""
    return np.asarray(x, dtype=np.float64) * SCALING
