"""Named layout of the 12-element plant state and the 4-element pitch vector.

Frames are the paper's: position in earth NWU (z up), velocity and rates in body
FLU, ZYX Euler angles. Arrays are used in the hot path; these names are the only
way code refers to an element.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

# plant state x
X_N, Y_W, Z_U = 0, 1, 2  # position, earth NWU [m]
U_F, V_L, W_U = 3, 4, 5  # velocity, body FLU [m/s]
PHI, THETA, PSI = 6, 7, 8  # ZYX Euler angles [rad]
P_X, Q_Y, R_Z = 9, 10, 11  # body rates about FLU axes [rad/s]
N_STATE = 12
# each element's label (unit last): columns of tables and DataFrames, break points' names
STATE_NAMES = ("x_m", "y_m", "z_m", "u_m_s", "v_m_s", "w_m_s", "phi_rad", "theta_rad", "psi_rad",
               "p_rad_s", "q_rad_s", "r_rad_s")  # fmt: skip
POS = slice(X_N, Z_U + 1)
VEL = slice(U_F, W_U + 1)
EULER = slice(PHI, PSI + 1)
OMEGA = slice(P_X, R_Z + 1)

# control input u: blade pitches [rad]
THETA_M, THETA_T, EPS, ETA = 0, 1, 2, 3  # main collective, tail collective, long./lat. cyclic
N_PITCH = 4
PITCH_NAMES = ("theta_m", "theta_t", "eps", "eta")
PITCH_LABELS = tuple(f"{n}_rad" for n in PITCH_NAMES)  # the same with their unit


def _vec3(name: str, value: Sequence[float]) -> tuple[float, float, float]:
    if len(value) != 3:
        raise ValueError(f"{name} needs 3 components, got {len(value)}")
    x, y, z = (float(v) for v in value)
    return (x, y, z)


@dataclass(frozen=True)
class State:
    """The plant state with named, frame-and-unit-carrying fields."""

    pos_nwu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    vel_flu_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    euler_rad: tuple[float, float, float] = (0.0, 0.0, 0.0)
    omega_flu_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for name in ("pos_nwu_m", "vel_flu_m_s", "euler_rad", "omega_flu_rad_s"):
            object.__setattr__(self, name, _vec3(name, getattr(self, name)))

    def to_array(self) -> FloatArray:
        x = np.empty(N_STATE)
        x[POS] = self.pos_nwu_m
        x[VEL] = self.vel_flu_m_s
        x[EULER] = self.euler_rad
        x[OMEGA] = self.omega_flu_rad_s
        return x

    @classmethod
    def from_array(cls, x: npt.ArrayLike) -> State:
        a = np.asarray(x, dtype=float)
        if a.shape != (N_STATE,):
            raise ValueError(f"state array must have shape ({N_STATE},), got {a.shape}")
        return cls(
            tuple(a[POS]), tuple(a[VEL]), tuple(a[EULER]), tuple(a[OMEGA])  # type: ignore[arg-type]
        )
