"""The only place frames change: the paper's NWU/FLU <-> MAVLink's NED/FRD.

T = diag(1, -1, -1) maps both earth NWU -> NED and body FLU -> FRD, and it is its own
inverse. ZYX Euler angles map as (phi, theta, psi) -> (phi, -theta, -psi) because
T Rz(psi) Ry(theta) Rx(phi) T = Rz(-psi) Ry(-theta) Rx(phi). Yaw is wrapped to
(-pi, pi] on the MAVLink side, as ATTITUDE carries it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TypeAlias

import numpy as np

from heli_common.jit import njit
from heli_common.kinematics import rot_body_to_earth, wrap_pi
from heli_common.layout import Layout
from heli_common.state import EULER, N_STATE, OMEGA, POS, VEL, FloatArray

Vec3 = tuple[float, float, float]
VecIn: TypeAlias = Sequence[float] | FloatArray  # anything with 3 indexable numbers


def flip(v: VecIn) -> Vec3:
    """Apply T = diag(1, -1, -1): NWU <-> NED and FLU <-> FRD (self-inverse)."""
    return (float(v[0]), -float(v[1]), -float(v[2]))


nwu_to_ned = flip
ned_to_nwu = flip
flu_to_frd = flip
frd_to_flu = flip
_T_DIAG = np.array([1.0, -1.0, -1.0])


def flip_rows(a: FloatArray) -> FloatArray:
    """T applied to each row of an (n, 3) array (NWU <-> NED, FLU <-> FRD)."""
    out: FloatArray = np.asarray(a, dtype=float) * _T_DIAG
    return out


def euler_flu_to_frd(euler_rad: VecIn) -> Vec3:
    """(phi, theta, psi) in NWU/FLU -> (roll, pitch, yaw) in NED/FRD, yaw in (-pi, pi]."""
    return (float(euler_rad[0]), -float(euler_rad[1]), wrap_pi(-float(euler_rad[2])))


def euler_frd_to_flu(euler_rad: VecIn) -> Vec3:
    """(roll, pitch, yaw) in NED/FRD -> (phi, theta, psi) in NWU/FLU, psi in (-pi, pi]."""
    return (float(euler_rad[0]), -float(euler_rad[1]), wrap_pi(-float(euler_rad[2])))


def euler_to_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """ZYX Euler angles -> unit quaternion (w, x, y, z), Hamilton convention, as MAVLink."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def quaternion_to_euler(q: VecIn) -> Vec3:
    """Unit quaternion (w, x, y, z) -> ZYX (roll, pitch, yaw)."""
    w, x, y, z = (float(v) for v in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (math.isfinite(n) and n > 0.0):
        raise ValueError(f"not a rotation quaternion: {tuple(q)}")
    w, x, y, z = w / n, x / n, y / n, z / n
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return (roll, pitch, yaw)


def state_nwu_to_ned(x: FloatArray) -> tuple[Vec3, Vec3, Vec3, Vec3]:
    """Plant state -> (pos_ned_m, vel_frd_m_s, euler_frd_rad, omega_frd_rad_s)."""
    return (
        nwu_to_ned(x[POS]),
        flu_to_frd(x[VEL]),
        euler_flu_to_frd(x[EULER]),
        flu_to_frd(x[OMEGA]),
    )


def state_ned_to_nwu(
    pos_ned_m: VecIn,
    vel_frd_m_s: VecIn,
    euler_frd_rad: VecIn,
    omega_frd_rad_s: VecIn,
) -> FloatArray:
    """(pos_ned_m, vel_frd_m_s, euler_frd_rad, omega_frd_rad_s) -> plant state array."""
    x = np.empty(N_STATE)
    x[POS] = ned_to_nwu(pos_ned_m)
    x[VEL] = frd_to_flu(vel_frd_m_s)
    x[EULER] = euler_frd_to_flu(euler_frd_rad)
    x[OMEGA] = frd_to_flu(omega_frd_rad_s)
    return x


# -- compiled whole-state conversions for the links' hot path ---------------------------
# the fields of ATTITUDE, HIL_STATE_QUATERNION and LOCAL_POSITION_NED in one flat array
NED_FIELDS = Layout(
    "NED fields",
    ("euler_frd", 3),  # roll, pitch, yaw [rad]
    ("rates_frd", 3),  # p, q, r [rad/s]
    ("quat", 4),  # qw, qx, qy, qz
    ("pos_ned", 3),  # north, east, down [m]
    ("vel_ned", 3),  # earth-frame velocity, as LOCAL_POSITION_NED carries it [m/s]
)
NF_EULER = NED_FIELDS.offset("euler_frd")
NF_RATES = NED_FIELDS.offset("rates_frd")
NF_QUAT = NED_FIELDS.offset("quat")
NF_POS = NED_FIELDS.offset("pos_ned")
NF_VEL = NED_FIELDS.offset("vel_ned")
N_NED_FIELDS = NED_FIELDS.size


@njit
def state_to_ned_fields(x: FloatArray) -> FloatArray:
    """Plant state (NWU/FLU) -> the NED/FRD fields of ATTITUDE, LOCAL_POSITION_NED and the
    HIL_STATE_QUATERNION quaternion, in one compiled call."""
    out = np.empty(N_NED_FIELDS)
    phi, theta, psi = x[EULER.start], x[EULER.start + 1], x[EULER.start + 2]
    roll, pitch, yaw = phi, -theta, wrap_pi(-psi)
    out[NF_EULER], out[NF_EULER + 1], out[NF_EULER + 2] = roll, pitch, yaw
    w = OMEGA.start
    out[NF_RATES], out[NF_RATES + 1], out[NF_RATES + 2] = x[w], -x[w + 1], -x[w + 2]
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    out[NF_QUAT] = cr * cp * cy + sr * sp * sy
    out[NF_QUAT + 1] = sr * cp * cy - cr * sp * sy
    out[NF_QUAT + 2] = cr * sp * cy + sr * cp * sy
    out[NF_QUAT + 3] = cr * cp * sy - sr * sp * cy
    out[NF_POS], out[NF_POS + 1], out[NF_POS + 2] = x[POS.start], -x[POS.start + 1], -x[POS.start + 2]
    v = rot_body_to_earth(phi, theta, psi) @ x[VEL]
    out[NF_VEL], out[NF_VEL + 1], out[NF_VEL + 2] = v[0], -v[1], -v[2]
    return out


@njit
def state_from_ned_fields(
    roll: float, pitch: float, yaw: float, p: float, q: float, r: float,
    north: float, east: float, down: float, vn: float, ve: float, vd: float,
) -> FloatArray:  # fmt: skip
    """ATTITUDE and LOCAL_POSITION_NED fields (NED/FRD) -> plant state (NWU/FLU)."""
    x = np.empty(N_STATE)
    phi, theta, psi = roll, -pitch, wrap_pi(-yaw)
    x[POS.start], x[POS.start + 1], x[POS.start + 2] = north, -east, -down
    x[EULER.start], x[EULER.start + 1], x[EULER.start + 2] = phi, theta, psi
    x[OMEGA.start], x[OMEGA.start + 1], x[OMEGA.start + 2] = p, -q, -r
    v_nwu = np.array([vn, -ve, -vd])
    x[VEL] = rot_body_to_earth(phi, theta, psi).T @ v_nwu
    return x
