"""Wind: air velocity in the earth frame, ``W = W_mean + W_gust + W_turb`` (NWU, m/s).

Three independent pieces, each a small pure function the plant composes:

* :func:`heli_common.world.gusts.mean_wind_nwu` maps ArduPilot's ``SIM_WIND_SPD`` / ``_DIR`` / ``_DIR_Z``
  to a steady air velocity.
* :func:`heli_common.world.gusts.gust_factor` is the shape of a discrete gust, 0..1: the 1-cosine rise
  of MIL-F-8785C (also the MathWorks Discrete Wind Gust Model), optionally held and then ramped down with a
  cosine as in JSBSim's ``FGWinds::CosineGustProfile``. The caller scales a fixed earth
  direction by ``V_m * gust_factor``.
* Dryden turbulence (MIL-F-8785C low-altitude model, the form JSBSim's ``FGWinds`` quotes):
  :func:`dryden_low_altitude` gives scale lengths and intensities from height and the wind at
  20 ft; :func:`dryden_coefficients` discretises the forming filters exactly for one step;
  :func:`dryden_init` / :func:`dryden_step` / :func:`dryden_output` run them on a 5-element
  state with counter-based noise (:mod:`heli_plant.world.noise`), and
  :func:`turbulence_nwu` turns the (u, v, w) components into earth axes.

Why an exact discretisation: the forming filters are linear with white-noise input, so the
sampled process has a closed form ``x_{k+1} = Phi x_k + chol(Q_d) eta_k`` whose variance is the
continuous one at every step and for any ``dt`` (JSBSim's Euler "milspec" recursion and a
plain zero-order hold are only right for ``dt << L/V``; hovering at ``V ~ 1 m/s`` makes
``L/V`` long, but a coarse step still must not bias the variance).

Spectra (MIL-F-8785C form, one-sided in ``Omega`` [rad/m], ``integral_0^inf Phi = sigma^2``;
in time ``Phi(omega) = Phi(Omega = omega/V)/V``)::

    Phi_u = sigma_u^2 (2 L_u/pi) / (1 + (L_u Omega)^2)
    Phi_v = sigma_v^2 (L_v/pi) (1 + 3 (L_v Omega)^2) / (1 + (L_v Omega)^2)^2      (w with L_w)

MIL-HDBK-1797 writes the same spectra with half lengths (its ``2 L``): the lengths here are
the 8785C ones (``L_w = h``, ``L_v = L_u``).

Turbulence is a frozen field convected past the vehicle at the airspeed ``V`` (Taylor's
hypothesis), which needs ``V >> sigma``; JSBSim switches turbulence off at zero airspeed, the
MathWorks blocks list the same limitation. Near hover the caller holds a floor, e.g.
``V = max(|V_E - W_mean|, 1 m/s)``, fixed per run segment. Angular-rate gusts (p_g, q_g, r_g)
are out of scope: the scale lengths (>= 3 m) exceed the rotor, so the c.g. value is used.

State normalisation (why the state is not the textbook one): each filter is run in
coordinates where its stationary covariance is the identity. For u that is ``u_g/sigma_u``;
for v and w (double pole at ``-1/b``, ``b = L/V``, textbook state ``x = (x1, x1')`` with
``P = diag(b^3/4, b/4)``) it is ``z = D^-1 x``, ``D = diag(b^(3/2)/2, b^(1/2)/2)``. Then
``Phi`` and ``Q_d`` depend only on ``tau = V dt/L``, the output row is ``sigma (1, sqrt 3)/2``,
the stationary draw is ``N(0, I)`` whatever the coefficients, and a change of height or
airspeed between steps (new coefficients) keeps the state at the stationary variance; a
zero ``sigma`` gives exactly zero output.
"""

from __future__ import annotations

import math

import numpy as np

from heli_common.jit import njit
from heli_common.layout import Layout
from heli_common.state import FloatArray
from heli_plant.world.noise import (
    STREAM_TURB_INIT,
    STREAM_TURB_U,
    STREAM_TURB_V,
    STREAM_TURB_W,
    normal,
    normal_pair,
)

FT_M = 0.3048  # metres per foot (exact)
KT_M_S = 1852.0 / 3600.0  # metres per second per knot (exact)

# MIL-F-8785C low-altitude model validity: clip below 10 ft, above 1000 ft (medium/high
# altitude model, not provided here).
H_MIN_M = 10.0 * FT_M
H_MAX_M = 1000.0 * FT_M

# Wind at 20 ft for the MIL-F-8785C intensity levels (light / moderate / severe).
W20_LIGHT_M_S = 15.0 * KT_M_S
W20_MODERATE_M_S = 30.0 * KT_M_S
W20_SEVERE_M_S = 45.0 * KT_M_S

_SQRT3 = math.sqrt(3.0)

# --- coefficient array layout (one flat float64 array, see dryden_coefficients) ---------
# offsets inside a second-order block (normalised coordinates, see the module docstring)
BLOCK2 = Layout(
    "Dryden second-order block",
    ("phi11", 1), ("phi12", 1), ("phi21", 1), ("phi22", 1),  # transition matrix Phi, row-major
    # lower Cholesky factor of Q_d = I - Phi Phi^T: [[L11, 0], [L21, L22]]
    ("l11", 1), ("l21", 1), ("l22", 1),
    ("sigma", 1),  # sigma [m/s]
)  # fmt: skip
B_PHI11 = BLOCK2.offset("phi11")
B_PHI12 = BLOCK2.offset("phi12")
B_PHI21 = BLOCK2.offset("phi21")
B_PHI22 = BLOCK2.offset("phi22")
B_L11 = BLOCK2.offset("l11")
B_L21 = BLOCK2.offset("l21")
B_L22 = BLOCK2.offset("l22")
B_SIGMA = BLOCK2.offset("sigma")
N_BLOCK2 = BLOCK2.size
# u: a first-order filter; v and w: a second-order block each
DRYDEN_COEFFS = Layout(
    "Dryden coefficients",
    ("u_a", 1),  # a = exp(-V dt/L_u): one-step decay
    ("u_g", 1),  # sqrt(1 - a^2): noise gain of the unit-variance state
    ("u_sigma", 1),  # sigma_u [m/s]
    ("v", N_BLOCK2),
    ("w", N_BLOCK2),
)
C_U_A = DRYDEN_COEFFS.offset("u_a")
C_U_G = DRYDEN_COEFFS.offset("u_g")
C_U_SIGMA = DRYDEN_COEFFS.offset("u_sigma")
C_V = DRYDEN_COEFFS.offset("v")
C_W = DRYDEN_COEFFS.offset("w")
N_DRYDEN_COEFFS = DRYDEN_COEFFS.size

# --- state layout (normalised: stationary covariance = identity) ------------------------
DRYDEN_STATE = Layout(
    "Dryden state",
    ("u", 1),  # u_g/sigma_u
    ("v", 2),  # v filter: S_V, S_V + 1
    ("w", 2),  # w filter: S_W, S_W + 1
)
S_U = DRYDEN_STATE.offset("u")
S_V = DRYDEN_STATE.offset("v")
S_W = DRYDEN_STATE.offset("w")
N_DRYDEN_STATE = DRYDEN_STATE.size

# Series vs closed form in _incomplete_gamma (both accurate to ~1e-16 relative there).
_SERIES_X_MAX = 1.0


@njit
def dryden_low_altitude(h_m: float, w20_m_s: float) -> tuple[float, float, float, float, float, float]:
    """(L_u, L_v, L_w [m], sigma_u, sigma_v, sigma_w [m/s]): MIL-F-8785C below 1000 ft.

    The standard gives, with h in feet, ``L_w = h``, ``L_u = L_v = h/(0.177 + 0.000823 h)^1.2``,
    ``sigma_w = 0.1 W20`` and ``sigma_u = sigma_v = sigma_w/(0.177 + 0.000823 h)^0.4`` (W20 =
    wind speed at 20 ft, any unit). Evaluated in feet and converted, so the constants are the
    published ones. ``h`` is clipped to [10, 1000] ft (the curves' range; below 10 ft the
    lengths would vanish).
    """
    h_ft = min(max(h_m, H_MIN_M), H_MAX_M) / FT_M
    d = 0.177 + 0.000823 * h_ft
    l_u = h_ft / d**1.2 * FT_M
    sigma_w = 0.1 * w20_m_s
    sigma_u = sigma_w / d**0.4
    return l_u, l_u, h_ft * FT_M, sigma_u, sigma_u, sigma_w


@njit
def _incomplete_gamma(n: int, x: float) -> float:
    """``J_n(x) = integral_0^x t^n e^-t dt`` for n = 0, 1, 2, without cancellation at small x.

    Small x: ``n! e^-x sum_{k>n} x^k/k!`` (every term positive). Otherwise the closed form
    ``n! (1 - e^-x sum_{k<=n} x^k/k!)``.
    """
    fact = 1.0
    for i in range(2, n + 1):
        fact *= i
    if x < _SERIES_X_MAX:
        term = 1.0
        for i in range(1, n + 2):
            term *= x / i  # x^(n+1)/(n+1)!
        total = 0.0
        k = n + 1
        while term > 1e-18 * total or total == 0.0:
            total += term
            k += 1
            term *= x / k
            if term == 0.0:
                break
        return fact * math.exp(-x) * total
    partial = 0.0
    term = 1.0
    for k in range(n + 1):
        if k > 0:
            term *= x / k
        partial += term
    return fact * (1.0 - math.exp(-x) * partial)


@njit
def second_order_discrete(tau: float) -> tuple[FloatArray, FloatArray]:
    """(Phi, Q_d) of the normalised double-pole forming filter for ``tau = V dt/L``.

    Textbook form (``b = L/V``, unit white noise on x2): ``A = [[0, 1], [-1/b^2, -2/b]]``,
    ``e^(A dt) = e^(-dt/b) [[1 + dt/b, dt], [-dt/b^2, 1 - dt/b]]``. With ``z = D^-1 x``,
    ``D = diag(b^(3/2)/2, b^(1/2)/2)``: ``Phi = e^-tau [[1 + tau, tau], [-tau, 1 - tau]]``.
    ``Q_d = D^-1 (integral_0^dt e^(As) B B^T e^(A^T s) ds) D^-1`` in closed form with
    ``J_n = integral_0^(2 tau) t^n e^-t dt``: ``q11 = J2/2``, ``q12 = J1 - J2/2``,
    ``q22 = 2 J0 - 2 J1 + J2/2``. It equals ``I - Phi Phi^T`` (stationarity), but is computed
    from the integral because that difference loses every digit when ``dt << L/V``.
    """
    e = math.exp(-tau)
    phi = np.empty((2, 2))
    phi[0, 0] = e * (1.0 + tau)
    phi[0, 1] = e * tau
    phi[1, 0] = -e * tau
    phi[1, 1] = e * (1.0 - tau)
    x = 2.0 * tau
    j0 = -math.expm1(-x)
    j1 = _incomplete_gamma(1, x)
    j2 = _incomplete_gamma(2, x)
    q = np.empty((2, 2))
    q[0, 0] = 0.5 * j2
    q[0, 1] = j1 - 0.5 * j2
    q[1, 0] = q[0, 1]
    q[1, 1] = 2.0 * j0 - 2.0 * j1 + 0.5 * j2
    return phi, q


@njit
def _fill_block2(c: FloatArray, base: int, l_m: float, sigma_m_s: float, v_m_s: float, dt_s: float) -> None:
    """Write one second-order block (Phi, chol(Q_d), sigma) at ``c[base:base + N_BLOCK2]``."""
    phi, q = second_order_discrete(v_m_s * dt_s / l_m)
    l11 = math.sqrt(max(q[0, 0], 0.0))
    l21 = q[0, 1] / l11 if l11 > 0.0 else 0.0
    l22 = math.sqrt(max(q[1, 1] - l21 * l21, 0.0))
    c[base + B_PHI11] = phi[0, 0]
    c[base + B_PHI12] = phi[0, 1]
    c[base + B_PHI21] = phi[1, 0]
    c[base + B_PHI22] = phi[1, 1]
    c[base + B_L11] = l11
    c[base + B_L21] = l21
    c[base + B_L22] = l22
    c[base + B_SIGMA] = sigma_m_s


@njit
def dryden_coefficients(
    l_u: float,
    l_v: float,
    l_w: float,
    sigma_u: float,
    sigma_v: float,
    sigma_w: float,
    v_m_s: float,
    dt_s: float,
) -> FloatArray:
    """Everything :func:`dryden_step` needs for step ``dt_s`` at convection speed ``v_m_s``.

    Lengths in m, intensities in m/s; layout ``C_*``/``B_*`` above (``N_DRYDEN_COEFFS``
    entries). u: ``a = exp(-V dt/L_u)`` and ``sqrt(1 - a^2)`` (computed as
    ``sqrt(-expm1(-2 V dt/L_u))``, exact for tiny steps); v, w: see
    :func:`second_order_discrete`. Raises ValueError on a non-positive length, speed or step
    or a negative intensity.
    """
    if not (l_u > 0.0 and l_v > 0.0 and l_w > 0.0):
        raise ValueError("Dryden scale lengths must be > 0")
    if not (v_m_s > 0.0 and dt_s > 0.0):
        raise ValueError("Dryden convection speed and time step must be > 0")
    if not (sigma_u >= 0.0 and sigma_v >= 0.0 and sigma_w >= 0.0):
        raise ValueError("Dryden intensities must be >= 0")
    c = np.zeros(N_DRYDEN_COEFFS)
    tau_u = v_m_s * dt_s / l_u
    c[C_U_A] = math.exp(-tau_u)
    c[C_U_G] = math.sqrt(-math.expm1(-2.0 * tau_u))
    c[C_U_SIGMA] = sigma_u
    _fill_block2(c, C_V, l_v, sigma_v, v_m_s, dt_s)
    _fill_block2(c, C_W, l_w, sigma_w, v_m_s, dt_s)
    return c


@njit
def _step_block2(c: FloatArray, base: int, state: FloatArray, s: int, eta1: float, eta2: float) -> None:
    """``z <- Phi z + chol(Q_d) eta`` for the second-order filter at ``state[s:s + 2]``."""
    z1 = state[s]
    z2 = state[s + 1]
    state[s] = c[base + B_PHI11] * z1 + c[base + B_PHI12] * z2 + c[base + B_L11] * eta1
    state[s + 1] = (
        c[base + B_PHI21] * z1 + c[base + B_PHI22] * z2 + c[base + B_L21] * eta1 + c[base + B_L22] * eta2
    )


@njit
def dryden_step(coeffs: FloatArray, state: FloatArray, seed: int, k: int) -> None:
    """Advance the turbulence state by one step, in place; ``k`` is the step counter (>= 0).

    Noise: ``normal(seed, STREAM_TURB_U, k)`` for u, both deviates of
    ``normal_pair(seed, STREAM_TURB_V/W, k)`` for v/w, so step k is reproducible on its own.
    """
    eta_u = normal(seed, STREAM_TURB_U, k)
    ev1, ev2 = normal_pair(seed, STREAM_TURB_V, k)
    ew1, ew2 = normal_pair(seed, STREAM_TURB_W, k)
    state[S_U] = coeffs[C_U_A] * state[S_U] + coeffs[C_U_G] * eta_u
    _step_block2(coeffs, C_V, state, S_V, ev1, ev2)
    _step_block2(coeffs, C_W, state, S_W, ew1, ew2)


@njit
def dryden_output(coeffs: FloatArray, state: FloatArray) -> tuple[float, float, float]:
    """(u_g, v_g, w_g) [m/s] in mean-wind axes: ``sigma_u z_u`` and ``sigma (z1 + sqrt3 z2)/2``."""
    u = coeffs[C_U_SIGMA] * state[S_U]
    v = coeffs[C_V + B_SIGMA] * 0.5 * (state[S_V] + _SQRT3 * state[S_V + 1])
    w = coeffs[C_W + B_SIGMA] * 0.5 * (state[S_W] + _SQRT3 * state[S_W + 1])
    return u, v, w


@njit
def dryden_init(coeffs: FloatArray, state: FloatArray, seed: int) -> None:
    """Draw the stationary initial state ``x0 ~ N(0, P)``: N(0, I) in normalised coordinates.

    Uses its own stream (``STREAM_TURB_INIT``, counters 0..4), so the step noises
    (counters k >= 0 of the U/V/W streams) stay untouched. ``coeffs`` is only checked for
    its layout: the stationary law does not depend on it.
    """
    if coeffs.shape[0] != N_DRYDEN_COEFFS or state.shape[0] != N_DRYDEN_STATE:
        raise ValueError("dryden_init: wrong coefficient or state length")
    for i in range(N_DRYDEN_STATE):
        state[i] = normal(seed, STREAM_TURB_INIT, i)


@njit
def turbulence_nwu(
    u_g: float, v_g: float, w_g: float, psi_from_rad: float, calm: bool
) -> tuple[float, float, float]:
    """Turbulence in earth NWU [m/s] from mean-wind-axis components (u downwind, w up).

    Below 1000 ft MIL-F-8785C resolves the components in mean-wind axes:
    ``e_u = (-cos psi_from, sin psi_from, 0)`` (downwind, psi_from = direction the wind comes
    from, clockwise from north), ``e_v = e_z x e_u = (-sin psi_from, -cos psi_from, 0)``, w along
    ``e_z`` (up). In calm air (no mean wind to align with) ``e_u`` = north.
    """
    if calm:
        cx, cy = 1.0, 0.0
    else:
        cx, cy = -math.cos(psi_from_rad), math.sin(psi_from_rad)
    return u_g * cx - v_g * cy, u_g * cy + v_g * cx, w_g
