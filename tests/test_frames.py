"""Frame conversions NWU/FLU <-> NED/FRD (heli_common.frames), both ways, and the rotation
identity they rest on: T Rt(phi, theta, psi) T = Rt(phi, -theta, -psi), T = diag(1, -1, -1)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.spatial.transform import Rotation

from heli_common import frames
from heli_common.kinematics import rot_body_to_earth, wrap_pi
from heli_common.state import EULER, N_STATE, OMEGA, POS, VEL

T = np.diag([1.0, -1.0, -1.0])
PI = math.pi

coord = st.floats(-1e5, 1e5, allow_nan=False)
vec3 = st.tuples(coord, coord, coord)
roll = st.floats(-PI, PI)
pitch = st.floats(-1.5, 1.5)  # |theta| < pi/2, away from gimbal lock
yaw_any = st.floats(-20.0, 20.0)  # several turns, to exercise the wrap
yaw = st.floats(-PI, PI)
euler = st.tuples(roll, pitch, yaw_any)


# wrap_pi can land 1 ulp above pi (see test_wrap_pi_just_above_minus_pi); the properties
# below allow that ulp so they test everything else.
ULP = 1e-15


def in_range(a: float) -> bool:
    return -PI < a <= PI + ULP


def ang_diff(a: float, b: float) -> float:
    return abs(wrap_pi(a - b))


def quat_to_matrix(q: tuple[float, float, float, float]) -> np.ndarray:
    """Hamilton (w, x, y, z) unit quaternion -> the rotation matrix it applies (body -> earth)."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


# --- T and the rotation identity -----------------------------------------------------------------


@given(vec3)
def test_flip_is_T_and_self_inverse(v: tuple[float, float, float]) -> None:
    assert_allclose(frames.nwu_to_ned(v), T @ np.array(v), rtol=0, atol=0)
    assert_allclose(frames.flu_to_frd(v), T @ np.array(v), rtol=0, atol=0)
    assert frames.ned_to_nwu(frames.nwu_to_ned(v)) == tuple(float(c) for c in v)
    assert frames.frd_to_flu(frames.flu_to_frd(v)) == tuple(float(c) for c in v)


def test_named_axes() -> None:
    # north stays north, west becomes -east, up becomes -down
    assert frames.nwu_to_ned((1.0, 2.0, 3.0)) == (1.0, -2.0, -3.0)
    # forward stays forward, left becomes -right, up becomes -down
    assert frames.flu_to_frd((4.0, 5.0, 6.0)) == (4.0, -5.0, -6.0)


@given(euler)
def test_rt_matches_scipy_intrinsic_zyx(e: tuple[float, float, float]) -> None:
    """Rt(gamma) = Rz(psi) Ry(theta) Rx(phi), checked against an independent implementation."""
    phi, theta, psi = e
    ref = Rotation.from_euler("ZYX", [psi, theta, phi]).as_matrix()
    assert_allclose(rot_body_to_earth(phi, theta, psi), ref, atol=1e-12)


@given(euler)
def test_T_Rt_T_is_Rt_with_pitch_and_yaw_negated(e: tuple[float, float, float]) -> None:
    phi, theta, psi = e
    lhs = T @ rot_body_to_earth(phi, theta, psi) @ T
    assert_allclose(lhs, rot_body_to_earth(phi, -theta, -psi), atol=1e-12)
    # and it is a proper rotation
    assert_allclose(lhs @ lhs.T, np.eye(3), atol=1e-12)
    assert math.isclose(np.linalg.det(lhs), 1.0, rel_tol=1e-12)


# --- Euler angles --------------------------------------------------------------------------------


@given(euler)
def test_euler_flu_frd_round_trip(e: tuple[float, float, float]) -> None:
    frd = frames.euler_flu_to_frd(e)
    assert frd[0] == e[0]
    assert frd[1] == -e[1]
    assert ang_diff(frd[2], -e[2]) < 1e-12
    assert in_range(frd[2])  # MAVLink ATTITUDE yaw range
    back = frames.euler_frd_to_flu(frd)
    assert back[0] == e[0]
    assert back[1] == e[1]
    assert ang_diff(back[2], e[2]) < 1e-12
    assert in_range(back[2])


@given(st.tuples(roll, pitch, yaw))
def test_euler_frd_flu_round_trip(e: tuple[float, float, float]) -> None:
    back = frames.euler_flu_to_frd(frames.euler_frd_to_flu(e))
    assert back[0] == e[0] and back[1] == e[1]
    assert ang_diff(back[2], e[2]) < 1e-12


@given(euler, vec3)
def test_euler_conversion_rotates_vectors_consistently(
    e: tuple[float, float, float], v_body: tuple[float, float, float]
) -> None:
    """A body vector taken to earth in NWU/FLU, then to NED, equals the same vector taken to
    FRD then to earth with the converted angles (the frames agree on what the attitude is)."""
    v_earth_nwu = rot_body_to_earth(*e) @ np.array(v_body)
    via_nwu = frames.nwu_to_ned(v_earth_nwu)
    via_frd = rot_body_to_earth(*frames.euler_flu_to_frd(e)) @ np.array(frames.flu_to_frd(v_body))
    assert_allclose(via_nwu, via_frd, atol=1e-9 * (1.0 + np.linalg.norm(v_body)))


def test_wrap_pi_edges() -> None:
    assert wrap_pi(PI) == PI
    assert wrap_pi(-PI) == PI
    assert wrap_pi(0.0) == 0.0
    assert math.isclose(wrap_pi(3 * PI / 2), -PI / 2)
    assert math.isclose(wrap_pi(-3 * PI / 2), PI / 2)
    assert frames.euler_flu_to_frd((0.0, 0.0, PI))[2] == PI
    assert frames.euler_flu_to_frd((0.0, 0.0, -PI))[2] == PI


def test_wrap_pi_just_above_minus_pi() -> None:
    a = math.nextafter(-PI, 0.0)
    assert -PI < wrap_pi(a) <= PI
    assert -PI < frames.euler_flu_to_frd((0.0, 0.0, -a))[2] <= PI


@given(st.floats(-1e4, 1e4))
def test_wrap_pi_range_and_congruence(a: float) -> None:
    w = wrap_pi(a)
    assert in_range(w)
    k = (a - w) / (2 * PI)
    assert abs(k - round(k)) < 1e-9


# --- quaternions ---------------------------------------------------------------------------------


@given(euler)
def test_quaternion_euler_round_trip(e: tuple[float, float, float]) -> None:
    q = frames.euler_to_quaternion(*e)
    assert math.isclose(math.fsum(c * c for c in q), 1.0, rel_tol=1e-12)
    # the quaternion applies the same body -> earth rotation as Rt (Hamilton, as MAVLink)
    assert_allclose(quat_to_matrix(q), rot_body_to_earth(*e), atol=1e-12)
    r, p, y = frames.quaternion_to_euler(q)
    assert ang_diff(r, e[0]) < 1e-9
    assert abs(p - e[1]) < 1e-9
    assert ang_diff(y, e[2]) < 1e-9
    # -q is the same attitude
    r2, p2, y2 = frames.quaternion_to_euler(tuple(-c for c in q))
    assert ang_diff(r2, r) < 1e-12 and abs(p2 - p) < 1e-12 and ang_diff(y2, y) < 1e-12


@given(
    st.tuples(*(st.floats(-1.0, 1.0) for _ in range(4))).filter(
        lambda q: math.sqrt(sum(c * c for c in q)) > 0.1
    )
)
def test_quaternion_to_euler_to_quaternion(q: tuple[float, float, float, float]) -> None:
    """Any (non-normalised) quaternion away from gimbal lock survives q -> euler -> q up to sign."""
    n = math.sqrt(sum(c * c for c in q))
    qn = np.array(q) / n
    e = frames.quaternion_to_euler(q)
    if abs(e[1]) > 1.5:  # gimbal lock region: roll and yaw are ill-conditioned
        return
    back = np.array(frames.euler_to_quaternion(*e))
    sign = 1.0 if float(back @ qn) >= 0 else -1.0
    assert_allclose(sign * back, qn, atol=1e-9)


# --- whole state ---------------------------------------------------------------------------------


@settings(max_examples=50)
@given(vec3, vec3, euler, vec3)
def test_state_round_trip(
    pos: tuple[float, float, float],
    vel: tuple[float, float, float],
    e: tuple[float, float, float],
    om: tuple[float, float, float],
) -> None:
    x = np.empty(N_STATE)
    x[POS], x[VEL], x[EULER], x[OMEGA] = pos, vel, e, om
    p_ned, v_frd, e_frd, w_frd = frames.state_nwu_to_ned(x)
    assert p_ned == (pos[0], -pos[1], -pos[2])
    assert v_frd == (vel[0], -vel[1], -vel[2])
    assert w_frd == (om[0], -om[1], -om[2])  # p, -q, -r
    assert e_frd[0] == e[0] and e_frd[1] == -e[1]
    back = frames.state_ned_to_nwu(p_ned, v_frd, e_frd, w_frd)
    assert_allclose(back[POS], pos, rtol=0, atol=0)
    assert_allclose(back[VEL], vel, rtol=0, atol=0)
    assert_allclose(back[OMEGA], om, rtol=0, atol=0)
    assert back[6] == e[0] and back[7] == e[1]
    assert ang_diff(back[8], e[2]) < 1e-12


@given(euler, vec3)
def test_body_rates_map_like_vectors(e: tuple[float, float, float], om: tuple[float, float, float]) -> None:
    """omega_FRD = T omega_FLU is the rate of the FRD attitude: d/dt of T Rt T is
    (T Rt T) [T omega]x exactly when Rt' = Rt [omega]x."""
    w = np.array(om)
    sk = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    rt_dot = rot_body_to_earth(*e) @ sk
    w_frd = np.array(frames.flu_to_frd(om))
    sk_frd = np.array([[0, -w_frd[2], w_frd[1]], [w_frd[2], 0, -w_frd[0]], [-w_frd[1], w_frd[0], 0]])
    lhs = T @ rt_dot @ T
    rhs = rot_body_to_earth(*frames.euler_flu_to_frd(e)) @ sk_frd
    assert_allclose(lhs, rhs, atol=1e-9 * (1 + np.abs(w).max()))


@pytest.mark.parametrize("q", [(0.0, 0.0, 0.0, 0.0), (float("nan"), 0.0, 0.0, 1.0)])
def test_a_zero_or_nan_quaternion_is_a_clear_error(q: tuple[float, float, float, float]) -> None:
    with pytest.raises(ValueError, match="quaternion"):
        frames.quaternion_to_euler(q)


@settings(max_examples=100)
@given(
    st.lists(st.floats(-50, 50), min_size=6, max_size=6),
    st.tuples(st.floats(-1.4, 1.4), st.floats(-1.4, 1.4), st.floats(-6.3, 6.3)),
    st.lists(st.floats(-5, 5), min_size=3, max_size=3),
)
def test_compiled_whole_state_conversion_matches_and_inverts(pv, euler, omega) -> None:  # type: ignore[no-untyped-def]
    from heli_common.kinematics import rot_body_to_earth

    x = np.array([*pv[:3], *pv[3:], *euler, *omega])
    f = frames.state_to_ned_fields(x)
    pos, _, eul, om = frames.state_nwu_to_ned(x)
    np.testing.assert_allclose(f[0:3], eul, atol=1e-12)
    np.testing.assert_allclose(f[3:6], om, atol=1e-12)
    np.testing.assert_allclose(f[6:10], frames.euler_to_quaternion(*eul), atol=1e-12)
    np.testing.assert_allclose(f[10:13], pos, atol=1e-12)
    v_nwu = rot_body_to_earth(*euler) @ x[3:6]
    np.testing.assert_allclose(f[13:16], frames.nwu_to_ned(v_nwu), atol=1e-9)
    y = frames.state_from_ned_fields(*f[0:6], *f[10:16])
    expect = x.copy()
    expect[8] = frames.wrap_pi(expect[8])
    np.testing.assert_allclose(y, expect, atol=1e-9)
