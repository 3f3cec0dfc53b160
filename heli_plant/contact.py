"""Ground contact: a flat rigid ground at z = 0 (NWU) that the skids cannot go through.

Kept deliberately simple (the paper has none): when the c.g. would go below the ground
the vehicle is put back on it, its velocity into the ground is removed, and while it rests
there attitude and rates are levelled, as skids on flat ground do. Lift-off is free.
"""

from __future__ import annotations

import math

from heli_common.jit import njit
from heli_common.kinematics import rot_body_to_earth
from heli_common.state import P_X, PHI, PSI, Q_Y, R_Z, THETA, U_F, V_L, W_U, X_N, Y_W, Z_U, FloatArray

GROUND_Z_M = 0.0


@njit
def apply_ground_contact(x: FloatArray, x_before: FloatArray) -> bool:
    """Project ``x`` (in place) onto the admissible set; True if the vehicle rests on the ground.
    ``x_before`` is the state at the start of the step: while resting, skid friction keeps its
    horizontal position and yaw (the step's own integration would let them creep)."""
    if x[Z_U] > GROUND_Z_M:
        return False
    rt = rot_body_to_earth(x[PHI], x[THETA], x[PSI])
    vz_earth = rt[2, 0] * x[U_F] + rt[2, 1] * x[V_L] + rt[2, 2] * x[W_U]
    if x[Z_U] == GROUND_Z_M and vz_earth > 0.0:
        return False  # lifting off
    x[Z_U] = GROUND_Z_M
    # resting on skids: level, no sliding, no rotation except yaw held
    x[PHI] = 0.0
    x[THETA] = 0.0
    x[U_F] = 0.0
    x[V_L] = 0.0
    x[W_U] = max(0.0, vz_earth) if math.isfinite(vz_earth) else 0.0
    x[P_X] = 0.0
    x[Q_Y] = 0.0
    x[R_Z] = 0.0
    if x_before[Z_U] <= GROUND_Z_M:  # already resting before the step: nothing slides
        x[X_N] = x_before[X_N]
        x[Y_W] = x_before[Y_W]
        x[PSI] = x_before[PSI]
    return True
