"""The estimator as the autopilot runs it: the vehicle's measurements in, a state out.

The component beside the controller: the runner hands it what the sim link delivered (the
measurement layout of :mod:`heli_common.measurements`, a mask of what is new, the sensors'
time) and flies on what it returns. It calls the same compiled tick as the in-process loop
(:func:`~autopilot.estimation.kf.est_tick`), so a lockstep flight and an in-process one see
the same estimates. It keeps the estimator's log for est.csv and reports its health.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from autopilot.estimation.config import EstimatorConfig
from autopilot.estimation.kf import (
    E_N_REJECT,
    E_N_RESET,
    E_NIS,
    E_T,
    E_T_FIX,
    K_GPS_TIMEOUT,
    K_N_BUF,
    N_EST_LOG,
    est_init,
    est_tick,
    log_tick,
    make_params,
    state_size,
)
from heli_common.measurements import N_OUT, OUT_ACCEL
from heli_common.state import N_STATE, FloatArray


class NavHealth(NamedTuple):
    """What the flight manager's failsafes read."""

    gps_lost: bool
    time_since_fix_s: float
    n_rejected: int
    n_resets: int
    last_nis: float


class OnboardEstimator:
    """One :meth:`update` per control tick; a measurement whose time did not advance (a
    re-sent datagram, a held vehicle) changes nothing."""

    def __init__(self, config: EstimatorConfig, rate_hz: float, x0: FloatArray) -> None:
        self.config = config
        self.params = make_params(config, rate_hz)
        self.state = np.zeros(state_size(int(self.params[K_N_BUF])))
        x = np.asarray(x0, dtype=float)
        if x.shape != (N_STATE,) or not np.all(np.isfinite(x)):
            raise ValueError(f"x0 must be a finite ({N_STATE},) state")
        est_init(self.params, self.state, x)
        self.x_hat = x.copy()
        self.log_row = np.full(N_EST_LOG, math.nan)
        self._t_s = -math.inf

    def warm_up(self) -> None:
        """Load the compiled tick (numba loads code on a first call) on throwaway copies."""
        meas = np.zeros(N_OUT)
        meas[OUT_ACCEL + 2] = self.config.gravity_m_s2
        st, row = self.state.copy(), np.zeros(N_EST_LOG)
        for t in (0.0, 0.01):
            log_tick(st, est_tick(self.params, st, t, meas, 0, False, np.zeros(N_STATE)), row)

    def update(self, t_s: float, meas: FloatArray, mask: int) -> FloatArray:
        """The estimate after this tick's measurements (valid at ``t_s``, the sensors' time);
        the previous one if ``t_s`` did not advance."""
        if t_s > self._t_s:
            self._t_s = t_s
            gps = est_tick(self.params, self.state, t_s, meas, mask, self.config.use_baro, self.x_hat)
            log_tick(self.state, gps, self.log_row)
        return self.x_hat

    @property
    def health(self) -> NavHealth:
        s = self.state
        since = float(s[E_T] - s[E_T_FIX]) if math.isfinite(s[E_T]) else 0.0
        return NavHealth(since > self.params[K_GPS_TIMEOUT], since, int(s[E_N_REJECT]), int(s[E_N_RESET]),
                         float(s[E_NIS]))  # fmt: skip
