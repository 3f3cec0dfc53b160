"""The reference the controller follows, named once: what a trajectory evaluates to, what
the flight modes hand the controller, what telemetry reports.

As a flat 9-vector (the compiled kernels' layout): ``REF_POS``, ``REF_VEL``, ``REF_ACC``,
earth NWU, SI units; NaN in a derivative means "not known" (the controller's
pseudo-differentiators estimate it). The yaw command is not part of it: the controller
forms it from the path's heading (yaw augmentation) and reports it beside the pitches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from heli_common.layout import Layout
from heli_common.state import FloatArray

REFERENCE = Layout("reference", ("pos_m", 3), ("vel_m_s", 3), ("acc_m_s2", 3))
N_REF = REFERENCE.size
# first index of each part (the compiled kernels use these)
POS_0 = REFERENCE.offset("pos_m")
VEL_0 = REFERENCE.offset("vel_m_s")
ACC_0 = REFERENCE.offset("acc_m_s2")
REF_POS = slice(POS_0, POS_0 + REFERENCE.size_of("pos_m"))  # [m]
REF_VEL = slice(VEL_0, VEL_0 + REFERENCE.size_of("vel_m_s"))  # [m/s]
REF_ACC = slice(ACC_0, ACC_0 + REFERENCE.size_of("acc_m_s2"))  # [m/s^2]
REF_DERIVATIVES = slice(VEL_0, REF_ACC.stop)


@dataclass(frozen=True)
class Reference:
    """One reference, with named fields (the 9-vector's readable form)."""

    pos_nwu_m: FloatArray
    vel_nwu_m_s: FloatArray
    acc_nwu_m_s2: FloatArray

    @classmethod
    def from_row(cls, row: FloatArray) -> Reference:
        return cls(row[REF_POS], row[REF_VEL], row[REF_ACC])

    def as_array(self) -> FloatArray:
        return np.concatenate([self.pos_nwu_m, self.vel_nwu_m_s, self.acc_nwu_m_s2])


def position_reference(pos_nwu_m: FloatArray) -> FloatArray:
    """Hold ``pos_nwu_m``: zero velocity and acceleration."""
    ref = np.zeros(N_REF)
    ref[REF_POS] = pos_nwu_m
    return ref
