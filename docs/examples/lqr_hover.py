"""Your own controller on the bench: an LQR about the hover trim.

The law is designed in a dozen lines from the bench's own linearisation (``hs.linearize``:
the paper's rigid-body plant about hover, differentiated from the very derivative the
plant integrates), discretised at the control rate with a zero-order hold and weighted by
Bryson's rule. It keeps the bench's controller contract (``autopilot.user_controller``):
built from the airframe and the control rate, ``update(t_s, state, reference) ->
pitches``, ``reset()``. The same class flies

* in-process:        ``python docs/examples/lqr_hover.py`` (the paper scenario), or
                     ``hs.simulate(controller="docs/examples/lqr_hover.py:LqrHover")``;
* as processes:      ``heli-sitl demo --mode lockstep --autostart --out out/lqr
                     --controller docs/examples/lqr_hover.py:LqrHover``
                     (the autopilot process loads the class);
* in a campaign:     ``heli-sitl campaign robustness --out out/lqr-campaign
                     --controller docs/examples/lqr_hover.py:LqrHover``.

A linear law about hover has no feedforward of the trajectory's acceleration and no model
of the attitude the thrust needs: it tracks the paper's slow circle (0.8 m/s) to a few
centimetres, and it is no answer to an aggressive turn. That is the point of the TLC.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

import heli_sitl as hs
from heli_common.kinematics import rot_body_to_earth
from heli_common.state import EULER, N_STATE, POS, PSI, VEL, FloatArray
from heli_common.vehicle.airframe import Airframe

# Bryson's rule: the largest error (or command) we accept on each state (and input)
MAX_ERROR = np.array([0.2, 0.2, 0.2,          # position NWU [m]
                      0.5, 0.5, 0.5,          # velocity FLU [m/s]
                      0.1, 0.1, 0.1,          # roll, pitch, yaw [rad]
                      0.5, 0.5, 0.5])         # body rates [rad/s]  # fmt: skip
MAX_PITCH_RAD = np.array([0.05, 0.1, 0.03, 0.03])  # theta_m, theta_t, eps, eta


def discrete_lqr(a: FloatArray, b: FloatArray, dt_s: float, q: FloatArray, r: FloatArray) -> FloatArray:
    """The gain K of u = -K x for the zero-order-hold discretisation of (a, b) at dt_s."""
    n, m = b.shape
    block = np.zeros((n + m, n + m))
    block[:n, :n], block[:n, n:] = a, b
    e = scipy.linalg.expm(block * dt_s)
    ad, bd = e[:n, :n], e[:n, n:]
    p = scipy.linalg.solve_discrete_are(ad, bd, q, r)
    k: FloatArray = np.linalg.solve(r + bd.T @ p @ bd, bd.T @ p @ ad)
    return k


class LqrHover:
    """u = u_trim - K (x - x_ref): position and velocity from the reference, attitude and
    rates those of the hover trim."""

    name = "LQR about hover"

    def __init__(self, airframe: Airframe, rate_hz: float) -> None:
        lin = hs.linearize("paper", airframe=airframe)
        self.x_trim = lin.trim.x[:N_STATE].copy()
        self.u_trim = lin.trim.u.copy()
        q = np.diag(1.0 / MAX_ERROR**2)
        r = np.diag(1.0 / MAX_PITCH_RAD**2)
        self.k = discrete_lqr(lin.a[:N_STATE, :N_STATE], lin.b[:N_STATE], 1.0 / rate_hz, q, r)

    def update(self, t_s: float, state: FloatArray, reference: FloatArray) -> FloatArray:
        x_ref = self.x_trim.copy()
        x_ref[POS] = reference[0:3]
        vel_nwu = np.nan_to_num(reference[3:6])  # an unknown derivative: no feedforward
        phi, theta, psi = state[EULER]
        x_ref[VEL] = rot_body_to_earth(phi, theta, psi).T @ vel_nwu
        e = state - x_ref
        e[PSI] = (e[PSI] + np.pi) % (2.0 * np.pi) - np.pi
        u: FloatArray = self.u_trim - self.k @ e
        return u

    def reset(self) -> None:
        """Nothing to forget: the law has no integrator and no filter."""


if __name__ == "__main__":
    flight = hs.simulate("paper", controller=LqrHover)
    print(f"{flight.controller}: {flight.status.value}, RMS [45, 120] s = "
          f"{flight.metrics.rms_m['45-120']:.4f} m" if flight.metrics else flight.error)  # fmt: skip
