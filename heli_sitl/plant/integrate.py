"""Fixed-step classical RK4 over one hold interval (inputs held constant: zero-order hold)."""

from __future__ import annotations

from heli_common.airframe import PlantConstants
from heli_common.jit import njit
from heli_common.state import FloatArray
from heli_sitl.plant.dynamics import derivative


@njit
def rk4_step(t: float, x: FloatArray, u: FloatArray, c: PlantConstants, dt: float, n_sub: int) -> FloatArray:
    """Advance ``x`` by ``dt`` with ``n_sub`` RK4 sub-steps and ``u`` held; returns the new state."""
    h = dt / n_sub
    y = x.copy()
    for k in range(n_sub):
        tk = t + k * h
        k1 = derivative(tk, y, u, c)
        k2 = derivative(tk + 0.5 * h, y + 0.5 * h * k1, u, c)
        k3 = derivative(tk + 0.5 * h, y + 0.5 * h * k2, u, c)
        k4 = derivative(tk + h, y + h * k3, u, c)
        y = y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return y
