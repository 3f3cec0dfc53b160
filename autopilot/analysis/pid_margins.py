"""Linear margins of the PID baseline's four loops with a servo model in the loop, by the
same method and approximations as the TLC's (:mod:`autopilot.analysis.margins`), so the two
controllers' margins compare like for like. ``heli-sitl margins --controller pid --loops``
prints them for the servo models ideal, default and sloppy.

About hover, one channel at a time (the numbering of the TLC's loops, inner to outer):

* loop 4, body rate (roll, pitch, yaw): the torque command reaches the rate through the
  actuator ``A(s)`` (servo delay + half a period of hold, first-order lag) and ``1/s`` (``J``
  cancels, the law multiplies by the design ``J``); the regulator is ``Kpi = kp + ki/s`` on
  the error and ``Kd = kd s / (tau_d s + 1)`` on the measured rate (the derivative filter at
  ``d_filter_hz``), the rate set point's feed-forward ``ff`` outside the loop:
  ``L4 = A (Kpi + Kd) / s``, ``T4 = A (Kpi + ff) / (s + A (Kpi + Kd))``;
* loop 3, attitude: ``L3 = kp_att T4 / s``;
* loop 2, velocity: x through the closed pitch loop, y through the closed roll loop (the
  tilt set point is the acceleration over g), z through the collective's actuator alone:
  ``L2 = (kv + ki_v / s) P / s`` with ``P = T3`` or ``A``;
* loop 1, position: ``L1 = kp_pos T2 / s``.

The feed-forward paths (trajectory velocity and acceleration, the yaw rate) do not change
the loops' margins and are left out; the rate limits and the tilt limit are not in a
linear model. Stability of each closure comes from the Pade model's poles, as for the TLC.
"""

from __future__ import annotations

import math
from typing import Any

import control as ct
import numpy as np

from autopilot.analysis.margins import (
    _LOOP2_THROUGH,
    LOOP_CHANNELS,
    OMEGA_GRID,
    PADE_ORDER,
    LoopMargins,
    MarginReport,
    ServoModel,
    _actuator_poly,
    _hurwitz,
    _inner_chain,
    _margins,
    _Ratio,
)
from autopilot.pid.gains import PidGains


def _stages(gains: PidGains, s: Any, a: _Ratio) -> dict[tuple[int, int], tuple[_Ratio, _Ratio, Any]]:
    """(loop, channel) -> (open loop L, closed loop T, characteristic polynomial)."""
    out: dict[tuple[int, int], tuple[_Ratio, _Ratio, Any]] = {}
    r, tau_d = gains.rate, 1.0 / (2.0 * math.pi * gains.rate.d_filter_hz)
    for ch in range(3):
        f = s * tau_d + 1.0
        pi = s * r.kp[ch] + r.ki[ch]  # Kpi = pi / s
        nc = pi * f + s * s * r.kd[ch]  # Kpi + Kd = nc / (s f)
        char = a.den * f * s * s + a.num * nc
        ref = (pi + s * r.ff[ch]) * f  # the set point's path: Kpi + ff, times s f
        out[4, ch] = (_Ratio(a.num * nc, a.den * f * s * s), _Ratio(a.num * ref, char), char)
    for ch in range(3):
        t4 = out[4, ch][1]
        k = gains.attitude.kp[ch]
        char = s * t4.den + k * t4.num
        out[3, ch] = (_Ratio(k * t4.num, s * t4.den), _Ratio(k * t4.num, char), char)
    for ch, through in enumerate(_LOOP2_THROUGH):
        p = a if through is None else out[3, through][1]
        kv = s * gains.velocity.kp[ch] + gains.velocity.ki[ch]
        char = s * s * p.den + kv * p.num
        out[2, ch] = (_Ratio(kv * p.num, s * s * p.den), _Ratio(kv * p.num, char), char)
    for ch in range(3):
        t2 = out[2, ch][1]
        k = gains.position.kp[ch]
        char = s * t2.den + k * t2.num
        out[1, ch] = (_Ratio(k * t2.num, s * t2.den), _Ratio(k * t2.num, char), char)
    return out


def pid_loop_margins(gains: PidGains, servo: ServoModel, *, pade_order: int = PADE_ORDER) -> MarginReport:
    """Margins of the PID's loops 1-4, every channel, flying through ``servo``: the exact
    delay on :data:`OMEGA_GRID` (python-control's FRD margins), stability from the poles of
    the Pade model."""
    poly = _stages(gains, np.poly1d([1.0, 0.0]), _actuator_poly(servo, pade_order))
    s = 1j * OMEGA_GRID
    freq = _stages(gains, s, _Ratio(np.exp(-s * servo.effective_delay_s), 1.0 + servo.tau_s * s))
    loops: list[LoopMargins] = []
    for loop in (1, 2, 3, 4):
        for ch, name in enumerate(LOOP_CHANNELS[loop]):
            stable = all(_hurwitz(np.poly1d(poly[key][2])) for key in _inner_chain(loop, ch))
            lo = freq[loop, ch][0]
            sys = ct.frd(np.asarray(lo.num / lo.den, dtype=complex), OMEGA_GRID)
            loops.append(_margins(sys, loop, name, stable))
    return MarginReport(gains.name, servo, "exact", False, tuple(loops))
