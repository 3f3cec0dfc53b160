"""The air on the X-Cell: fuselage drag and rotor inflow in a relative wind (compiled).

Wind enters the plant only through these aerodynamic loads; the rigid body keeps its ground
velocity. Every velocity here is *air-relative* and in body FLU axes: ``V_a = V - R^T W``
(vehicle velocity minus wind), and at a body point ``r`` the local air-relative velocity is
``V_a + omega x r`` (:func:`hub_velocity_flu`). Hubs: main ``(lm, 0, hm)``, tail ``(-lt, 0, ht)``.

Fuselage (:func:`fuselage_force_flu`)
    Quadratic drag of three equivalent flat plates, frontal, side and vertical, whose areas
    ``S_x, S_y, S_z`` already contain the drag coefficient (the X-Cell model of Gavrilets,
    Mettler & Feron 2001 gives 0.10, 0.22, 0.15 m^2). The vertical plate sits in the main
    rotor's downwash, so its relative velocity is ``w_a + v_i``. The force acts at the c.g.:
    no aerodynamic moment is modelled.

Rotor inflow (:func:`rotor_inflow`)
    Uniform-inflow momentum theory (Glauert's form, valid in climb, hover, forward flight and
    moderate descent; Padfield, *Helicopter Flight Dynamics*, ch. 3) closed by blade-element
    thrust for untwisted blades with a constant lift slope ``a``; Gavrilets et al. add a wake
    factor ``eta_w`` to the momentum relation::

        C_T = (a s / 2) [theta (1/3 + mu^2/2) - (mu_z + lam)/2]
        lam = C_T / (2 eta_w sqrt(mu^2 + (lam + mu_z)^2))

    with ``mu`` the in-plane and ``mu_z`` the axial hub airspeed (positive in climb, i.e. along
    the thrust) over the tip speed ``Omega R``, and ``lam`` the induced inflow (positive down
    the thrust axis for positive thrust). Thrust ``T = C_T rho A (Omega R)^2`` and torque
    ``Q = C_Q rho A (Omega R)^2 R`` with ``C_Q = 1.13 C_T lam + C_T mu_z + s delta/8``.

Hover consistency (mu = mu_z = 0, eta_w = 1) with :mod:`heli_common.vehicle.rotor`
    The momentum relation becomes ``lam |lam| = C_T/2``; with ``tc = C_T/s`` the pair reads
    ``tc = a theta/6 - a lam/4``, ``lam = sqrt(s tc/2)``, the implicit form the hover map is
    derived from. Writing ``x = sqrt(tc)`` gives ``x^2 + (a/4) sqrt(s/2) x - a theta/6 = 0``
    whose positive root squared is ``tc = (1/4)[-(a/4) sqrt(s/2) + sqrt(a^2 s/32 + (2/3) a
    theta)]^2``: exactly ``thrust_coeff``. The torque is ``C_T lam = C_T^1.5/sqrt(2) =
    s tc^1.5 sqrt(s/2)``, so ``C_Q/s = delta/8 + 1.13 tc^1.5 sqrt(s/2) = torque_coeff(tc)``.
    With the plant's scales ``rho s A (Omega R)^2 [R]`` that means ``T = (C_T/s) thrust_scale``
    and ``Q = (C_Q/s) torque_scale``.

Negative thrust
    The two equations are odd under ``(theta, mu_z, lam, C_T) -> -(theta, mu_z, lam, C_T)``,
    so the solver works on the half with non-negative thrust and reflects back: the result
    is exactly odd, continuous through zero thrust (theta = 0 in hover), and reduces to the
    hover map's odd extension ``tc(-theta) = -tc(theta)``. ``C_Q`` is even.

Solver
    With ``K = (a s/2)[theta (1/3 + mu^2/2) - mu_z/2]`` (thrust at zero inflow), the root lies
    in ``[0, 4K/(a s)]`` (scaled by ``sign K``): the residual is ``-K`` at the lower end and
    ``>= 0`` at the upper one. Newton from the caller's previous ``lam`` is safeguarded by
    that shrinking bracket (bisection whenever a step leaves it or stalls), so it always
    terminates, in a bounded number of steps, at a root to ~1e-15 relative, and no finite
    input gives NaN. In fast descent (beyond about 2 v_h axially) momentum theory has several
    roots; the one reached then depends on ``lam_guess`` (a hysteresis), and the theory itself
    is not valid there: :func:`vortex_ring_flag` marks the region.

Near zero thrust in axial flow
    An unloaded disc is "in descent" relative to its own tiny induced velocity, so the same
    breakdown shows up there: at theta = 0, mu = 0 and |mu_z| < a s/8 the only root is
    ``lam = -mu_z``, ``C_T = 0`` (beyond it, the windmill-brake root ``lam = -sign(mu_z) a s/8``).
    T(theta) stays continuous but is not monotone near zero thrust (main rotor at 0.5 m/s
    climb: a dip to -0.29 N at theta = 0.0027 rad before thrust turns positive at 0.0058 rad).
"""

from __future__ import annotations

import math

from heli_common.jit import njit
from heli_common.vehicle.airframe import PlantConstants

_MAX_ITER = 100  # bisection alone reaches 1e-13 of the bracket in ~45 halvings
_REL_TOL = 1e-13  # a Newton step this small leaves an error ~ its square
# A Newton step ``s`` this small (relative) is taken as the last one when the error it leaves,
# ``|g''| s^2 / (2 g')`` (Newton's quadratic term, from the residual's curvature at the
# point), is below _LAST_ERR of lam, a quarter of an ulp: the confirming iteration that would
# follow could change the result by a rounding at most. Saves one of the ~3 iterations of a
# solve started from the previous stage's inflow (the plant solves 10 a tick: 0.3 us).
_QUAD_TOL = 1e-6
_LAST_ERR = 2.5e-17
_CLAMP = 1e6  # |mu|, |mu_z|, |theta| beyond this are not physics: clipped so nothing overflows


@njit
def hub_velocity_flu(
    u_a: float, v_a: float, w_a: float, p: float, q: float, r: float, rx: float, ry: float, rz: float
) -> tuple[float, float, float]:
    """Air-relative velocity [m/s, FLU] of the body point ``(rx, ry, rz)`` [m from the c.g.]:
    ``V_a + omega x r`` for c.g. air velocity ``(u_a, v_a, w_a)`` and body rates ``(p, q, r)``."""
    return (u_a + q * rz - r * ry, v_a + r * rx - p * rz, w_a + p * ry - q * rx)


@njit
def fuselage_force_flu(
    u_a: float, v_a: float, w_a: float, v_i: float, s_x: float, s_y: float, s_z: float, rho: float
) -> tuple[float, float, float]:
    """Fuselage drag [N, FLU] at the c.g.: ``-(rho/2) V_inf (S_x u_a, S_y v_a, S_z w_d)``.

    ``(u_a, v_a, w_a)``: c.g. air-relative velocity [m/s] (vehicle minus wind, body FLU);
    ``v_i``: main-rotor induced velocity [m/s], positive for downwash (down the thrust axis),
    so ``w_d = w_a + v_i``; ``V_inf = |(u_a, v_a, w_d)|``. ``S_*`` [m^2] are flat-plate
    areas that include the drag coefficient; ``rho`` [kg/m^3]. No moment is modelled.
    """
    w_d = w_a + v_i
    k = -0.5 * rho * math.sqrt(u_a * u_a + v_a * v_a + w_d * w_d)
    return (k * s_x * u_a, k * s_y * v_a, k * s_z * w_d)


@njit
def _clip(x: float) -> float:
    return max(-_CLAMP, min(x, _CLAMP))


@njit
def advance_ratios(u_h: float, v_h: float, w_h: float, tip_speed_m_s: float) -> tuple[float, float]:
    """(mu, mu_z): in-plane and axial (along the thrust) hub airspeed over the tip speed."""
    # not hypot: a library call, ~4x the latency of the square root on the tick's path; a
    # hub airspeed is nowhere near the ~1e154 m/s where the squares would overflow
    mu = min(math.sqrt(u_h * u_h + v_h * v_h) / tip_speed_m_s, _CLAMP)
    return mu, _clip(w_h / tip_speed_m_s)


@njit
def _solve_inflow(
    theta: float, mu: float, mu_z: float, lift_slope: float, solidity: float, eta_w: float, lam_guess: float
) -> tuple[float, float]:
    """(C_T, lam) for given advance ratios; see the module notes for the method."""
    half = 0.5 * lift_slope * solidity  # a s / 2
    quarter = 0.5 * half  # a s / 4 = -dC_T/dlam
    k = half * (_clip(theta) * (1.0 / 3.0 + 0.5 * mu * mu) - 0.5 * mu_z)
    if k == 0.0:
        return 0.0, 0.0
    sgn = 1.0 if k > 0.0 else -1.0
    kk, mz = sgn * k, sgn * mu_z  # the half with non-negative thrust: root in [0, kk/quarter]
    two_eta = 2.0 * eta_w
    lo, hi = 0.0, kk / quarter
    lam = sgn * lam_guess
    if not lo < lam < hi:  # no usable guess (first call, sign change): the hover-like estimate
        lam = min(math.sqrt(kk / two_eta), 0.5 * hi)
    dx_old = hi - lo
    for _ in range(_MAX_ITER):
        d = lam + mz
        qq = math.sqrt(mu * mu + d * d)  # not hypot (a library call): both are clipped to 1e6
        g = two_eta * lam * qq + quarter * lam - kk  # momentum minus blade-element thrust
        if g > 0.0:
            hi = lam
        elif g < 0.0:
            lo = lam
        else:
            break
        dg = two_eta * (qq + (lam * d / qq if qq > 0.0 else 0.0)) + quarter  # <= 0: multi-root region
        step = g / dg if dg > 0.0 else math.inf
        size = abs(step)
        if size <= _REL_TOL * lam:  # Newton's correction is below tolerance: take it, done
            lam -= step
            break
        if size <= _QUAD_TOL * lam and qq > 0.0:
            # g'' = 2 eta (2 d / q + lam mu^2 / q^3) (q'' = mu^2 / q^3); dg > 0 here
            d2g = two_eta * (2.0 * d + lam * mu * mu / (qq * qq)) / qq
            if abs(d2g) * size * size <= 2.0 * _LAST_ERR * lam * dg:
                lam -= step  # what is left after it is below a quarter of an ulp
                break
        new = lam - step
        if not lo < new < hi or size > 0.5 * dx_old:  # Newton leaves the bracket or stalls
            new = 0.5 * (lo + hi)
            step = lam - new
        dx_old = abs(step)
        lam = new
        if hi - lo <= _REL_TOL * hi:
            break
    # The two equal forms of C_T at the root: take the better conditioned. Blade element cancels
    # when C_T << (a s/4) lam (near zero thrust); momentum when lam + mu_z cancels (descent).
    if two_eta * max(lam, abs(mz)) <= 2.0 * quarter:
        d = lam + mz
        c_t = two_eta * lam * math.sqrt(mu * mu + d * d)  # both clipped to 1e6: no overflow
    else:
        c_t = kk - quarter * lam
    return sgn * c_t, sgn * lam


@njit
def rotor_inflow(
    theta: float,
    u_h: float,
    v_h: float,
    w_h: float,
    lift_slope: float,
    solidity: float,
    tip_speed_m_s: float,
    eta_w: float,
    lam_guess: float,
) -> tuple[float, float]:
    """(C_T, lam): thrust coefficient (on ``rho A (Omega R)^2``, so ``tc = C_T/s``) and
    induced inflow ratio ``v_i/(Omega R)`` of a rotor at collective ``theta`` [rad].

    ``(u_h, v_h)`` [m/s]: in-plane hub air velocity; ``w_h`` [m/s]: hub air velocity along the
    thrust axis (climb > 0). ``lift_slope`` [1/rad], ``solidity``, ``tip_speed_m_s = Omega R``
    (> 0), wake factor ``eta_w`` (> 0; 1 reproduces the hover map). ``lam_guess``: the
    previous ``lam`` (any value works; 0 means none). Odd in ``(theta, w_h, lam_guess)``.
    """
    mu, mu_z = advance_ratios(u_h, v_h, w_h, tip_speed_m_s)
    return _solve_inflow(theta, mu, mu_z, lift_slope, solidity, eta_w, lam_guess)


@njit
def rotor_torque_coeff(c_t: float, lam: float, mu_z: float, solidity: float, delta: float) -> float:
    """C_Q = Q/(rho A (Omega R)^2 R) = 1.13 C_T lam + C_T mu_z + s delta/8: induced (with the
    empirical 1.13 of the hover map), climb and profile torque. Even under thrust reversal;
    in hover it equals ``heli_common.vehicle.rotor.torque_coeff(C_T/s) * s``."""
    return 1.13 * c_t * lam + c_t * mu_z + solidity * delta / 8.0


@njit
def hover_inflow(c_t: float, eta_w: float) -> float:
    """Hover inflow ratio at thrust coefficient ``c_t``: ``sign(c_t) sqrt(|c_t|/(2 eta_w))``."""
    return math.copysign(math.sqrt(abs(c_t) / (2.0 * eta_w)), c_t)


@njit
def vortex_ring_flag(mu: float, mu_z: float, lam_hover: float) -> bool:
    """True where uniform-inflow momentum theory is not to be trusted: near-axial descent
    (``mu < 0.05``) faster than a quarter of the hover inflow (``mu_z < -0.25 lam_hover``).
    For negative thrust (``lam_hover < 0``) the mirrored condition (``mu_z > 0.25 |lam_hover|``)."""
    return mu < 0.05 and math.copysign(1.0, lam_hover) * mu_z < -0.25 * abs(lam_hover)


@njit
def rotor_loads_from_ratios(
    theta: float, mu: float, mu_z: float, a: float, s: float, delta: float, thrust_scale: float,
    torque_scale: float, tip_speed_m_s: float, eta_w: float, lam_guess: float,
) -> tuple[float, float, float, float]:  # fmt: skip
    """(thrust [N], torque [N m], lam, v_i [m/s]) of one rotor from its advance ratios."""
    c_t, lam = _solve_inflow(theta, mu, mu_z, a, s, eta_w, lam_guess)
    c_q = rotor_torque_coeff(c_t, lam, mu_z, s, delta)
    return (c_t / s) * thrust_scale, (c_q / s) * torque_scale, lam, lam * tip_speed_m_s


@njit
def main_rotor_loads_in_air(
    theta_m: float,
    u_h: float,
    v_h: float,
    w_h: float,
    c: PlantConstants,
    tip_speed_m_s: float,
    eta_w: float,
    lam_guess: float,
) -> tuple[float, float, float, float]:
    """(Tm [N] along +z body, Qm [N m], lam, v_i [m/s]) of the main rotor.

    ``(u_h, v_h, w_h)``: main-hub air-relative velocity, body FLU [m/s] (thrust axis = +z, so
    ``w_h`` is the climb component); ``tip_speed_m_s = Omega_m R_m``. With zero relative air
    this is :func:`heli_plant.dynamics.rotor_loads`' main rotor (for ``eta_w = 1``).
    ``v_i = lam Omega R`` is the downwash :func:`fuselage_force_flu` takes.
    """
    mu, mu_z = advance_ratios(u_h, v_h, w_h, tip_speed_m_s)
    return rotor_loads_from_ratios(theta_m, mu, mu_z, c.a_m, c.s_m, c.delta, c.thrust_scale_m,
                                   c.torque_scale_m, tip_speed_m_s, eta_w, lam_guess)  # fmt: skip


@njit
def tail_rotor_loads_in_air(
    theta_t: float,
    u_h: float,
    v_h: float,
    w_h: float,
    c: PlantConstants,
    tip_speed_m_s: float,
    eta_w: float,
    lam_guess: float,
) -> tuple[float, float, float, float]:
    """(Tt [N] along -y body, Qt [N m], lam, v_i [m/s]) of the tail rotor.

    ``(u_h, v_h, w_h)``: tail-hub air-relative velocity, body FLU [m/s] (from
    :func:`hub_velocity_flu` at ``(-lt, 0, ht)``). The thrust axis is -y body, so the axial
    (climb) speed is ``-v_h = -v_a + r lt + p ht`` and the in-plane speed is ``|(u_h, w_h)|``
    with ``u_h = u_a + q ht``, ``w_h = w_a + q lt``. ``tip_speed_m_s = Omega_t R_t``.
    """
    mu, mu_z = advance_ratios(u_h, w_h, -v_h, tip_speed_m_s)
    return rotor_loads_from_ratios(theta_t, mu, mu_z, c.a_t, c.s_t, c.delta, c.thrust_scale_t,
                                   c.torque_scale_t, tip_speed_m_s, eta_w, lam_guess)  # fmt: skip


@njit
def rotor_loads_in_air(
    theta_m: float,
    theta_t: float,
    u_a: float,
    v_a: float,
    w_a: float,
    p: float,
    q: float,
    r: float,
    c: PlantConstants,
    tip_speed_m: float,
    tip_speed_t: float,
    eta_w: float,
    lam_m_guess: float,
    lam_t_guess: float,
) -> tuple[float, float, float, float, float, float]:
    """(Tm, Qm, Tt, Qt, lam_m, lam_t): :func:`heli_plant.dynamics.rotor_loads` in a relative
    wind, from the c.g. air velocity ``(u_a, v_a, w_a)`` [m/s, FLU] and body rates [rad/s].
    Hubs at ``(lm, 0, hm)`` and ``(-lt, 0, ht)``; the main downwash is ``lam_m * tip_speed_m``."""
    um, vm, wm = hub_velocity_flu(u_a, v_a, w_a, p, q, r, c.lm, 0.0, c.hm)
    ut, vt, wt = hub_velocity_flu(u_a, v_a, w_a, p, q, r, -c.lt, 0.0, c.ht)
    tm, qm, lam_m, _ = main_rotor_loads_in_air(theta_m, um, vm, wm, c, tip_speed_m, eta_w, lam_m_guess)
    tt, qt, lam_t, _ = tail_rotor_loads_in_air(theta_t, ut, vt, wt, c, tip_speed_t, eta_w, lam_t_guess)
    return tm, qm, tt, qt, lam_m, lam_t
